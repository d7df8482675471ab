//! `nerf-render --serve`: the browser viewer and one bundle over HTTP, for onnxruntime-web.
//!
//! Only files known when the server starts are served, each at one exact path: the viewer's
//! regular files at their path below the viewer directory (`/` is its `index.html`), and the
//! bundle's files at `/bundle/<name>`: `scene.json` and the files it names, once the bundle
//! loads ([`bundle_files`]; a folder that is not a loadable bundle is refused, or, when asked,
//! served with its `scene.json` alone so that the page shows why). A request path is looked up
//! as it arrives, never decoded or joined to a directory, so `..`, encoded variants and
//! absolute paths cannot reach anything else. GET and HEAD only; files stream from disk in
//! chunks, with their length from the file's metadata. Every response carries the
//! cross-origin isolation headers (COOP same-origin, COEP require-corp, CORP same-origin) that
//! multi-threaded WASM needs.
//!
//! A site may also be live ([`Live`]: a run being trained, `nerf train --serve`, `nerf view`):
//! `/live/status.json` is then the run's progress, made at each request, and
//! `/live/<id>/<name>` the files of its snapshot `<id>` as [`bundle_files`] lists them, looked up
//! at each request (snapshots come and go as training goes); the page finds the newest id in
//! the status.

use crate::error::{Result, RuntimeError};
use axum::body::{Body, Bytes, HttpBody};
use axum::http::{HeaderValue, Method, Request, Response, StatusCode, header};
use http_body::{Frame, SizeHint};
use nerf_bundle::SCENE_FILE;
use nerf_bundle::graph::MAX_GRAPH_BYTES;
use nerf_core::io::limits::{self, Origin};
use std::collections::HashMap;
use std::net::{IpAddr, SocketAddr};
use std::path::{Path, PathBuf};
use std::pin::Pin;
use std::sync::Arc;
use std::task::{Context, Poll, ready};
use tokio::io::{AsyncRead, ReadBuf};

/// The environment variable naming the viewer directory (default: `$NERF_HOME/viewer`, where
/// `scripts/setup.sh` installs the built viewer).
pub const VIEWER_ENV: &str = "NERF_VIEWER";

/// Most files served from the viewer directory (a built viewer has a few dozen).
const MAX_VIEWER_FILES: usize = 1000;

/// Where the viewer is: `$NERF_VIEWER`, else `$NERF_HOME/viewer` (default
/// `~/.cache/nerf-rs/viewer`).
pub fn viewer_dir() -> Option<PathBuf> {
    if let Some(dir) = std::env::var_os(VIEWER_ENV).filter(|v| !v.is_empty()) {
        return Some(PathBuf::from(dir));
    }
    let home = std::env::var_os("NERF_HOME").map(PathBuf::from).or_else(|| std::env::var_os("HOME").map(|h| Path::new(&h).join(".cache/nerf-rs")))?;
    Some(home.join("viewer"))
}

/// A bundle's files as served: (name below `/bundle/`, path).
pub type BundleFiles = Vec<(String, PathBuf)>;

/// The files of the bundle in `dir` once it loads: `scene.json` and every file it names (each
/// graph, the occupancy grid), nothing else. It loads when `scene.json` reads and passes its
/// checks, each graph is a regular file inside `dir` within [`MAX_GRAPH_BYTES`], and the
/// occupancy grid reads and matches `scene.json`; the graphs are not decoded (the page does).
/// The error names the folder and why it is not served.
pub fn bundle_files(dir: &Path) -> Result<BundleFiles> {
    let refuse = |problem: String| RuntimeError::bundle(dir, format!("not a bundle that loads: {problem}"));
    if !dir.is_dir() {
        return Err(RuntimeError::bundle(dir, "no such bundle directory"));
    }
    let scene_path = scene_file(dir).map_err(|e| refuse(e.to_string()))?;
    let scene = nerf_bundle::read_scene(dir).map_err(|e| refuse(e.to_string()))?;
    let mut files = vec![(SCENE_FILE.to_string(), scene_path)];
    for g in scene.graph_files() {
        let path = nerf_bundle::bundle_file(dir, g.file, g.key).map_err(|e| refuse(e.to_string()))?;
        // bundle_file leaves a missing file to the reader: here it is refused now.
        let meta = std::fs::metadata(&path).map_err(|e| refuse(nerf_core::Error::io(&path, e).to_string()))?;
        if meta.len() > MAX_GRAPH_BYTES {
            return Err(refuse(format!("{}: {} bytes is more than the limit of {MAX_GRAPH_BYTES} for a graph", path.display(), meta.len())));
        }
        files.push((g.file.to_string(), path));
    }
    if let Some(o) = &scene.occupancy {
        nerf_bundle::read_occupancy(dir, &scene).map_err(|e| refuse(e.to_string()))?;
        files.push((o.file.clone(), nerf_bundle::bundle_file(dir, &o.file, "occupancy.file").map_err(|e| refuse(e.to_string()))?));
    }
    Ok(files)
}

