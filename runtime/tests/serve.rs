//! `nerf-render --serve` over raw HTTP/1.1 (requests written by hand, so that no client
//! normalises the paths): the viewer's files and exactly the bundle's (`scene.json` and what it
//! names) with the cross-origin isolation headers and their content types, nothing else (other
//! files of the folder, traversal, encoded and absolute paths, hidden files, links out of the
//! tree), GET and HEAD only, a clear error without a viewer or on a folder that is not a
//! loadable bundle, `scene.json` alone with `--show-bundle-error`, and bounded memory under
//! parallel requests for a large graph.

use nerf_bundle::proto::{ModelProto, TensorProto, data_type};
use prost::Message;
use std::io::{BufRead, BufReader, Read, Write};
use std::net::TcpStream;
use std::path::Path;
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

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

/// `nerf-render --bundle B --serve --port 0 --viewer V` and `more`.
fn serve_command(bundle: &Path, viewer: &Path, more: &[&str]) -> Command {
    let mut command = Command::new(env!("CARGO_BIN_EXE_nerf-render"));
    command.args(["--bundle", bundle.to_str().unwrap(), "--serve", "--port", "0", "--viewer", viewer.to_str().unwrap()]).args(more);
    command
}

/// Start `nerf-render --serve --port 0` and read the address it prints.
fn start(bundle: &Path, viewer: &Path) -> Server {
    start_with(bundle, viewer, &[])
}

/// [`start`] with more options.
fn start_with(bundle: &Path, viewer: &Path, more: &[&str]) -> Server {
    let mut child = serve_command(bundle, viewer, more)
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
    // Plain regular files that scene.json does not name.
    std::fs::write(bundle.join("notes.txt"), "not served").unwrap();
    std::fs::copy(bundle.join("coarse.onnx"), bundle.join("extra.onnx")).unwrap();
    (viewer, bundle)
}

