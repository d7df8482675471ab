//! What the files of [`super`] share: one frame to render ([`FrameSpec`]), the part of the frames
//! one process takes ([`Shard`]), the GIF ([`GifSpec`]), the names of the files a render leaves in
//! its output directory, and what a render or a merge reports ([`FramesReport`]).
//!
//! Plain values only: the views, the writer, the manifests and the merge all import this file,
//! and it imports none of them.

use crate::camera::{PinholeCamera, Pose};
use crate::dataset::SplitData;
use crate::error::{Error, Result};
use crate::io::limits::MAX_FRAMES;
use crate::render::metrics::EvalReport;
use serde::{Deserialize, Serialize};
use std::ops::Range;
use std::path::{Path, PathBuf};
use std::str::FromStr;

/// File name of the metrics written when the frames have ground truth.
pub const METRICS_FILE: &str = "metrics.json";
/// File name of the contact sheet written with metrics: ground truth | render | depth, one row
/// per view, for the first [`SHEET_VIEWS`] views (at most [`SHEET_MAX_WIDTH`] pixels wide each).
pub const SHEET_FILE: &str = "contact_sheet.png";
/// Views on the contact sheet.
pub const SHEET_VIEWS: usize = 4;
/// Widest image on the contact sheet: wider views are shrunk by an integer factor.
pub const SHEET_MAX_WIDTH: u32 = 256;
/// File name of the orbit animation.
pub const GIF_FILE: &str = "orbit.gif";
/// Milliseconds per GIF frame.
pub const GIF_DELAY_MS: u16 = 100;
/// Folder of an output directory holding the parts' manifests and contact-sheet rows.
pub const SHARDS_DIR: &str = ".shards";

/// One image to render.
#[derive(Debug, Clone, PartialEq)]
pub struct FrameSpec {
    /// Output file stem (`r_0`, `frame_007`).
    pub name: String,
    /// Camera.
    pub camera: PinholeCamera,
    /// Camera-to-world pose.
    pub pose: Pose,
    /// Ground truth (row-major RGB, white background) for metrics.
    pub target: Option<Vec<[f32; 3]>>,
}

impl FrameSpec {
    /// The orbit frames `frame_000`, `frame_001`, … for `poses`.
    pub fn orbit(camera: &PinholeCamera, poses: &[Pose]) -> Vec<FrameSpec> {
        poses
            .iter()
            .enumerate()
            .map(|(k, pose)| FrameSpec { name: format!("frame_{k:03}"), camera: *camera, pose: *pose, target: None })
            .collect()
    }

    /// A split's views, named after their images, with the images as targets when loaded.
    pub fn from_split(data: SplitData) -> Vec<FrameSpec> {
        data.views.into_iter().map(|v| FrameSpec { name: v.name, camera: v.camera, pose: v.pose, target: v.image }).collect()
    }
}

/// The GIF a render writes: file name and the time each frame is shown.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct GifSpec {
    /// File name inside the output directory.
    pub file: String,
    /// Milliseconds per frame.
    pub delay_ms: u16,
}

/// Part `index` of `count` (0-based) of a render.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Shard {
    /// Which part, `0..count`.
    pub index: usize,
    /// How many parts, `1..=MAX_FRAMES`.
    pub count: usize,
}

impl Shard {
    /// The whole render in one process.
    pub const WHOLE: Shard = Shard { index: 0, count: 1 };

    /// Part `index` of `count`: an error unless `index < count <= MAX_FRAMES`.
    pub fn new(index: usize, count: usize) -> Result<Self> {
        if count == 0 || count > MAX_FRAMES {
            return Err(Error::Argument(format!("{index}/{count}: give 1 to {MAX_FRAMES} shards")));
        }
        if index >= count {
            return Err(Error::Argument(format!(
                "{index}/{count}: shards count from 0, so the index of one of {count} is 0 to {}",
                count - 1
            )));
        }
        Ok(Shard { index, count })
    }

    /// Whether this is the whole render.
    pub fn is_whole(&self) -> bool {
        self.count == 1
    }

    /// The frames of this part out of `frames`: `index·frames/count .. (index+1)·frames/count`
    /// (10 frames in 3 parts: 0..3, 3..6, 6..10; a part of more parts than frames may be empty).
    pub fn range(&self, frames: usize) -> Range<usize> {
        let at = |i: usize| (i as u128 * frames as u128 / self.count as u128) as usize;
        at(self.index)..at(self.index + 1)
    }