/// `dir/scene.json` when it is a regular file inside `dir` within the JSON size limit (served
/// alone for a bundle that does not load, so that the page shows why).
pub fn scene_file(dir: &Path) -> Result<PathBuf> {
    let path = limits::file_in_dir(dir, SCENE_FILE, Origin::Field(dir, "the bundle"))?;
    let meta = std::fs::metadata(&path).map_err(|e| nerf_core::Error::io(&path, e))?;
    if meta.len() > limits::MAX_JSON_BYTES {
        return Err(RuntimeError::bundle(&path, format!("{} bytes is more than the limit of {} for this file", meta.len(), limits::MAX_JSON_BYTES)));
    }
    Ok(path)
}

/// What a live site serves beside its fixed files: a run's progress and its latest snapshot.
pub trait Live: Send + Sync {
    /// The body of `/live/status.json` (a JSON object; its fields are the page's business).
    fn status(&self) -> Vec<u8>;
    /// The bundle directory of snapshot `id`, when it is one of the run's now (`id` is a plain
    /// name: no `/`, no leading dot).
    fn snapshot(&self, id: &str) -> Option<PathBuf>;
}

/// The files served, by request path, and the live run, if any.
#[derive(Default)]
pub struct Site {
    files: HashMap<String, PathBuf>,
    live: Option<Arc<dyn Live>>,
}

impl std::fmt::Debug for Site {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Site").field("files", &self.files).field("live", &self.live.is_some()).finish()
    }
}

impl Site {
    /// The viewer's files (recursively, regular files only, no hidden names) and `bundle`, each
    /// at `/bundle/<name>`.
    pub fn new(viewer: &Path, bundle: BundleFiles) -> Result<Self> {
        if !viewer.join("index.html").is_file() {
            return Err(RuntimeError::Other(format!(
                "no viewer at {} (no index.html): run `bash scripts/setup.sh`, which builds it with npm and installs it there, or set {VIEWER_ENV}",
                viewer.display()
            )));
        }
        let mut site = Site::default();
        site.add_tree(viewer, "", 0)?;
        if let Some(index) = site.files.get("/index.html").cloned() {
            site.files.insert("/".into(), index);
        }
        for (name, path) in bundle {
            site.files.insert(format!("/bundle/{name}"), path);
        }
        Ok(site)
    }

    fn add_tree(&mut self, dir: &Path, prefix: &str, depth: usize) -> Result<()> {
        let err = |e: std::io::Error| RuntimeError::Other(format!("{}: {e}", dir.display()));
        for entry in std::fs::read_dir(dir).map_err(err)? {
            let entry = entry.map_err(err)?;
            let name = entry.file_name().to_string_lossy().into_owned();
            let kind = entry.file_type().map_err(err)?;
            if !plain(&name) {
                continue;
            }
            if kind.is_file() {
                if self.files.len() >= MAX_VIEWER_FILES {
                    return Err(RuntimeError::Other(format!("{}: more than {MAX_VIEWER_FILES} files: not a built viewer", dir.display())));
                }
                self.files.insert(format!("{prefix}/{name}"), entry.path());
            } else if kind.is_dir() && depth < 8 {
                self.add_tree(&entry.path(), &format!("{prefix}/{name}"), depth + 1)?;
            }
        }
        Ok(())
    }

    /// The site serving `live` under `/live/` too.
    pub fn with_live(mut self, live: Arc<dyn Live>) -> Self {
        self.live = Some(live);
        self
    }

    /// The file served at `path`, if any (a live snapshot's file: when that snapshot is there
    /// now and loads as a bundle).
    pub fn file(&self, path: &str) -> Option<PathBuf> {
        if let Some(file) = self.files.get(path) {
            return Some(file.clone());
        }
        let (id, name) = path.strip_prefix("/live/")?.split_once('/')?;
        if !plain(id) || !plain(name) {
            return None;
        }
        let dir = self.live.as_ref()?.snapshot(id)?;
        // The snapshot's own files only, as for `/bundle/`; one that does not load serves nothing.
        bundle_files(&dir).ok()?.into_iter().find(|(n, _)| n == name).map(|(_, p)| p)
    }

