//! `nerf-render --serve`: the browser viewer and one bundle over HTTP, for onnxruntime-web.
//!
//! Only files known when the server starts are served, each at one exact path: the viewer's
//! regular files at their path below the viewer directory (`/` is its `index.html`), and the
//! bundle's regular files at `/bundle/<name>`. A request path is looked up as it arrives, never
//! decoded or joined to a directory, so `..`, encoded variants and absolute paths cannot reach
//! anything else. GET and HEAD only. Every response carries the cross-origin isolation headers
//! (COOP same-origin, COEP require-corp, CORP same-origin) that multi-threaded WASM needs.

use crate::error::{Result, RuntimeError};
use axum::body::Body;
use axum::http::{HeaderValue, Method, Request, Response, StatusCode, header};
use std::collections::HashMap;
use std::net::{IpAddr, SocketAddr};
use std::path::{Path, PathBuf};
use std::sync::Arc;

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

/// The files served, by request path.
#[derive(Debug, Default)]
pub struct Site {
    files: HashMap<String, PathBuf>,
}

impl Site {
    /// The viewer's files (recursively, regular files only, no hidden names) and the bundle's
    /// (its top level, regular files only).
    pub fn new(viewer: &Path, bundle: &Path) -> Result<Self> {
        if !viewer.join("index.html").is_file() {
            return Err(RuntimeError::Other(format!(
                "no viewer at {} (no index.html): run `bash scripts/setup.sh`, which builds it with npm and installs it there, or set {VIEWER_ENV}",
                viewer.display()
            )));
        }
        if !bundle.is_dir() {
            return Err(RuntimeError::bundle(bundle, "no such bundle directory"));
        }
        let mut site = Site::default();
        site.add_tree(viewer, "", 0)?;
        if let Some(index) = site.files.get("/index.html").cloned() {
            site.files.insert("/".into(), index);
        }
        for entry in std::fs::read_dir(bundle).map_err(|e| RuntimeError::bundle(bundle, e.to_string()))? {
            let entry = entry.map_err(|e| RuntimeError::bundle(bundle, e.to_string()))?;
            let name = entry.file_name().to_string_lossy().into_owned();
            if plain(&name) && entry.file_type().is_ok_and(|t| t.is_file()) {
                site.files.insert(format!("/bundle/{name}"), entry.path());
            }
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

    /// The file served at `path`, if any.
    pub fn file(&self, path: &str) -> Option<&Path> {
        self.files.get(path).map(PathBuf::as_path)
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

/// The response to `method path` (the path as requested, query excluded).
pub async fn respond(site: &Site, method: &Method, path: &str) -> Response<Body> {
    let (status, body, kind) = if method != Method::GET && method != Method::HEAD {
        (StatusCode::METHOD_NOT_ALLOWED, Body::from("only GET and HEAD\n"), "text/plain; charset=utf-8")
    } else {
        match site.file(path) {
            None => (StatusCode::NOT_FOUND, Body::from("not found\n"), "text/plain; charset=utf-8"),
            Some(file) => match tokio::fs::read(file).await {
                // For HEAD, hyper sends the headers (with the length) and not the body.
                Ok(bytes) => (StatusCode::OK, Body::from(bytes), content_type(path)),
                Err(e) => {
                    eprintln!("{}: {e}", file.display());
                    (StatusCode::NOT_FOUND, Body::from("not found\n"), "text/plain; charset=utf-8")
                }
            },
        }
    };
    let mut response = Response::new(body);
    *response.status_mut() = status;
    let headers = response.headers_mut();
    headers.insert(header::CONTENT_TYPE, HeaderValue::from_static(kind));
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
    if !host.is_loopback() {
        eprintln!("warning: serving on {host}, reachable from other machines: the bundle's files can be read by anyone who can reach this address");
    }
    let runtime = tokio::runtime::Builder::new_current_thread().enable_io().build().map_err(|e| RuntimeError::Other(format!("cannot start the server: {e}")))?;
    runtime.block_on(async move {
        let listener = tokio::net::TcpListener::bind(SocketAddr::new(host, port)).await.map_err(|e| RuntimeError::Other(format!("cannot listen on {host}:{port}: {e}")))?;
        let address = listener.local_addr().map_err(|e| RuntimeError::Other(e.to_string()))?;
        let host = match address.ip() {
            IpAddr::V6(ip) => format!("[{ip}]"),
            ip => ip.to_string(),
        };
        println!("viewer: http://{host}:{}/", address.port());
        use std::io::Write;
        std::io::stdout().flush().ok();
        let site = Arc::new(site);
        let app = axum::Router::new().fallback(move |request: Request<Body>| {
            let site = site.clone();
            async move { respond(&site, request.method(), request.uri().path()).await }
        });
        axum::serve(listener, app).await.map_err(|e| RuntimeError::Other(format!("the server stopped: {e}")))
    })
}