/// The files the shipped bundle's scene.json names, and itself.
const NAMED: [&str; 4] = ["scene.json", "coarse.onnx", "fine.onnx", "occupancy.bin"];

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
    // Each file scene.json names (and scene.json), byte for byte, with its length.
    for name in NAMED {
        let file = std::fs::read(bundle.join(name)).unwrap();
        let (status, head, body) = request(&server, "GET", &format!("/bundle/{name}"));
        assert_eq!(status, 200, "{name}: {head}");
        assert!(head.contains(&format!("content-length: {}", file.len())), "{name}: {head}");
        assert!(body == file, "{name}: {} bytes served, the file has {}", body.len(), file.len());
    }
    let onnx = std::fs::read(bundle.join("coarse.onnx")).unwrap();

    // Nothing outside the two trees, however the path is written; no hidden files, no links,
    // no subfolders of the bundle, no directory listings, no files scene.json does not name.
    for path in [
        "/bundle/notes.txt",
        "/bundle/extra.onnx",
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

/// Run `nerf-render --serve` expecting it to refuse: (stdout, stderr). Fails if it is still
/// running after 30 s (serving).
fn refused(bundle: &Path, viewer: &Path, more: &[&str]) -> (String, String) {
    let mut child = serve_command(bundle, viewer, more)
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("run nerf-render");
    let start = Instant::now();
    let status = loop {
        if let Some(status) = child.try_wait().unwrap() {
            break status;
        }
        if start.elapsed() > Duration::from_secs(30) {
            child.kill().ok();
            let out = child.wait_with_output().unwrap();
            panic!("still serving {} after 30 s: {}", bundle.display(), String::from_utf8_lossy(&out.stdout));
        }
        std::thread::sleep(Duration::from_millis(50));
    };
    let out = child.wait_with_output().unwrap();
    let (stdout, stderr) = (String::from_utf8_lossy(&out.stdout).into_owned(), String::from_utf8_lossy(&out.stderr).into_owned());
    assert!(!status.success() && !stderr.contains("panicked"), "{status}: {stderr}");
    assert!(!stdout.contains("http://"), "printed a URL: {stdout}");
    (stdout, stderr)
}

#[test]
fn refuses_a_folder_that_is_not_a_loadable_bundle() {
    let dir = tempfile::tempdir().unwrap();
    let (viewer, bundle) = site(dir.path());
    // A folder of files without scene.json (as `--bundle ~`).
    let home = dir.path().join("home");
    std::fs::create_dir(&home).unwrap();
    std::fs::write(home.join("notes.txt"), "private").unwrap();
    std::fs::write(home.join("id_rsa"), "private").unwrap();
    let (_, err) = refused(&home, &viewer, &[]);
    assert!(err.contains(&format!("{}: not a bundle that loads", home.display())) && err.contains("scene.json") && err.contains("--show-bundle-error"), "{err}");

    // Bundles broken in one way each: the error names the folder and the file at fault.
    let broken = |name: &str, edit: &dyn Fn(&Path)| {
        let b = dir.path().join(name);
        std::fs::create_dir(&b).unwrap();
        for f in NAMED {
            std::fs::copy(bundle.join(f), b.join(f)).unwrap();
        }
        edit(&b);
        b
    };
    let scene = std::fs::read_to_string(bundle.join("scene.json")).unwrap();
    for (b, names) in [
        (broken("no-fine", &|b| std::fs::remove_file(b.join("fine.onnx")).unwrap()), "fine.onnx"),
        (broken("no-grid", &|b| std::fs::remove_file(b.join("occupancy.bin")).unwrap()), "occupancy.bin"),
        (broken("not-json", &|b| std::fs::write(b.join("scene.json"), "{ not json").unwrap()), "scene.json"),
        (broken("outside", &|b| std::fs::write(b.join("scene.json"), scene.replace("\"fine.onnx\"", "\"../fine.onnx\"")).unwrap()), "networks.fine"),
        (broken("fine-is-a-dir", &|b| {
            std::fs::remove_file(b.join("fine.onnx")).unwrap();
            std::fs::create_dir(b.join("fine.onnx")).unwrap();
        }), "fine.onnx"),
    ] {
        let (_, err) = refused(&b, &viewer, &[]);
        assert!(err.contains(&format!("{}: not a bundle that loads", b.display())) && err.contains(names), "{}: {err}", b.display());
    }
    // No folder at all: refused even with --show-bundle-error.
    let (_, err) = refused(&dir.path().join("missing"), &viewer, &["--show-bundle-error"]);
    assert!(err.contains("missing: no such bundle directory"), "{err}");
}

#[test]
fn show_bundle_error_serves_scene_json_alone() {
    let dir = tempfile::tempdir().unwrap();
    let (viewer, bundle) = site(dir.path());
    std::fs::remove_file(bundle.join("fine.onnx")).unwrap();
    let server = start_with(&bundle, &viewer, &["--show-bundle-error"]);
    assert_eq!(request(&server, "GET", "/").0, 200, "the viewer");
    let (status, _, body) = request(&server, "GET", "/bundle/scene.json");
    assert!(status == 200 && body == std::fs::read(bundle.join("scene.json")).unwrap(), "scene.json: {status}");
    // Not even the files that are there: the bundle does not load.
    for name in ["coarse.onnx", "fine.onnx", "occupancy.bin", "notes.txt", "extra.onnx"] {
        assert_eq!(request(&server, "GET", &format!("/bundle/{name}")).0, 404, "{name}");
    }
    drop(server);

    // A folder without scene.json, one whose scene.json is over the JSON limit (a sparse file)
    // and one whose scene.json links out of the folder: the viewer, and nothing of the folder.
    let outside = dir.path().join("outside.json");
    std::fs::write(&outside, "{}").unwrap();
    for (name, make) in [
        ("empty", &(|_: &Path| {}) as &dyn Fn(&Path)),
        ("huge", &|b: &Path| std::fs::File::create(b.join("scene.json")).unwrap().set_len((64 << 20) + 1).unwrap()),
        ("link", &|b: &Path| std::os::unix::fs::symlink(&outside, b.join("scene.json")).unwrap()),
    ] {
        let b = dir.path().join(name);
        std::fs::create_dir(&b).unwrap();
        std::fs::write(b.join("notes.txt"), "private").unwrap();
        make(&b);
        let server = start_with(&b, &viewer, &["--show-bundle-error"]);
        assert_eq!(request(&server, "GET", "/index.html").0, 200, "{name}: the viewer");
        for file in ["scene.json", "notes.txt"] {
            assert_eq!(request(&server, "GET", &format!("/bundle/{file}")).0, 404, "{name}: {file}");
        }
    }

    // A bundle that loads is served whole with the option too.
    let server = start_with(&Path::new(env!("CARGO_MANIFEST_DIR")).join("../models/spheres"), &viewer, &["--show-bundle-error"]);
    assert_eq!(request(&server, "GET", "/bundle/fine.onnx").0, 200);
}

/// The shipped bundle with `coarse.onnx` grown past 50 MB by an initializer no node reads (a
/// graph that still loads and renders); returns the graph's bytes.
fn large_bundle(to: &Path) -> Vec<u8> {
    std::fs::create_dir_all(to).unwrap();
    let shipped = Path::new(env!("CARGO_MANIFEST_DIR")).join("../models/spheres");
    for f in NAMED {
        std::fs::copy(shipped.join(f), to.join(f)).unwrap();
    }
    let mut model = ModelProto::decode(&std::fs::read(shipped.join("coarse.onnx")).unwrap()[..]).unwrap();
    let values = 13_000_000usize;
    // Values that differ from byte to byte, so a misplaced or repeated chunk cannot compare equal.
    let raw_data = (0..values as u32).flat_map(|i| (i.wrapping_mul(2_654_435_761) as f32 * 1e-9).to_le_bytes()).collect();
    model.graph.as_mut().unwrap().initializer.push(TensorProto { name: "padding".into(), data_type: data_type::FLOAT, dims: vec![values as i64], raw_data, ..Default::default() });
    let bytes = model.encode_to_vec();
    assert!(bytes.len() >= 50_000_000, "{} bytes", bytes.len());
    std::fs::write(to.join("coarse.onnx"), &bytes).unwrap();
    bytes
}

/// Read one HTTP/1.1 response from `stream` (sent with `Connection: close`) and check, a chunk
/// at a time, that it is 200 with exactly `expected` as its body.
fn check_streamed(stream: TcpStream, expected: &[u8]) -> Result<(), String> {
    let mut reader = BufReader::new(stream);
    let mut head = String::new();
    loop {
        let mut line = String::new();
        if reader.read_line(&mut line).map_err(|e| e.to_string())? == 0 {
            return Err(format!("the response ended in its headers: {head}"));
        }
        if line == "\r\n" {
            break;
        }
        head.push_str(&line.to_lowercase());
    }
    if !head.starts_with("http/1.1 200") || !head.contains(&format!("content-length: {}\r\n", expected.len())) {
        return Err(format!("not a 200 with the file's length: {head}"));
    }
    let mut at = 0;
    let mut chunk = vec![0; 1 << 16];
    loop {
        let n = reader.read(&mut chunk).map_err(|e| format!("after {at} bytes: {e}"))?;
        if n == 0 {
            break;
        }
        if at + n > expected.len() || chunk[..n] != expected[at..at + n] {
            return Err(format!("the bytes at {at}..{} differ from the file's", at + n));
        }
        at += n;
    }
    if at != expected.len() {
        return Err(format!("{at} bytes, the file has {}", expected.len()));
    }
    Ok(())
}

/// A process's peak resident memory (VmHWM), in bytes.
fn peak_rss(pid: u32) -> u64 {
    let status = std::fs::read_to_string(format!("/proc/{pid}/status")).unwrap();
    let kb: u64 = status.lines().find_map(|l| l.strip_prefix("VmHWM:")).and_then(|v| v.trim().strip_suffix("kB")).unwrap().trim().parse().unwrap();
    kb * 1024
}

#[test]
fn parallel_requests_for_a_large_graph_keep_the_server_memory_bounded() {
    let dir = tempfile::tempdir().unwrap();
    let (viewer, _) = site(dir.path());
    let bundle = dir.path().join("large");
    let graph = std::sync::Arc::new(large_bundle(&bundle));
    // It is a bundle that loads: nerf-render renders a view of it.
    let out = Command::new(env!("CARGO_BIN_EXE_nerf-render"))
        .args(["--bundle", bundle.to_str().unwrap(), "--split", "test", "--limit", "1", "--width", "8", "--threads", "1", "--out", dir.path().join("frames").to_str().unwrap()])
        .output()
        .unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));

    let server = start(&bundle, &viewer);
    let before = peak_rss(server.child.id());
    // 16 requests sent before any response is read, then read side by side: a server that
    // holds each whole file in memory until it is sent would hold 16 × 52 MB.
    let requests = 16;
    let sent = std::sync::Arc::new(std::sync::Barrier::new(requests));
    let clients: Vec<_> = (0..requests)
        .map(|_| {
            let (graph, sent, address) = (graph.clone(), sent.clone(), server.address.clone());
            std::thread::spawn(move || {
                let mut stream = TcpStream::connect(&address).unwrap();
                write!(stream, "GET /bundle/coarse.onnx HTTP/1.1\r\nHost: {address}\r\nConnection: close\r\n\r\n").unwrap();
                sent.wait();
                std::thread::sleep(Duration::from_millis(500));
                check_streamed(stream, &graph)
            })
        })
        .collect();
    for (k, client) in clients.into_iter().enumerate() {
        client.join().unwrap().unwrap_or_else(|e| panic!("request {k}: {e}"));
    }
    let peak = peak_rss(server.child.id());
    eprintln!("server peak RSS: {:.1} MB before the requests, {:.1} MB after {requests} parallel requests for a {:.1} MB graph", before as f64 / 1e6, peak as f64 / 1e6, graph.len() as f64 / 1e6);
    assert!(peak < 100_000_000, "the server's peak RSS reached {:.1} MB serving {requests} parallel requests for a {:.1} MB graph", peak as f64 / 1e6, graph.len() as f64 / 1e6);
}