    /// Every file served, by request path (`/` once, as `/index.html`), sorted by path.
    pub fn files(&self) -> Vec<(&str, &Path)> {
        let mut files: Vec<_> = self.files.iter().filter(|(p, _)| p.as_str() != "/").map(|(p, f)| (p.as_str(), f.as_path())).collect();
        files.sort();
        files
    }
}

/// A name served as it is: printable ASCII letters, digits and `._-`, not starting with a dot.
fn plain(name: &str) -> bool {
    !name.is_empty() && !name.starts_with('.') && name.bytes().all(|b| b.is_ascii_alphanumeric() || b"._-".contains(&b))
}

/// The content type of a file served under `path`.
pub fn content_type(path: &str) -> &'static str {
    match path.rsplit_once('.').map(|(_, ext)| ext) {
        _ if path == "/" => "text/html; charset=utf-8",
        Some("html") => "text/html; charset=utf-8",
        Some("js" | "mjs") => "text/javascript; charset=utf-8",
        Some("css") => "text/css; charset=utf-8",
        Some("json") => "application/json",
        Some("wasm") => "application/wasm",
        Some("png") => "image/png",
        Some("svg") => "image/svg+xml",
        Some("ico") => "image/x-icon",
        _ => "application/octet-stream",
    }
}

/// Bytes read from disk per piece of a response body.
const CHUNK_BYTES: u64 = 64 << 10;

/// The first `left` bytes of a file as a response body, read a chunk of [`CHUNK_BYTES`] at a
/// time as the connection takes them, so a response holds a chunk or two in memory whatever
/// the file's size. A file that is shorter than when the response began ends it with an error
/// (the connection is cut, never a short body under the promised length); one that grew is
/// sent only up to that length.
struct FileBody {
    file: tokio::fs::File,
    left: u64,
}

impl HttpBody for FileBody {
    type Data = Bytes;
    type Error = std::io::Error;

