//! Assembling a finished render from its parts' manifests ([`super::manifest`]): the GIF from
//! the frames' PNGs, `metrics.json` from the recorded metrics in frame order, the contact sheet
//! from the recorded rows. A single process assembles its own render the same way, so a render split
//! in parts and merged writes the same bytes as one process.
//!
//! Everything is read and checked before anything is written: a missing part, an unfinished
//! frame or a missing file is an error naming it, and leaves the output directory as it was.

use super::manifest::{ShardManifest, read_manifests, sheet_row_path};
use super::spec::{FramesReport, METRICS_FILE, SHARDS_DIR, SHEET_FILE, SHEET_VIEWS};
use crate::error::{Error, Result};
use crate::io::image::{encode_gif_rgb8, load_rgb8, save_png_rgb8};
use crate::io::atomic::write_atomic;
use crate::render::metrics::EvalReport;
use std::path::Path;

/// Names listed in an error at most (then "and N more").
const LISTED: usize = 8;

/// `--merge`: assemble the render whose parts' manifests are in `dir/.shards/`. They must all
/// be parts of one render (one split, one fingerprint), every part present and finished.
pub fn merge_shards(dir: &Path) -> Result<FramesReport> {
    let manifests = read_manifests(dir)?;
    let Some((first_path, first)) = manifests.first() else {
        return Err(Error::invalid(
            dir.join(SHARDS_DIR),
            "no shard manifests: render into this directory with --shard i/n first (every shard with the same --out)",
        ));
    };
    for (path, m) in &manifests[1..] {
        if m.shards != first.shards || m.fingerprint != first.fingerprint {
            let why = if m.shards != first.shards {
                format!("split {} and {} ways", first.shards, m.shards)
            } else {
                "different frames or options".to_string()
            };
            return Err(Error::invalid(
                dir.join(SHARDS_DIR),
                format!(
                    "{} and {} are parts of different renders ({why}): remove the stale manifests, or render into a fresh --out",
                    file_name(first_path),
                    file_name(path)
                ),
            ));
        }
    }
    let parts: Vec<ShardManifest> = manifests.into_iter().map(|(_, m)| m).collect();
    assemble(dir, &parts)
}

/// Write the GIF, `metrics.json` and contact sheet of the render in `dir` whose parts are
/// `parts` (one per shard, sorted by index, one fingerprint), once every part is finished.
pub fn assemble(dir: &Path, parts: &[ShardManifest]) -> Result<FramesReport> {
    let shards_dir = dir.join(SHARDS_DIR);
    let Some(first) = parts.first() else {
        return Err(Error::invalid(&shards_dir, "no shard manifests to merge"));
    };
    let count = first.shards;
    let missing: Vec<String> = (0..count).filter(|i| !parts.iter().any(|m| m.shard == *i)).map(|i| format!("{i}/{count}")).collect();
    if !missing.is_empty() {
        let (shards, have) = if missing.len() == 1 { ("shard", "has") } else { ("shards", "have") };
        return Err(Error::invalid(
            &shards_dir,
            format!("{shards} {} {have} no manifest (not started, or rendered into another directory)", listed(&missing)),
        ));
    }
    for m in parts {
        let left = m.missing();
        if !left.is_empty() {
            return Err(Error::invalid(
                m.path(dir),
                format!(
                    "shard {} has not finished {} of its {} frames: {} (run it again with --skip-existing)",
                    m.part(),
                    left.len(),
                    m.names.len(),
                    listed(&left)
                ),
            ));
        }
    }
    let records: Vec<_> = parts.iter().flat_map(|m| m.done.iter().map(move |r| (m, r))).collect();
    for (m, r) in &records {
        let mut files = vec![format!("{}.png", r.name), format!("{}_depth.png", r.name)];
        if m.raw {
            files.push(format!("{}.npy", r.name));
        }
        for f in files {
            if !dir.join(&f).is_file() {
                return Err(Error::invalid(dir.join(&f), format!("missing, though shard {} recorded frame {} as done", m.part(), r.name)));
            }
        }
    }

    // Read everything first.
    let gif = match (&first.gif, records.first()) {
        (Some(spec), Some((_, r0))) => {
            let path = dir.join(&spec.file);
            let (w, h, _) = load_rgb8(&dir.join(format!("{}.png", r0.name)))?;
            let bytes = encode_gif_rgb8(&path, w, h, records.len(), spec.delay_ms, |k| {
                let png = dir.join(format!("{}.png", records[k].1.name));
                let (fw, fh, rgb) = load_rgb8(&png)?;
                if (fw, fh) != (w, h) {
                    return Err(Error::invalid(&png, format!("{fw}×{fh}: the GIF's frames are {w}×{h}")));
                }
                Ok(rgb)
            })?;
            Some((path, bytes))
        }
        _ => None,
    };
    let metrics = if first.metrics && !records.is_empty() {
        let per_image = records.iter().filter_map(|(_, r)| r.image_metrics()).collect();
        let mut rows = Vec::new();
        for (m, r) in records.iter().take_while(|(_, r)| r.index < SHEET_VIEWS) {
            rows.push(load_rgb8(&sheet_row_path(dir, &m.fingerprint, r.index))?);
        }
        Some((EvalReport::from_images(per_image), stack_rows(&rows)))
    } else {
        None
    };

    // Then write.
    let report = match metrics {
        Some((report, sheet)) => {
            report.write_json(&dir.join(METRICS_FILE))?;
            if let Some((w, h, bytes)) = sheet {
                save_png_rgb8(&dir.join(SHEET_FILE), w, h, &bytes)?;
            }
            Some(report)
        }
        None => None,
    };
    let gif = match gif {
        Some((path, bytes)) => {
            write_atomic(&path, &bytes)?;
            Some(path)
        }
        None => None,
    };
    Ok(FramesReport { frames: records.len(), skipped: 0, metrics: report, gif })
}

