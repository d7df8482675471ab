//! Frame output shared by `nerf eval`/`nerf render` (burn) and `nerf-render` (onnxruntime):
//! a progress bar per frame, PNG + depth map (+ optional raw `.npy`, [`super::raw`]), metrics
//! against ground truth and the orbit GIF. The renderer is a closure, so both binaries write the
//! same files the same way.
//!
//! A render may be one shard of several processes ([`FramePlan`], [`super::manifest`]) and may
//! keep the frames an earlier run finished; the GIF, `metrics.json` and contact sheet are then
//! assembled from what is on disk ([`super::merge`]), by the whole render itself or by the
//! merge of its shards, which write the same bytes.

use super::manifest::{FrameRecord, RecordedMetrics, ShardManifest, finished_frames, sheet_row_path};
use super::merge::assemble;
use super::raw::save_npy;
use super::spec::{FrameSpec, FramesReport, GIF_DELAY_MS, GIF_FILE, GifSpec, SHARDS_DIR, SHEET_MAX_WIDTH, SHEET_VIEWS, Shard};
use crate::error::{Error, Result};
use crate::io::image::{depth_to_rgb, save_png};
use crate::render::metrics::{psnr, ssim};
use crate::render::RenderedImage;
use indicatif::{ProgressBar, ProgressStyle};
use std::path::{Path, PathBuf};

/// Where and what to write.
#[derive(Debug, Clone, PartialEq)]
pub struct FrameOutput {
    /// Output directory (created if missing).
    pub dir: PathBuf,
    /// Depth range of the colour map (near, far).
    pub depth_range: (f32, f32),
    /// Also write a GIF of all frames ([`FramePlan::gif`]: `orbit.gif` unless told otherwise).
    pub gif: bool,
    /// Also write `<name>.npy`: float32 `[H, W, 5]` = r, g, b, depth, acc (exact values for
    /// comparisons; PNGs are 8-bit).
    pub raw: bool,
    /// Show a progress bar per frame.
    pub progress: bool,
}

/// How a render is split across processes and resumed, and what its GIF is called.
#[derive(Debug, Clone, PartialEq)]
pub struct FramePlan {
    /// The part of the frames this process renders. The whole render ([`Shard::WHOLE`]) writes
    /// the GIF, metrics and contact sheet at once; a part leaves them to a merge
    /// ([`super::merge::merge_shards`]).
    pub shard: Shard,
    /// Keep frames an earlier run finished: a frame whose PNG and depth map (and `.npy` when
    /// asked for) exist is not rendered again (with ground truth, its metrics must also be on
    /// record in `.shards/`).
    pub skip_existing: bool,
    /// The GIF's file and frame time (written when [`FrameOutput::gif`] is set).
    pub gif: GifSpec,
}

impl Default for FramePlan {
    /// The whole render in one process, from scratch, `orbit.gif` at [`GIF_DELAY_MS`].
    fn default() -> Self {
        FramePlan { shard: Shard::WHOLE, skip_existing: false, gif: GifSpec { file: GIF_FILE.into(), delay_ms: GIF_DELAY_MS } }
    }
}

/// A progress bar for one frame labelled `what` (hidden when `show` is false).
pub fn frame_bar(show: bool, what: &str) -> ProgressBar {
    let bar = if show { ProgressBar::new(0) } else { ProgressBar::hidden() };
    bar.set_style(
        ProgressStyle::with_template("{prefix} [{elapsed_precise}<{eta_precise}] {wide_bar} {percent}% {msg}").expect("valid template"),
    );
    bar.set_prefix(what.to_string());
    bar
}

/// Render every frame with `render(frame, progress(done, total))` and write PNG + depth map
/// per frame, then `metrics.json` and the contact sheet (if all frames have targets) and
/// `orbit.gif` (if asked). Errors are the renderer's own type, which takes the core's file errors.
pub fn render_frames<E: From<Error>>(
    frames: Vec<FrameSpec>,
    out: &FrameOutput,
    render: impl FnMut(&FrameSpec, &mut dyn FnMut(usize, usize)) -> std::result::Result<RenderedImage, E>,
) -> std::result::Result<FramesReport, E> {
    render_frames_with(frames, out, &FramePlan::default(), render)
}

