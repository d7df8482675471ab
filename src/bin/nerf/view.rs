//! `nerf train --serve` and `nerf view RUN`: the browser viewer on a run being trained
//! ([`nerf::live`]), served by nerf-render's server with its live route.

use anyhow::{Context, Result};
use nerf::evaluate::LoadedRun;
use nerf::export::RunScene;
use nerf::live::{latest_snapshot, read_progress, snapshot_dir, status, write_snapshot};
use nerf::run_dir::RunDir;
use nerf_runtime::serve::{Listener, Live, Site, viewer_dir};
use std::net::IpAddr;
use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex};
use std::time::Duration;

/// Seconds between two looks at a watched run's checkpoints.
const WATCH_EVERY: Duration = Duration::from_secs(2);

/// A `progress.json` older than this is a trainer that has stopped (killed): `nerf view` then
/// exports its checkpoints itself even if it wrote snapshots.
const STALE_PROGRESS_S: f64 = 30.0;

/// Where the viewer is served.
#[derive(Debug, Clone, clap::Args)]
pub struct ServeArgs {
    /// Address to serve the viewer on (default 127.0.0.1: this machine only).
    #[arg(long, default_value = "127.0.0.1")]
    pub host: IpAddr,
    /// Port to serve the viewer on (0: any free port).
    #[arg(long, default_value_t = 8000)]
    pub port: u16,
    /// The built viewer's directory (default: $NERF_VIEWER, else ~/.cache/nerf-rs/viewer).
    #[arg(long)]
    pub viewer: Option<PathBuf>,
}

/// A run served live: its status, and its snapshots by id.
struct LiveRun {
    run: RunDir,
    /// What the server is doing, for the page.
    note: Mutex<Option<String>>,
}

impl Live for LiveRun {
    fn status(&self) -> Vec<u8> {
        let note = self.note.lock().map(|n| n.clone()).unwrap_or_default();
        serde_json::to_vec(&status(&self.run, note)).expect("the status serialises")
    }

    fn snapshot(&self, id: &str) -> Option<PathBuf> {
        snapshot_dir(&self.run, id)
    }
}

/// Bind `args`' port and serve the viewer on the run `open` gives from a thread; returns the
/// page's URL. A missing viewer or a port in use is an error before the run is touched.
fn start(args: &ServeArgs, open: impl FnOnce() -> nerf::Result<RunDir>) -> Result<(String, Arc<LiveRun>)> {
    let viewer = args.viewer.clone().or_else(viewer_dir).context("no viewer directory: set --viewer or $NERF_VIEWER")?;
    let site = Site::new(&viewer, Vec::new())?;
    let listener = Listener::bind(args.host, args.port)?;
    let live = Arc::new(LiveRun { run: open()?, note: Mutex::new(None) });
    let site = site.with_live(live.clone());
    let url = listener.url();
    std::thread::Builder::new()
        .name("viewer".into())
        .spawn(move || {
            if let Err(e) = listener.serve(site) {
                eprintln!("warning: the viewer stopped: {e}");
            }
        })
        .context("starting the viewer's thread")?;
    println!("viewer: {url}");
    use std::io::Write;
    std::io::stdout().flush().ok();
    Ok((url, live))
}

/// `nerf train --serve`: start the viewer on the run at `out` (created if new); returns its URL.
pub fn serve_training(out: &Path, args: &ServeArgs) -> Result<String> {
    Ok(start(args, || RunDir::create(out))?.0)
}

/// Serve until the process is stopped.
pub fn serve_forever() -> ! {
    loop {
        std::thread::park();
    }
}

/// `nerf view RUN`: serve the viewer on `run`, exporting a snapshot from each newer checkpoint
/// unless a live trainer writes its own; runs until stopped.
pub fn view(run: &Path, args: &ServeArgs) -> Result<()> {
    let run = RunDir::open(run)?;
    let (_, live) = start(args, || Ok(run.clone()))?;
    let mut tried = Tried::default();
    loop {
        let note = refresh(&run, &mut tried, &|note| *live.note.lock().expect("not poisoned") = Some(note));
        *live.note.lock().expect("not poisoned") = note;
        std::thread::sleep(WATCH_EVERY);
    }
}

/// The last checkpoint `nerf view` exported, and why it failed if it did.
#[derive(Default)]
struct Tried {
    step: Option<usize>,
    failure: Option<String>,
}

/// Export the latest checkpoint of `run` as its snapshot when it is newer than the latest
/// snapshot, not already `tried`, and no live trainer writes snapshots; `busy` says what is
/// being done meanwhile. Returns what the page should be told (why there is no snapshot).
fn refresh(run: &RunDir, tried: &mut Tried, busy: &dyn Fn(String)) -> Option<String> {
    let trainer_writes = read_progress(run).is_some_and(|(p, age)| p.snapshots && !p.done && age < STALE_PROGRESS_S);
    let snapshot = latest_snapshot(run).map(|(step, _)| step);
    if trainer_writes {
        return snapshot.is_none().then(|| "waiting for the trainer's first snapshot".into());
    }
    let checkpoint = match run.latest_checkpoint() {
        Ok(Some(c)) => c,
        Ok(None) if snapshot.is_none() => return Some("no checkpoint yet: the first snapshot is exported from it".into()),
        Ok(None) => return None,
        Err(e) => return Some(e.to_string()),
    };
    let step = checkpoint.step()?;
    if tried.step == Some(step) {
        return tried.failure.clone();
    }
    if snapshot.is_some_and(|s| s >= step) {
        return None;
    }
    *tried = Tried { step: Some(step), failure: None };
    busy(format!("exporting the checkpoint of step {step}"));
    let exported = LoadedRun::open(run.root()).and_then(|loaded| {
        let scene = RunScene::read(loaded.source.as_ref());
        write_snapshot(run, loaded.step, loaded.model.as_ref(), &loaded.config, &loaded.camera, loaded.occupancy.clone(), &scene).map(|w| (loaded.step, w))
    });
    match exported {
        Ok((step, (dir, took))) => {
            println!("snapshot of step {step} from its checkpoint in {:.2} s: {}", took.as_secs_f64(), dir.display());
            None
        }
        Err(e) => {
            let failure = format!("no snapshot from the checkpoint of step {step}: {e}");
            eprintln!("warning: {failure}");
            tried.failure = Some(failure);
            tried.failure.clone()
        }
    }
}