/// Rows of 8-bit RGB images stacked top to bottom, each padded on the right with white to the
/// widest: `(width, height, bytes)`, or `None` when there is nothing to show.
pub fn stack_rows(rows: &[(u32, u32, Vec<u8>)]) -> Option<(u32, u32, Vec<u8>)> {
    let width = rows.iter().map(|r| r.0).max().unwrap_or(0);
    let height = rows.iter().map(|r| r.1).sum::<u32>();
    if width == 0 || height == 0 {
        return None;
    }
    let mut bytes = Vec::with_capacity(3 * (width * height) as usize);
    for (w, h, row) in rows {
        for line in row.chunks_exact(3 * *w as usize).take(*h as usize) {
            bytes.extend_from_slice(line);
            bytes.extend(std::iter::repeat_n(255u8, 3 * (width - w) as usize));
        }
    }
    Some((width, height, bytes))
}

fn file_name(path: &Path) -> String {
    path.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default()
}

/// `a, b, c` or `a, b, … and 12 more`.
fn listed(names: &[impl AsRef<str>]) -> String {
    let shown: Vec<&str> = names.iter().take(LISTED).map(|n| n.as_ref()).collect();
    match names.len().saturating_sub(LISTED) {
        0 => shown.join(", "),
        more => format!("{} and {more} more", shown.join(", ")),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::camera::{Intrinsics, PinholeCamera, Pose};
    use crate::frames::spec::{FrameSpec, Shard};
    use crate::frames::write::{FrameOutput, FramePlan, render_frames_with};
    use crate::render::{RenderedImage, RenderedRays};
    use std::collections::BTreeMap;

    /// A 6×4 image that depends on the frame (its pose's x), a fake renderer.
    fn fake_render(frame: &FrameSpec) -> RenderedImage {
        let x = frame.pose.0[0][3];
        let n = frame.camera.num_pixels();
        RenderedImage {
            width: frame.camera.width,
            height: frame.camera.height,
            rays: RenderedRays {
                rgb: (0..n).map(|p| [(x * 0.1 + p as f32 * 0.03).fract(), 0.5, (p as f32 * 0.07).fract()]).collect(),
                depth: (0..n).map(|p| 2.0 + (p % 5) as f32).collect(),
                acc: vec![0.9; n],
            },
        }
    }

    /// Seven frames; with targets, each off the render by its own amount.
    fn frames(targets: bool) -> Vec<FrameSpec> {
        let k = PinholeCamera::from(Intrinsics { width: 6, height: 4, focal: 5.0 });
        let mut frames = FrameSpec::orbit(&k, &Pose::orbit(7));
        if targets {
            for (j, f) in frames.iter_mut().enumerate() {
                f.target = Some(fake_render(f).rays.rgb.iter().map(|c| c.map(|v| v - 0.01 * (j + 1) as f32)).collect());
            }
        }
        frames
    }

    fn output(dir: &Path) -> FrameOutput {
        FrameOutput { dir: dir.to_path_buf(), depth_range: (2.0, 6.0), gif: true, raw: true, progress: false }
    }

    /// Every file but the manifests, by name.
    fn files(dir: &Path) -> BTreeMap<String, Vec<u8>> {
        std::fs::read_dir(dir)
            .unwrap()
            .map(|e| e.unwrap().path())
            .filter(|p| p.is_file())
            .map(|p| (p.file_name().unwrap().to_string_lossy().into_owned(), std::fs::read(&p).unwrap()))
            .collect()
    }

    fn render(frames: &[FrameSpec], dir: &Path, plan: &FramePlan, count: &mut usize) -> FramesReport {
        render_frames_with(frames.to_vec(), &output(dir), plan, |f, _| {
            *count += 1;
            Ok::<_, Error>(fake_render(f))
        })
        .unwrap()
    }

    #[test]
    fn three_shards_merged_write_the_bytes_of_one_process() {
        for targets in [false, true] {
            let root = tempfile::tempdir().unwrap();
            let (whole, split) = (root.path().join("whole"), root.path().join("split"));
            let mut n = 0;
            let one = render(&frames(targets), &whole, &FramePlan::default(), &mut n);
            assert_eq!((one.frames, one.metrics.is_some(), one.gif.is_some()), (7, targets, true));
            for i in [2, 0, 1] {
                let plan = FramePlan { shard: Shard::new(i, 3).unwrap(), ..FramePlan::default() };
                let part = render(&frames(targets), &split, &plan, &mut n);
                assert_eq!((part.frames, part.metrics, part.gif), (Shard::new(i, 3).unwrap().range(7).len(), None, None));
                assert!(!split.join(METRICS_FILE).exists() && !split.join("orbit.gif").exists(), "a shard wrote the merged files");
            }
            assert_eq!(n, 14, "every frame rendered once per render");
            let merged = merge_shards(&split).unwrap();
            assert_eq!((merged.frames, merged.gif.is_some()), (7, true));
            let (a, b) = (files(&whole), files(&split));
            assert_eq!(a.keys().collect::<Vec<_>>(), b.keys().collect::<Vec<_>>());
            for (name, bytes) in &a {
                assert!(bytes == &b[name], "{name} differs (targets: {targets})");
            }
            let expected = 7 * 3 + 1 + if targets { 2 } else { 0 };
            assert_eq!(a.len(), expected, "{:?}", a.keys());
        }
    }

    #[test]
    fn skip_existing_renders_only_what_is_missing() {
        let root = tempfile::tempdir().unwrap();
        let dir = root.path().join("out");
        let all = frames(true);
        let mut n = 0;
        let plan = FramePlan { skip_existing: true, ..FramePlan::default() };
        // With --skip-existing a finished whole render keeps its manifest for the next run.
        render(&all, &dir, &plan, &mut n);
        let before = files(&dir);
        // A part killed after its files but before its record, and a frame whose PNG is gone.
        std::fs::remove_file(dir.join("frame_005.png")).unwrap();
        let path = dir.join(".shards/shard-0-of-1.json");
        let mut m = ShardManifest::read(&path).unwrap();
        m.done.retain(|r| r.index != 1);
        m.write(&dir).unwrap();
        let mut n = 0;
        let report = render(&all, &dir, &plan, &mut n);
        assert_eq!((n, report.skipped, report.frames), (2, 5, 7));
        assert_eq!(files(&dir), before, "resumed output differs");
        // Without ground truth the files alone say a frame is done.
        let plain = root.path().join("plain");
        render(&frames(false), &plain, &FramePlan::default(), &mut n);
        // Without it, a finished whole render leaves no manifest behind.
        assert!(!plain.join(SHARDS_DIR).exists());
        let mut n = 0;
        assert_eq!(render(&frames(false), &plain, &plan, &mut n).skipped, 7);
        assert_eq!(n, 0);
        // Another render with ground truth in the same directory renders everything: no
        // metrics of its own are on record.
        let mut other = frames(true);
        other[3].pose = Pose::spherical(10.0, -30.0, 4.0);
        let mut n = 0;
        render(&other, &dir, &FramePlan { skip_existing: true, ..FramePlan::default() }, &mut n);
        assert_eq!(n, 7);
    }

    #[test]
    fn a_merge_names_what_is_missing_and_writes_nothing() {
        let root = tempfile::tempdir().unwrap();
        let dir = root.path().join("out");
        let err = merge_shards(&dir).unwrap_err().to_string();
        assert!(err.contains(".shards: no shard manifests"), "{err}");
        let all = frames(true);
        let shard = |i| FramePlan { shard: Shard::new(i, 3).unwrap(), ..FramePlan::default() };
        let mut n = 0;
        render(&all, &dir, &shard(0), &mut n);
        let err = merge_shards(&dir).unwrap_err().to_string();
        assert!(err.contains("shards 1/3, 2/3 have no manifest"), "{err}");
        render(&all, &dir, &shard(1), &mut n);
        render(&all, &dir, &shard(2), &mut n);
        // Shard 2 (frames 4..7) killed before finishing frame_006: its record is missing.
        let path = dir.join(".shards/shard-2-of-3.json");
        let mut m = ShardManifest::read(&path).unwrap();
        m.done.pop();
        m.write(&dir).unwrap();
        let err = merge_shards(&dir).unwrap_err().to_string();
        assert!(err.contains("shard-2-of-3.json: shard 2/3 has not finished 1 of its 3 frames: frame_006"), "{err}");
        render(&all, &dir, &FramePlan { skip_existing: true, ..shard(2) }, &mut n);
        // A recorded frame whose file is gone (7 frames in 3 shards: 0..2, 2..4, 4..7).
        std::fs::remove_file(dir.join("frame_002_depth.png")).unwrap();
        let err = merge_shards(&dir).unwrap_err().to_string();
        assert!(err.contains("frame_002_depth.png: missing, though shard 1/3 recorded frame frame_002 as done"), "{err}");
        // A stale part of another split.
        render(&all, &dir, &FramePlan { skip_existing: true, ..shard(1) }, &mut n);
        let mut stale = ShardManifest::read(&dir.join(".shards/shard-0-of-3.json")).unwrap();
        stale.shards = 4;
        std::fs::write(dir.join(".shards/shard-0-of-4.json"), serde_json::to_string(&ShardManifest { names: all[0..1].iter().map(|f| f.name.clone()).collect(), done: vec![], ..stale }).unwrap()).unwrap();
        let err = merge_shards(&dir).unwrap_err().to_string();
        assert!(err.contains("shard-0-of-3.json and shard-0-of-4.json are parts of different renders (split 3 and 4 ways)"), "{err}");
        assert!(!dir.join(METRICS_FILE).exists() && !dir.join("orbit.gif").exists() && !dir.join(SHEET_FILE).exists(), "a failed merge wrote files");
        std::fs::remove_file(dir.join(".shards/shard-0-of-4.json")).unwrap();
        assert_eq!(merge_shards(&dir).unwrap().metrics.unwrap().per_image.len(), 7);
    }

    #[test]
    fn rows_are_padded_with_white_to_the_widest() {
        // A 2×1 row of (10, 20, 30) pixels and a 1×2 row of zeros: 2×3, the second row's pixels
        // followed by a white one.
        let rows = vec![(2, 1, vec![10, 20, 30, 10, 20, 30]), (1, 2, vec![0; 6])];
        let (w, h, bytes) = stack_rows(&rows).unwrap();
        assert_eq!((w, h), (2, 3));
        assert_eq!(bytes, vec![10, 20, 30, 10, 20, 30, 0, 0, 0, 255, 255, 255, 0, 0, 0, 255, 255, 255]);
        assert_eq!(stack_rows(&[]), None);
    }

    #[test]
    fn lists_are_cut_after_eight_names() {
        let names: Vec<String> = (0..10).map(|k| k.to_string()).collect();
        assert_eq!(listed(&names), "0, 1, 2, 3, 4, 5, 6, 7 and 2 more");
        assert_eq!(listed(&names[..2]), "0, 1");
    }
}