/// [`render_frames`] for the frames of `plan.shard`, keeping what an earlier run finished when
/// `plan.skip_existing`. After each frame (files first) the shard's manifest in `.shards/`
/// records it; a whole render then assembles its GIF, metrics and contact sheet from what is on
/// disk ([`assemble`]), exactly as a merge of shards does.
pub fn render_frames_with<E: From<Error>>(
    frames: Vec<FrameSpec>,
    out: &FrameOutput,
    plan: &FramePlan,
    mut render: impl FnMut(&FrameSpec, &mut dyn FnMut(usize, usize)) -> std::result::Result<RenderedImage, E>,
) -> std::result::Result<FramesReport, E> {
    let shards_dir = out.dir.join(SHARDS_DIR);
    std::fs::create_dir_all(&shards_dir).map_err(|e| Error::io(&shards_dir, e))?;
    let with_metrics = !frames.is_empty() && frames.iter().all(|f| f.target.is_some());
    let gif = (out.gif && !frames.is_empty()).then(|| plan.gif.clone());
    let mut manifest = ShardManifest::new(plan.shard, &frames, out.raw, with_metrics, gif);
    let earlier = if plan.skip_existing { finished_frames(&out.dir, &manifest.fingerprint)? } else { Default::default() };
    manifest.write(&out.dir)?;
    let range = manifest.range();
    let mut skipped = 0;
    for k in range.clone() {
        let frame = &frames[k];
        if plan.skip_existing
            && let Some(record) = kept_frame(&out.dir, &manifest, k, &frame.name, earlier.get(&k))
        {
            manifest.done.push(record);
            manifest.write(&out.dir)?;
            skipped += 1;
            continue;
        }
        let bar = frame_bar(out.progress, &format!("{} {}/{}", frame.name, k + 1 - range.start, range.len()));
        bar.set_length(frame.camera.num_pixels() as u64);
        let image = render(frame, &mut |done, _| bar.set_position(done as u64))?;
        let depth = save_frame(&image, &out.dir, &frame.name, out.depth_range, out.raw)?;
        let mut metrics = None;
        if let Some(target) = frame.target.as_ref().filter(|_| with_metrics) {
            let m = RecordedMetrics {
                psnr: psnr(&image.rays.rgb, target) as f64,
                ssim: ssim(&image.rays.rgb, target, image.width as usize, image.height as usize) as f64,
            };
            bar.finish_with_message(format!("PSNR {:.2} dB, SSIM {:.3}", m.psnr, m.ssim));
            if k < SHEET_VIEWS {
                let (w, h, row) = sheet_row(image.width, image.height, &[target, &image.rays.rgb, &depth]);
                save_png(&sheet_row_path(&out.dir, &manifest.fingerprint, k), w, h, &row)?;
            }
            metrics = Some(m);
        } else {
            bar.finish();
        }
        manifest.done.push(FrameRecord { index: k, name: frame.name.clone(), metrics });
        manifest.write(&out.dir)?;
    }
    if plan.shard.is_whole() {
        let report = assemble(&out.dir, std::slice::from_ref(&manifest))?;
        if !plan.skip_existing {
            manifest.remove(&out.dir);
        }
        return Ok(FramesReport { frames: frames.len(), skipped, ..report });
    }
    Ok(FramesReport { frames: range.len(), skipped, metrics: None, gif: None })
}

/// The record of frame `index` (`name`) when an earlier run finished it: its PNG, depth map and
/// (when the render writes them) `.npy` exist, and with ground truth its metrics and contact-sheet
/// row are on record.
fn kept_frame(dir: &Path, manifest: &ShardManifest, index: usize, name: &str, earlier: Option<&FrameRecord>) -> Option<FrameRecord> {
    let mut files = vec![dir.join(format!("{name}.png")), dir.join(format!("{name}_depth.png"))];
    if manifest.raw {
        files.push(dir.join(format!("{name}.npy")));
    }
    if !files.iter().all(|f| f.is_file()) {
        return None;
    }
    if !manifest.metrics {
        return Some(FrameRecord { index, name: name.to_string(), metrics: None });
    }
    let record = earlier.filter(|r| r.name == name && r.metrics.is_some())?;
    let row_kept = index >= SHEET_VIEWS || sheet_row_path(dir, &manifest.fingerprint, index).is_file();
    row_kept.then(|| record.clone())
}

/// One contact-sheet row: `images` (each `width × height`, row-major) side by side, shrunk by
/// the integer factor that brings the width to at most [`SHEET_MAX_WIDTH`] (the mean of each
/// factor² block; never more than the height, so a row is never empty): `(row width, row
/// height, pixels)`.
fn sheet_row(width: u32, height: u32, images: &[&[[f32; 3]]]) -> (u32, u32, Vec<[f32; 3]>) {
    let f = width.div_ceil(SHEET_MAX_WIDTH).clamp(1, height.max(1)) as usize;
    let (w, h) = (width as usize, height as usize);
    let (sw, sh) = (w / f, h / f);
    let mut row = Vec::with_capacity(sw * sh * images.len());
    for j in 0..sh {
        for image in images {
            for i in 0..sw {
                let mut sum = [0.0f32; 3];
                for (dj, di) in (0..f).flat_map(|dj| (0..f).map(move |di| (dj, di))) {
                    let p = image[(j * f + dj) * w + i * f + di];
                    sum = [0, 1, 2].map(|c| sum[c] + p[c]);
                }
                row.push(sum.map(|v| v / (f * f) as f32));
            }
        }
    }
    ((sw * images.len()) as u32, sh as u32, row)
}