    fn poll_frame(self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<Option<std::io::Result<Frame<Bytes>>>> {
        let this = self.get_mut();
        if this.left == 0 {
            return Poll::Ready(None);
        }
        let mut chunk = vec![0; CHUNK_BYTES.min(this.left) as usize];
        let mut buf = ReadBuf::new(&mut chunk);
        ready!(Pin::new(&mut this.file).poll_read(cx, &mut buf))?;
        let n = buf.filled().len();
        if n == 0 {
            return Poll::Ready(Some(Err(std::io::Error::new(std::io::ErrorKind::UnexpectedEof, "the file is shorter than when its response began"))));
        }
        chunk.truncate(n);
        this.left -= n as u64;
        Poll::Ready(Some(Ok(Frame::data(Bytes::from(chunk)))))
    }

    fn is_end_stream(&self) -> bool {
        self.left == 0
    }

    fn size_hint(&self) -> SizeHint {
        SizeHint::with_exact(self.left)
    }
}

/// The body and length of `file`: streamed from disk for GET, empty for HEAD (the length is
/// its metadata's either way). Only regular files: a FIFO put in a file's place would block.
async fn file_body(file: &Path, head: bool) -> std::io::Result<(Body, u64)> {
    let not_regular = || std::io::Error::other("not a regular file");
    let meta = tokio::fs::metadata(file).await?;
    if !meta.is_file() {
        return Err(not_regular());
    }
    if head {
        return Ok((Body::empty(), meta.len()));
    }
    let file = tokio::fs::File::open(file).await?;
    let meta = file.metadata().await?;
    if !meta.is_file() {
        return Err(not_regular());
    }
    Ok((Body::new(FileBody { file, left: meta.len() }), meta.len()))
}

/// The path of a live site's status.
pub const LIVE_STATUS: &str = "/live/status.json";

/// The response to `method path` (the path as requested, query excluded).
pub async fn respond(site: &Site, method: &Method, path: &str) -> Response<Body> {
    let text = "text/plain; charset=utf-8";
    let (status, body, kind, length) = if method != Method::GET && method != Method::HEAD {
        (StatusCode::METHOD_NOT_ALLOWED, Body::from("only GET and HEAD\n"), text, None)
    } else if let (LIVE_STATUS, Some(live)) = (path, &site.live) {
        let status = live.status();
        let length = status.len() as u64;
        let body = if method == Method::HEAD { Body::empty() } else { Body::from(status) };
        (StatusCode::OK, body, content_type(path), Some(length))
    } else {
        match site.file(path) {
            None => (StatusCode::NOT_FOUND, Body::from("not found\n"), text, None),
            Some(file) => match file_body(&file, method == Method::HEAD).await {
                Ok((body, length)) => (StatusCode::OK, body, content_type(path), Some(length)),
                Err(e) => {
                    eprintln!("{}: {e}", file.display());
                    (StatusCode::NOT_FOUND, Body::from("not found\n"), text, None)
                }
            },
        }
    };
    let mut response = Response::new(body);
    *response.status_mut() = status;
    let headers = response.headers_mut();
    headers.insert(header::CONTENT_TYPE, HeaderValue::from_static(kind));
    if let Some(length) = length {
        headers.insert(header::CONTENT_LENGTH, HeaderValue::from(length));
    }
    headers.insert("cross-origin-opener-policy", HeaderValue::from_static("same-origin"));
    headers.insert("cross-origin-embedder-policy", HeaderValue::from_static("require-corp"));
    headers.insert("cross-origin-resource-policy", HeaderValue::from_static("same-origin"));
    headers.insert("x-content-type-options", HeaderValue::from_static("nosniff"));
    headers.insert(header::CACHE_CONTROL, HeaderValue::from_static("no-cache"));
    if status == StatusCode::METHOD_NOT_ALLOWED {
        headers.insert(header::ALLOW, HeaderValue::from_static("GET, HEAD"));
    }
    response
}

/// Serve `site` on `host:port` (port 0: any free port) until the process ends; prints the URL
/// to open (then flushes stdout, so a script can read it).
pub fn serve(site: Site, host: IpAddr, port: u16) -> Result<()> {
    let listener = Listener::bind(host, port)?;
    println!("viewer: {}", listener.url());
    use std::io::Write;
    std::io::stdout().flush().ok();
    listener.serve(site)
}

/// A port bound for the viewer, not yet served: binding first lets a command that serves
/// beside other work (`nerf train --serve`) fail on a taken port before it starts.
#[derive(Debug)]
pub struct Listener {
    listener: std::net::TcpListener,
    address: SocketAddr,
}

impl Listener {
    /// Listen on `host:port` (port 0: any free port); a port in use or an address that is not
    /// this machine's is an error naming it. A host other than loopback is warned about.
    pub fn bind(host: IpAddr, port: u16) -> Result<Self> {
        if !host.is_loopback() {
            eprintln!("warning: serving on {host}, reachable from other machines: the bundle's files can be read by anyone who can reach this address");
        }
        let listener = std::net::TcpListener::bind(SocketAddr::new(host, port)).map_err(|e| RuntimeError::Other(format!("cannot listen on {host}:{port}: {e}")))?;
        listener.set_nonblocking(true).map_err(|e| RuntimeError::Other(format!("{host}:{port}: {e}")))?;
        let address = listener.local_addr().map_err(|e| RuntimeError::Other(e.to_string()))?;
        Ok(Listener { listener, address })
    }

    /// The page's URL.
    pub fn url(&self) -> String {
        let host = match self.address.ip() {
            IpAddr::V6(ip) => format!("[{ip}]"),
            ip => ip.to_string(),
        };
        format!("http://{host}:{}/", self.address.port())
    }

