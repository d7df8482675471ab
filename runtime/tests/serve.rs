//! `nerf-render --serve` over raw HTTP/1.1 (requests written by hand, so that no client
//! normalises the paths): the viewer's and the bundle's files with the cross-origin isolation
//! headers and their content types, nothing else (traversal, encoded and absolute paths, hidden
//! files, links out of the tree), GET and HEAD only, and a clear error without a viewer.

use std::io::{BufRead, BufReader, Read, Write};
use std::net::TcpStream;
use std::path::Path;
use std::process::{Child, Command, Stdio};

struct Server {
    child: Child,
    address: String,
}

impl Drop for Server {
    fn drop(&mut self) {
        self.child.kill().ok();
        self.child.wait().ok();
    }
}

/// Start `nerf-render --serve --port 0` and read the address it prints.
fn start(bundle: &Path, viewer: &Path) -> Server {
    let mut child = Command::new(env!("CARGO_BIN_EXE_nerf-render"))
        .args(["--bundle", bundle.to_str().unwrap(), "--serve", "--port", "0", "--viewer", viewer.to_str().unwrap()])
        .stdout(Stdio::piped())
        .stderr(Stdio::null())
        .spawn()
        .expect("run nerf-render");
    let mut line = String::new();
    BufReader::new(child.stdout.take().unwrap()).read_line(&mut line).unwrap();
    let address = line.trim().strip_prefix("viewer: http://").and_then(|a| a.strip_suffix('/')).unwrap_or_else(|| panic!("no URL printed: {line:?}")).to_string();
    assert!(address.starts_with("127.0.0.1:"), "binds loopback by default: {address}");
    Server { child, address }
}

/// Send a raw request; (status, lower-cased headers, body).
fn request(server: &Server, method: &str, target: &str) -> (u16, String, Vec<u8>) {
    let mut stream = TcpStream::connect(&server.address).unwrap();
    write!(stream, "{method} {target} HTTP/1.1\r\nHost: {}\r\nConnection: close\r\n\r\n", server.address).unwrap();
    let mut raw = Vec::new();
    stream.read_to_end(&mut raw).unwrap();
    let split = raw.windows(4).position(|w| w == b"\r\n\r\n").expect("a complete response");
    let head = String::from_utf8_lossy(&raw[..split]).to_lowercase();
    let status = head.split_whitespace().nth(1).unwrap().parse().unwrap();
    (status, head, raw[split + 4..].to_vec())
}

fn site(dir: &Path) -> (std::path::PathBuf, std::path::PathBuf) {
    let viewer = dir.join("viewer");
    std::fs::create_dir_all(viewer.join("assets")).unwrap();
    std::fs::write(viewer.join("index.html"), "<!doctype html><title>viewer</title>").unwrap();
    std::fs::write(viewer.join("assets/app.js"), "export {};").unwrap();
    std::fs::write(viewer.join("assets/ort.wasm"), b"\0asm").unwrap();
    std::fs::write(viewer.join(".hidden"), "secret").unwrap();
    std::os::unix::fs::symlink(Path::new(env!("CARGO_MANIFEST_DIR")).join("Cargo.toml"), viewer.join("link.txt")).unwrap();
    let bundle = dir.join("bundle");
    std::fs::create_dir_all(bundle.join("sub")).unwrap();
    for entry in std::fs::read_dir(Path::new(env!("CARGO_MANIFEST_DIR")).join("../models/spheres")).unwrap() {
        let entry = entry.unwrap();
        std::fs::copy(entry.path(), bundle.join(entry.file_name())).unwrap();
    }
    std::fs::write(bundle.join("sub/inner.txt"), "not served").unwrap();
    std::fs::write(bundle.join(".env"), "secret").unwrap();
    (viewer, bundle)
}

#[test]
fn serves_the_viewer_and_the_bundle_with_isolation_headers_and_nothing_else() {
    let dir = tempfile::tempdir().unwrap();
    let (viewer, bundle) = site(dir.path());
    let server = start(&bundle, &viewer);

    for (path, kind) in [("/", "text/html"), ("/index.html", "text/html"), ("/assets/app.js", "text/javascript"), ("/assets/ort.wasm", "application/wasm"), ("/bundle/scene.json", "application/json"), ("/bundle/coarse.onnx", "application/octet-stream"), ("/bundle/scene.json?x=1", "application/json")] {
        let (status, head, body) = request(&server, "GET", path);
        assert_eq!(status, 200, "{path}: {head}");
        assert!(head.contains(&format!("content-type: {kind}")), "{path}: {head}");
        for h in ["cross-origin-opener-policy: same-origin", "cross-origin-embedder-policy: require-corp", "cross-origin-resource-policy: same-origin"] {
            assert!(head.contains(h), "{path} lacks {h}: {head}");
        }
        assert!(!body.is_empty(), "{path}");
    }
    let onnx = std::fs::read(bundle.join("coarse.onnx")).unwrap();
    assert_eq!(request(&server, "GET", "/bundle/coarse.onnx").2, onnx, "the file's bytes");

    // Nothing outside the two trees, however the path is written; no hidden files, no links,
    // no subfolders of the bundle, no directory listings.
    for path in [
        "/../Cargo.toml",
        "/bundle/../../Cargo.toml",
        "/%2e%2e/Cargo.toml",
        "/%2E%2E%2FCargo.toml",
        "/bundle/%2e%2e/%2e%2e/runtime/Cargo.toml",
        "/bundle/..%2f..%2fCargo.toml",
        "/bundle/sub/inner.txt",
        "/bundle/.env",
        "/.hidden",
        "/link.txt",
        "//etc/passwd",
        "/bundle//etc/passwd",
        "/assets/",
        "/bundle/",
        "/bundle",
        "/assets",
        "http://example.com/../Cargo.toml",
        "/index.html%00.png",
        "/assets\\app.js",
    ] {
        let (status, head, body) = request(&server, "GET", path);
        assert!(status == 404 || status == 400, "{path}: {status} {head}");
        assert!(!String::from_utf8_lossy(&body).contains("[package]"), "{path} leaked a file");
    }

    // GET and HEAD only; HEAD gives the length and no body.
    for method in ["POST", "PUT", "DELETE", "OPTIONS"] {
        let (status, head, _) = request(&server, method, "/index.html");
        assert_eq!(status, 405, "{method}: {head}");
        assert!(head.contains("allow: get, head"), "{head}");
    }
    let (status, head, body) = request(&server, "HEAD", "/bundle/coarse.onnx");
    assert_eq!(status, 200);
    assert!(head.contains(&format!("content-length: {}", onnx.len())) && body.is_empty(), "{head}");
}

#[test]
fn without_a_built_viewer_it_says_how_to_get_one() {
    let dir = tempfile::tempdir().unwrap();
    let out = Command::new(env!("CARGO_BIN_EXE_nerf-render"))
        .args(["--bundle", Path::new(env!("CARGO_MANIFEST_DIR")).join("../models/spheres").to_str().unwrap(), "--serve", "--port", "0", "--viewer", dir.path().to_str().unwrap()])
        .output()
        .unwrap();
    let text = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success() && text.contains("no viewer") && text.contains("scripts/setup.sh"), "{text}");
}