/// Write `<dir>/<name>.png`, `<dir>/<name>_depth.png` and, with `raw`, `<dir>/<name>.npy`;
/// returns the depth map's colours (for the contact sheet).
pub fn save_frame(image: &RenderedImage, dir: &Path, name: &str, depth_range: (f32, f32), raw: bool) -> Result<Vec<[f32; 3]>> {
    let (w, h) = (image.width, image.height);
    save_png(&dir.join(format!("{name}.png")), w, h, &image.rays.rgb)?;
    let depth = depth_to_rgb(&image.rays.depth, &image.rays.acc, depth_range.0, depth_range.1);
    save_png(&dir.join(format!("{name}_depth.png")), w, h, &depth)?;
    if raw {
        save_npy(&dir.join(format!("{name}.npy")), image)?;
    }
    Ok(depth)
}

#[cfg(test)]
pub(super) mod tests {
    use super::*;
    use crate::camera::{PinholeCamera, Pose};
    use crate::frames::spec::{METRICS_FILE, SHEET_FILE};
    use crate::render::RenderedRays;
    use crate::render::metrics::EvalReport;

    /// 3×2 pixels: pixel k has r = 0.1·k, depth 2 + k (also the raw frame's test image).
    pub(in crate::frames) fn image() -> RenderedImage {
        RenderedImage {
            width: 3,
            height: 2,
            rays: RenderedRays {
                rgb: (0..6).map(|k| [k as f32 * 0.1, 0.5, 1.0]).collect(),
                depth: (0..6).map(|k| 2.0 + k as f32).collect(),
                acc: vec![0.25; 6],
            },
        }
    }

    #[test]
    fn wide_views_are_shrunk_on_the_contact_sheet() {
        // 600 px wide → factor 3 (600/256 rounded up): 200×1 from 600×3, each pixel the mean
        // of a 3×3 block. Pixel (i, j) of the image holds i + 1000·j in red.
        let image: Vec<[f32; 3]> = (0..3).flat_map(|j| (0..600).map(move |i| [(i + 1000 * j) as f32, 0.0, 1.0])).collect();
        let (w, h, row) = sheet_row(600, 3, &[&image, &image]);
        assert_eq!((w, h, row.len()), (400, 1, 400));
        // Block 0: columns 0..3, rows 0..3: mean of i = 1, of 1000·j = 1000.
        assert_eq!(row[0], [1001.0, 0.0, 1.0]);
        // The second image starts at 200; block 5 covers columns 15..18: 16 + 1000.
        assert_eq!(row[205], [1016.0, 0.0, 1.0]);
    }

    #[test]
    fn frames_write_pngs_metrics_and_gif() {
        let dir = tempfile::tempdir().unwrap();
        let k = PinholeCamera::from(crate::camera::Intrinsics { width: 3, height: 2, focal: 3.0 });
        let pose = Pose::spherical(0.0, -30.0, 4.0);
        let mut frames = FrameSpec::orbit(&k, &[pose, pose]);
        let truth = image().rays.rgb;
        let out = FrameOutput { dir: dir.path().join("out"), depth_range: (2.0, 6.0), gif: true, raw: true, progress: false };
        // Without targets: no metrics.
        let report = render_frames(frames.clone(), &out, |_, _| Ok::<_, Error>(image())).unwrap();
        assert_eq!((report.frames, report.metrics.is_none()), (2, true));
        assert!(report.gif.unwrap().exists());
        for name in ["frame_000.png", "frame_001_depth.png", "frame_001.npy"] {
            assert!(out.dir.join(name).exists(), "{name}");
        }
        // With targets: one exact frame (infinite PSNR) and one off by 0.1 everywhere (20 dB).
        frames[0].target = Some(truth.clone());
        frames[1].target = Some(truth.iter().map(|c| c.map(|v| v - 0.1)).collect());
        let report = render_frames(frames, &out, |_, _| Ok::<_, Error>(image())).unwrap();
        let m = report.metrics.unwrap();
        assert!((m.per_image[1].psnr - 20.0).abs() < 1e-3, "{}", m.per_image[1].psnr);
        assert_eq!(EvalReport::read_json(&out.dir.join(METRICS_FILE)).unwrap().per_image.len(), 2);
        // The contact sheet: two rows of truth | render | depth, 9×4 pixels; row 1 starts with
        // its target (0.1 below the render), then the render itself.
        let (w, h, sheet) = crate::io::image::load_rgba(&out.dir.join(SHEET_FILE)).unwrap();
        assert_eq!((w, h), (9, 4));
        let at = |i: usize, j: usize| sheet[j * 9 + i];
        let byte = |v: f32| (v.clamp(0.0, 1.0) * 255.0).round() / 255.0;
        assert_eq!(at(1, 2)[0], byte(0.1 - 0.1));
        assert_eq!(at(4, 2)[0], byte(0.1));
        assert_eq!(at(4, 3)[0], byte(0.4));
        // A renderer error stops the run with its message.
        let err = render_frames(FrameSpec::orbit(&k, &[pose]), &out, |_, _| Err(Error::Argument("network exploded".into()))).unwrap_err();
        assert_eq!(err.to_string(), "network exploded");
    }
}
