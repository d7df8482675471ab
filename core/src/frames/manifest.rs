//! The record each part of a render split across processes or machines ([`Shard`], `--shard
//! i/n`) keeps of what it finished, so that a killed part resumes (`--skip-existing`) and a merge
//! assembles the GIF, `metrics.json` and contact sheet of all parts ([`super::merge`]).
//!
//! Part `i` of `n` renders a contiguous range of the frames (part 0 the first ones). Every render,
//! split or not, keeps a manifest per part in `<out>/.shards/shard-<i>-of-<n>.json`, rewritten
//! atomically after each frame (a whole render removes it when it has finished, unless asked to
//! `--skip-existing`): which frames the whole render has (a fingerprint of their names,
//! cameras and poses), which of them this part finished and their metrics. A frame's files are
//! written (atomically) before its manifest entry, so whatever a killed part recorded is on disk.

use super::spec::{FrameSpec, GifSpec, SHARDS_DIR, SHEET_VIEWS, Shard};
use crate::error::{Error, Result};
use crate::io::atomic::write_atomic;
use crate::io::limits::{self, MAX_FRAMES};
use crate::render::metrics::ImageMetrics;
use serde::{Deserialize, Deserializer, Serialize};
use std::collections::HashMap;
use std::ops::Range;
use std::path::{Path, PathBuf};

/// Metrics of a finished frame as a manifest keeps them: f64 holds each f32 exactly, so the
/// merged `metrics.json` is the one a single process writes. Non-finite values (an exact frame's
/// infinite PSNR) are stored as `null` and read back as NaN, as in `metrics.json`.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct RecordedMetrics {
    /// PSNR in dB.
    #[serde(deserialize_with = "f64_or_nan")]
    pub psnr: f64,
    /// SSIM.
    #[serde(deserialize_with = "f64_or_nan")]
    pub ssim: f64,
}

fn f64_or_nan<'de, D: Deserializer<'de>>(d: D) -> std::result::Result<f64, D::Error> {
    Ok(Option::<f64>::deserialize(d)?.unwrap_or(f64::NAN))
}

/// A finished frame.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct FrameRecord {
    /// Its index in the whole render.
    pub index: usize,
    /// Its file stem.
    pub name: String,
    /// Its metrics, when the render's frames have ground truth.
    pub metrics: Option<RecordedMetrics>,
}

impl FrameRecord {
    /// The metrics as `metrics.json` lists them (`None` without ground truth).
    pub fn image_metrics(&self) -> Option<ImageMetrics> {
        self.metrics.map(|m| ImageMetrics { name: self.name.clone(), psnr: m.psnr as f32, ssim: m.ssim as f32, lpips: None })
    }
}

/// What one part of a render is to do and has done (`.shards/shard-<i>-of-<n>.json`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ShardManifest {
    /// Which part.
    pub shard: usize,
    /// Of how many.
    pub shards: usize,
    /// Names, cameras and poses of all frames of the render, and the options that shape its
    /// files, hashed: parts of one render share it.
    pub fingerprint: String,
    /// Frames in the whole render.
    pub total: usize,
    /// This part's first frame.
    pub first: usize,
    /// This part's frames, in order.
    pub names: Vec<String>,
    /// Frames also have `<name>.npy`.
    pub raw: bool,
    /// Every frame has ground truth: `metrics.json` and the contact sheet are written.
    pub metrics: bool,
    /// The GIF of all frames, when one is written.
    pub gif: Option<GifSpec>,
    /// Finished frames, in order.
    pub done: Vec<FrameRecord>,
}

impl ShardManifest {
    /// The manifest of `shard` of a render of `frames`, nothing done yet.
    pub fn new(shard: Shard, frames: &[FrameSpec], raw: bool, metrics: bool, gif: Option<GifSpec>) -> Self {
        let range = shard.range(frames.len());
        ShardManifest {
            shard: shard.index,
            shards: shard.count,
            fingerprint: fingerprint(frames, raw, metrics, gif.as_ref()),
            total: frames.len(),
            first: range.start,
            names: frames[range].iter().map(|f| f.name.clone()).collect(),
            raw,
            metrics,
            gif,
            done: Vec::new(),
        }
    }

    /// Which part this is.
    pub fn part(&self) -> Shard {
        Shard { index: self.shard, count: self.shards }
    }

    /// Its frames' indices.
    pub fn range(&self) -> Range<usize> {
        self.first..self.first + self.names.len()
    }

    /// Whether every frame of this part is done.
    pub fn is_complete(&self) -> bool {
        self.done.len() == self.names.len()
    }

    /// The names of the frames not yet done, in order.
    pub fn missing(&self) -> Vec<&str> {
        let done: std::collections::HashSet<usize> = self.done.iter().map(|r| r.index).collect();
        self.range().filter(|k| !done.contains(k)).map(|k| self.names[k - self.first].as_str()).collect()
    }