    /// Serve `site` until the process ends.
    pub fn serve(self, site: Site) -> Result<()> {
        let runtime = tokio::runtime::Builder::new_current_thread().enable_io().build().map_err(|e| RuntimeError::Other(format!("cannot start the server: {e}")))?;
        runtime.block_on(async move {
            let listener = tokio::net::TcpListener::from_std(self.listener).map_err(|e| RuntimeError::Other(format!("cannot serve on {}: {e}", self.address)))?;
            let site = Arc::new(site);
            let app = axum::Router::new().fallback(move |request: Request<Body>| {
                let site = site.clone();
                async move { respond(&site, request.method(), request.uri().path()).await }
            });
            axum::serve(listener, app).await.map_err(|e| RuntimeError::Other(format!("the server stopped: {e}")))
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// `body`'s bytes until it ends or fails, and its error if it fails.
    async fn drain(mut body: FileBody) -> (Vec<u8>, Option<std::io::Error>) {
        let mut bytes = Vec::new();
        loop {
            match std::future::poll_fn(|cx| Pin::new(&mut body).poll_frame(cx)).await {
                None => return (bytes, None),
                Some(Ok(frame)) => {
                    let data = frame.into_data().expect("data frames only");
                    assert!(data.len() as u64 <= CHUNK_BYTES, "a frame of {} bytes", data.len());
                    bytes.extend_from_slice(&data);
                }
                Some(Err(e)) => return (bytes, Some(e)),
            }
        }
    }

    #[test]
    fn a_file_body_streams_the_promised_length_in_chunks_and_fails_when_the_file_is_shorter() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("graph.onnx");
        let data: Vec<u8> = (0..200_000u32).map(|i| (i * 7 % 251) as u8).collect();
        std::fs::write(&path, &data).unwrap();
        let runtime = tokio::runtime::Builder::new_current_thread().build().unwrap();
        runtime.block_on(async {
            let path = path.as_path();
            let body = |left| async move { FileBody { file: tokio::fs::File::open(&path).await.unwrap(), left } };
            let whole = body(data.len() as u64).await;
            assert_eq!(whole.size_hint().exact(), Some(data.len() as u64));
            let (bytes, err) = drain(whole).await;
            assert!(bytes == data && err.is_none(), "{} bytes, {err:?}", bytes.len());
            // The file shrank after its length was sent: the body fails rather than end short.
            let (bytes, err) = drain(body(data.len() as u64 + 10).await).await;
            assert!(bytes == data && err.is_some_and(|e| e.kind() == std::io::ErrorKind::UnexpectedEof), "{} bytes", bytes.len());
            // The file grew: only the length sent.
            let (bytes, err) = drain(body(1000).await).await;
            assert!(bytes == data[..1000] && err.is_none(), "{} bytes, {err:?}", bytes.len());
        });
    }

    /// A run with one snapshot, `7`: a copy of `models/spheres` with a stray file beside it.
    struct OneSnapshot(PathBuf);

    impl Live for OneSnapshot {
        fn status(&self) -> Vec<u8> {
            br#"{"snapshot":"7"}"#.to_vec()
        }
        fn snapshot(&self, id: &str) -> Option<PathBuf> {
            (id == "7").then(|| self.0.clone())
        }
    }

    #[test]
    fn a_live_site_serves_the_status_and_only_the_bundle_files_of_a_snapshot_it_names() {
        let dir = tempfile::tempdir().unwrap();
        let snapshot = dir.path().join("7");
        std::fs::create_dir(&snapshot).unwrap();
        let spheres = Path::new(env!("CARGO_MANIFEST_DIR")).join("../models/spheres");
        for name in ["scene.json", "coarse.onnx", "fine.onnx", "occupancy.bin"] {
            std::fs::copy(spheres.join(name), snapshot.join(name)).unwrap();
        }
        std::fs::write(snapshot.join("notes.txt"), "not a bundle file").unwrap();
        let viewer = dir.path().join("viewer");
        std::fs::create_dir(&viewer).unwrap();
        std::fs::write(viewer.join("index.html"), "<!doctype html>").unwrap();
        let plain_site = Site::new(&viewer, Vec::new()).unwrap();
        let site = Site::new(&viewer, Vec::new()).unwrap().with_live(Arc::new(OneSnapshot(snapshot.clone())));
        let runtime = tokio::runtime::Builder::new_current_thread().build().unwrap();
        let status = |site: &Site, path: &str| runtime.block_on(respond(site, &Method::GET, path)).status();
        assert_eq!(status(&site, LIVE_STATUS), StatusCode::OK);
        assert_eq!(status(&plain_site, LIVE_STATUS), StatusCode::NOT_FOUND, "a site that is not live has no status");
        assert_eq!(site.file("/live/7/fine.onnx"), Some(snapshot.join("fine.onnx")));
        for path in ["/live/7/scene.json", "/live/7/coarse.onnx", "/live/7/occupancy.bin"] {
            assert_eq!(status(&site, path), StatusCode::OK, "{path}");
        }
        for path in ["/live/7/notes.txt", "/live/8/scene.json", "/live/7/../7/scene.json", "/live/./7/scene.json", "/live/7", "/live/7/sub/scene.json", "/live/%37/scene.json"] {
            assert_eq!(status(&site, path), StatusCode::NOT_FOUND, "{path}");
        }
        // A snapshot that stops loading (its graph gone mid-write) serves nothing.
        std::fs::remove_file(snapshot.join("coarse.onnx")).unwrap();
        assert_eq!(status(&site, "/live/7/scene.json"), StatusCode::NOT_FOUND);
    }
}