    /// The manifest's file name, `shard-<i>-of-<n>.json`.
    pub fn manifest_name(&self) -> String {
        format!("shard-{}-of-{}.json", self.index, self.count)
    }
}

impl std::fmt::Display for Shard {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{}/{}", self.index, self.count)
    }
}

impl FromStr for Shard {
    type Err = Error;

    /// `i/n`, e.g. `0/3` (what `--shard` takes).
    fn from_str(s: &str) -> Result<Self> {
        let bad = || Error::Argument(format!("{s:?}: give the shard as i/n, e.g. 0/3 (the first of 3)"));
        let (i, n) = s.split_once('/').ok_or_else(bad)?;
        let number = |t: &str| t.trim().parse::<usize>().map_err(|_| bad());
        Shard::new(number(i)?, number(n)?)
    }
}

/// What a render ([`super::write::render_frames`]) or a merge ([`super::merge::merge_shards`])
/// wrote.
#[derive(Debug, Clone, PartialEq)]
pub struct FramesReport {
    /// Number of frames this process was given (all of them, or its shard's).
    pub frames: usize,
    /// Of those, frames an earlier run had finished (kept with `skip_existing`).
    pub skipped: usize,
    /// Metrics (also in `metrics.json`) when every frame had ground truth and the render is
    /// whole (a shard's metrics come with the merge).
    pub metrics: Option<EvalReport>,
    /// The GIF, when asked for and the render is whole.
    pub gif: Option<PathBuf>,
}

impl FramesReport {
    /// What was written into `out` by the render of `shard` (or a merge: [`Shard::WHOLE`]), as
    /// the binaries print it: the frames (and how many were kept), then for a shard how to
    /// merge, else the metrics and the GIF.
    pub fn summary(&self, out: &Path, shard: Shard) -> String {
        let kept = if self.skipped > 0 { format!(" ({} kept from an earlier run)", self.skipped) } else { String::new() };
        if !shard.is_whole() {
            return format!(
                "shard {shard}: {} frames and depth maps in {}{kept}\nonce every shard is done, assemble them with --merge --out {}",
                self.frames,
                out.display(),
                out.display()
            );
        }
        let mut lines = vec![format!("{} frames and depth maps in {}{kept}", self.frames, out.display())];
        if let Some(m) = &self.metrics {
            lines.push(format!("PSNR {:.2} dB, SSIM {:.4} over {} views: {}", m.psnr_mean, m.ssim_mean, m.per_image.len(), out.join(METRICS_FILE).display()));
        }
        if let Some(gif) = &self.gif {
            lines.push(format!("animation: {}", gif.display()));
        }
        lines.join("\n")
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parts_are_contiguous_and_cover_every_frame_once() {
        let parts: Vec<_> = (0..3).map(|i| Shard::new(i, 3).unwrap().range(10)).collect();
        assert_eq!(parts, vec![0..3, 3..6, 6..10]);
        assert_eq!(Shard::WHOLE.range(7), 0..7);
        // More parts than frames: some are empty, none overlaps.
        let parts: Vec<_> = (0..4).map(|i| Shard::new(i, 4).unwrap().range(2)).collect();
        assert_eq!(parts, vec![0..0, 0..1, 1..1, 1..2]);
        assert_eq!(Shard::new(9_999, 10_000).unwrap().range(10_000), 9_999..10_000);
    }

    #[test]
    fn shards_parse_as_i_of_n_with_clear_errors() {
        assert_eq!("2/5".parse::<Shard>().unwrap(), Shard { index: 2, count: 5 });
        assert_eq!(Shard { index: 2, count: 5 }.to_string(), "2/5");
        let err = |s: &str| s.parse::<Shard>().unwrap_err().to_string();
        assert!(err("3/3").contains("0 to 2"), "{}", err("3/3"));
        assert!(err("0/0").contains("1 to 10000"), "{}", err("0/0"));
        assert!(err("1-3").contains("i/n"), "{}", err("1-3"));
        assert!(err("a/3").contains("i/n"), "{}", err("a/3"));
        assert!(err("-1/3").contains("i/n"), "{}", err("-1/3"));
    }
}