    /// Where it is kept in the output directory `dir`.
    pub fn path(&self, dir: &Path) -> PathBuf {
        dir.join(SHARDS_DIR).join(self.part().manifest_name())
    }

    /// Remove its manifest and contact-sheet rows from `dir/.shards/`, and the folder once it is
    /// empty: a whole render that finished needs them no more. Best effort (what is left only
    /// costs a rerun with `--skip-existing` nothing).
    pub fn remove(&self, dir: &Path) {
        for k in self.first..(self.first + self.names.len()).min(SHEET_VIEWS) {
            let _ = std::fs::remove_file(sheet_row_path(dir, &self.fingerprint, k));
        }
        let _ = std::fs::remove_file(self.path(dir));
        let _ = std::fs::remove_dir(dir.join(SHARDS_DIR));
    }

    /// Write it (atomically) into `dir/.shards/` (created if missing).
    pub fn write(&self, dir: &Path) -> Result<()> {
        let folder = dir.join(SHARDS_DIR);
        std::fs::create_dir_all(&folder).map_err(|e| Error::io(&folder, e))?;
        let path = self.path(dir);
        let text = serde_json::to_string_pretty(self).map_err(|source| Error::Json { path: path.clone(), source })?;
        write_atomic(&path, text.as_bytes())
    }

    /// Read one and check that it is consistent: the part within its count, its range the
    /// part's share of `total`, its finished frames in its range, in order, with its names, and
    /// every file name it gives (frames, the GIF) a plain name inside the output directory.
    pub fn read(path: &Path) -> Result<Self> {
        let text = limits::read_json_text(path)?;
        let m: ShardManifest = serde_json::from_str(&text).map_err(|source| Error::Json { path: path.to_path_buf(), source })?;
        let part = Shard::new(m.shard, m.shards).map_err(|e| Error::invalid(path, format!("shard {e}")))?;
        limits::check_count(m.total.max(1), MAX_FRAMES, "frames", limits::Origin::Field(path, "total"))?;
        if part.range(m.total) != m.range() {
            return Err(Error::invalid(
                path,
                format!("frames {:?} are not shard {part}'s share {:?} of {} frames", m.range(), part.range(m.total), m.total),
            ));
        }
        for (k, name) in m.names.iter().enumerate() {
            limits::check_plain_file_name(name, limits::Origin::Field(path, &format!("names[{k}]")))?;
        }
        if let Some(gif) = &m.gif {
            limits::check_plain_file_name(&gif.file, limits::Origin::Field(path, "gif.file"))?;
        }
        let mut next = m.first;
        for (k, r) in m.done.iter().enumerate() {
            if !(r.index >= next && m.range().contains(&r.index) && m.names[r.index - m.first] == r.name) {
                return Err(Error::invalid(path, format!("done[{k}]: frame {} {:?} is not one of this shard's frames, in order", r.index, r.name)));
            }
            if m.metrics != r.metrics.is_some() {
                return Err(Error::invalid(path, format!("done[{k}]: {} metrics for a render {} ground truth", if m.metrics { "no" } else { "has" }, if m.metrics { "with" } else { "without" })));
            }
            next = r.index + 1;
        }
        Ok(m)
    }
}

/// Every manifest in `dir/.shards/` (none when the folder is missing), sorted by count and index.
pub fn read_manifests(dir: &Path) -> Result<Vec<(PathBuf, ShardManifest)>> {
    let folder = dir.join(SHARDS_DIR);
    let entries = match std::fs::read_dir(&folder) {
        Ok(entries) => entries,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(Vec::new()),
        Err(e) => return Err(Error::io(&folder, e)),
    };
    let mut manifests = Vec::new();
    for entry in entries {
        let path = entry.map_err(|e| Error::io(&folder, e))?.path();
        let name = path.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default();
        if name.starts_with("shard-") && name.ends_with(".json") {
            let m = ShardManifest::read(&path)?;
            if name != m.part().manifest_name() {
                return Err(Error::invalid(&path, format!("holds shard {}, not the one its name says", m.part())));
            }
            manifests.push((path, m));
        }
    }
    manifests.sort_by_key(|(_, m)| (m.shards, m.shard));
    Ok(manifests)
}

/// The frames finished by any part of the render with `fingerprint` recorded in `dir`, by index.
pub fn finished_frames(dir: &Path, fingerprint: &str) -> Result<HashMap<usize, FrameRecord>> {
    Ok(read_manifests(dir)?
        .into_iter()
        .filter(|(_, m)| m.fingerprint == fingerprint)
        .flat_map(|(_, m)| m.done)
        .map(|r| (r.index, r))
        .collect())
}

/// The contact-sheet row of frame `index` of the render with `fingerprint`, in `dir/.shards/`.
pub fn sheet_row_path(dir: &Path, fingerprint: &str, index: usize) -> PathBuf {
    dir.join(SHARDS_DIR).join(format!("sheet-{fingerprint}-{index}.png"))
}

