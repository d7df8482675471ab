// A static server for the tests until `nerf-render --serve` exists: dist/ at /, a bundle
// directory at /bundle/, with the COOP/COEP/CORP headers onnxruntime's threads need.
// usage: node tests/serve.mjs --bundle DIR [--port P] [--root dist] [--no-isolation]
import { createServer } from "node:http";
import { readFile, stat } from "node:fs/promises";
import { extname, join, normalize, resolve } from "node:path";

const TYPES = {
  ".html": "text/html; charset=utf-8", ".js": "text/javascript", ".mjs": "text/javascript",
  ".css": "text/css", ".json": "application/json", ".wasm": "application/wasm",
  ".onnx": "application/octet-stream", ".bin": "application/octet-stream", ".png": "image/png",
};

export function serve({ root, bundle, port = 0, isolation = true }) {
  const server = createServer(async (req, res) => {
    const path = decodeURIComponent(new URL(req.url, "http://x").pathname);
    let file;
    if (path.startsWith("/bundle/")) file = join(bundle, normalize(path.slice(8)).replace(/^(\.\.[/\\])+/, ""));
    else file = join(root, normalize(path === "/" ? "/index.html" : path).replace(/^(\.\.[/\\])+/, ""));
    const headers = { "Content-Type": TYPES[extname(file)] ?? "application/octet-stream", "Cache-Control": "no-store" };
    if (isolation) Object.assign(headers, {
      "Cross-Origin-Opener-Policy": "same-origin", "Cross-Origin-Embedder-Policy": "require-corp",
      "Cross-Origin-Resource-Policy": "same-origin",
    });
    try {
      if (!(await stat(file)).isFile()) throw new Error("not a file");
      const body = await readFile(file);
      res.writeHead(200, headers).end(body);
    } catch {
      res.writeHead(404, { ...headers, "Content-Type": "text/plain" }).end("not found\n");
    }
  });
  return new Promise((ok) => server.listen(port, "127.0.0.1", () => ok(server)));
}

if (import.meta.url === `file://${process.argv[1]}`) {
  const arg = (name, dflt) => { const i = process.argv.indexOf(name); return i > 0 ? process.argv[i + 1] : dflt; };
  const here = resolve(import.meta.dirname, "..");
  const server = await serve({ root: resolve(arg("--root", join(here, "dist"))), bundle: resolve(arg("--bundle", ".")),
    port: Number(arg("--port", 8080)), isolation: !process.argv.includes("--no-isolation") });
  console.log(`serving on http://127.0.0.1:${server.address().port}/`);
}