/// 64-bit FNV-1a, in hex, of every frame's name, camera and pose and of the options that shape
/// the files (`raw`, ground truth, the GIF): deterministic across processes and machines.
pub fn fingerprint(frames: &[FrameSpec], raw: bool, metrics: bool, gif: Option<&GifSpec>) -> String {
    let mut hash: u64 = 0xcbf2_9ce4_8422_2325;
    let mut feed = |text: &str| {
        for b in text.bytes().chain([0u8]) {
            hash = (hash ^ b as u64).wrapping_mul(0x0100_0000_01b3);
        }
    };
    feed(&format!("raw {raw} metrics {metrics} gif {gif:?}"));
    for f in frames {
        feed(&format!("{} {:?} {:?}", f.name, f.camera, f.pose));
    }
    format!("{hash:016x}")
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::camera::{Intrinsics, PinholeCamera, Pose};

    fn frames(n: usize) -> Vec<FrameSpec> {
        let k = PinholeCamera::from(Intrinsics { width: 2, height: 2, focal: 2.0 });
        FrameSpec::orbit(&k, &Pose::orbit(n))
    }

    #[test]
    fn manifests_round_trip_and_refuse_what_does_not_fit() {
        let dir = tempfile::tempdir().unwrap();
        let all = frames(10);
        let gif = GifSpec { file: "orbit.gif".into(), delay_ms: 100 };
        let mut m = ShardManifest::new(Shard::new(1, 3).unwrap(), &all, false, true, Some(gif.clone()));
        assert_eq!((m.first, m.names.as_slice()), (3, &["frame_003".to_string(), "frame_004".into(), "frame_005".into()][..]));
        // An exact frame: infinite PSNR is kept as null and read back as NaN.
        m.done.push(FrameRecord { index: 3, name: "frame_003".into(), metrics: Some(RecordedMetrics { psnr: f64::INFINITY, ssim: 1.0 }) });
        m.done.push(FrameRecord { index: 5, name: "frame_005".into(), metrics: Some(RecordedMetrics { psnr: 31.25, ssim: 0.5 }) });
        m.write(dir.path()).unwrap();
        let path = dir.path().join(".shards/shard-1-of-3.json");
        let back = ShardManifest::read(&path).unwrap();
        assert!(back.done[0].metrics.unwrap().psnr.is_nan());
        assert_eq!((back.done[1].clone(), back.missing()), (m.done[1].clone(), vec!["frame_004"]));
        assert!(!back.is_complete());
        assert_eq!(finished_frames(dir.path(), &m.fingerprint).unwrap().len(), 2);
        assert!(finished_frames(dir.path(), "another render").unwrap().is_empty());
        // Another render of the same views with other files has another fingerprint.
        assert_ne!(fingerprint(&all, true, true, Some(&gif)), m.fingerprint);
        assert_ne!(fingerprint(&all[..9], false, true, Some(&gif)), m.fingerprint);
        // Hand-edited manifests are refused, naming the file and the problem.
        let edit = |f: &dyn Fn(&mut serde_json::Value)| {
            let mut v: serde_json::Value = serde_json::to_value(&m).unwrap();
            f(&mut v);
            std::fs::write(&path, v.to_string()).unwrap();
            ShardManifest::read(&path).unwrap_err().to_string()
        };
        let e = edit(&|v| v["shard"] = 3.into());
        assert!(e.contains("shard-1-of-3.json") && e.contains("0 to 2"), "{e}");
        let e = edit(&|v| v["first"] = 4.into());
        assert!(e.contains("not shard 1/3's share"), "{e}");
        let e = edit(&|v| v["done"][1]["index"] = 9.into());
        assert!(e.contains("done[1]"), "{e}");
        let e = edit(&|v| v["done"][0]["metrics"] = serde_json::Value::Null);
        assert!(e.contains("done[0]: no metrics"), "{e}");
        // A merge writes the GIF and reads the frames it names: only inside the directory.
        let e = edit(&|v| v["gif"]["file"] = "../../elsewhere.gif".into());
        assert!(e.contains("gif.file: \"../../elsewhere.gif\" is not a plain file name"), "{e}");
        let e = edit(&|v| v["names"][2] = "/etc/passwd".into());
        assert!(e.contains("names[2]"), "{e}");
        std::fs::write(&path, "{").unwrap();
        assert!(ShardManifest::read(&path).unwrap_err().to_string().contains("invalid JSON"));
        // A manifest under another part's name.
        let mut other = m.clone();
        other.done.clear();
        other.write(dir.path()).unwrap();
        std::fs::rename(&path, dir.path().join(".shards/shard-2-of-3.json")).unwrap();
        let e = read_manifests(dir.path()).unwrap_err().to_string();
        assert!(e.contains("shard-2-of-3.json: holds shard 1/3"), "{e}");
    }
}
