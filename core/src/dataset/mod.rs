//! Datasets: the Blender (`transforms_{split}.json`) format, real captures (instant-ngp /
//! nerfstudio `transforms.json`, LLFF `poses_bounds.npy`) parsed into a format-free
//! [`Capture`], a generated test scene, and the random pixel batcher used in training.
//!
//! [`load_dataset`] is the entry point every command uses; each format is a parser behind it.
//! Images are row-major RGB (pixel (column `i`, row `j`) at index `j·W + i`), in `[0, 1]`,
//! already composited on the configured background (white unless told otherwise).

mod blender;
pub mod colmap;
mod capture;
mod images;
mod instant_ngp;
mod llff;
mod scene_fit;
mod source;
mod synthetic;

pub use blender::{Frame, Transforms, image_path, load_blender, load_split, transforms_path};
pub use images::{Background, check_divisible, load_image, prescaled_path, write_prescaled};
pub use scene_fit::{CameraPath, FAR_AABB_SCALE, OrbitPath, SpiralPath, contraction_by_default, field_near_far, fit_to_field};
pub use source::{Dataset, LoadOptions, SceneFrame, ScenePlacement, default_contraction, load_dataset};
pub use capture::{
    Capture, CaptureFormat, CaptureSplit, CaptureView, ExplicitSplits, FORWARD_FACING_MAX_DEG,
    HOLDOUT_EVERY, centroid, detect_format, focus_point, holdout_split, is_forward_facing,
};
pub use instant_ngp::{
    CameraFields, NGP_DEFAULT_OFFSET, NGP_DEFAULT_SCALE, NgpFrame, TransformsFile,
    camera_from_fields, load_instant_ngp, resolve_image,
};
pub use llff::{
    BD_FACTOR, LlffRow, bd_factor_scale, llff_images, llff_normalisation, llff_row, load_llff, load_llff_images,
    poses_avg, recenter_poses,
};
pub use synthetic::{
    CAMERA_ANGLE_X, SyntheticSceneConfig, generate_scene, render_reference, split_poses, surface_distance,
};

use std::collections::HashSet;
use std::fmt;
use std::ops::Range;
use std::str::FromStr;

use serde::{Deserialize, Serialize};

use crate::camera::Pose;
use crate::camera::PinholeCamera;
use crate::error::{Error, Result};
use crate::rng::Rng;

/// One of the three Blender splits.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Split {
    /// `transforms_train.json`.
    Train,
    /// `transforms_val.json`.
    Val,
    /// `transforms_test.json`.
    Test,
}

impl Split {
    /// All splits, in the order train, val, test.
    pub const ALL: [Split; 3] = [Split::Train, Split::Val, Split::Test];

    /// `"train"`, `"val"` or `"test"`.
    pub fn name(self) -> &'static str {
        match self {
            Split::Train => "train",
            Split::Val => "val",
            Split::Test => "test",
        }
    }
}

impl fmt::Display for Split {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

impl FromStr for Split {
    type Err = Error;
    fn from_str(s: &str) -> Result<Self> {
        match s {
            "train" => Ok(Split::Train),
            "val" => Ok(Split::Val),
            "test" => Ok(Split::Test),
            other => Err(Error::Argument(format!(
                "unknown split {other:?} (expected train, val or test)"
            ))),
        }
    }
}

/// One camera view of a split.
#[derive(Debug, Clone, PartialEq)]
pub struct View {
    /// The file stem of `file_path` (`./test/r_0` → `r_0`).
    pub name: String,
    /// The frame's `file_path` as written in the JSON.
    pub file_path: String,
    /// Its camera at the loaded resolution (shared by all views unless the format has
    /// per-frame intrinsics).
    pub camera: PinholeCamera,
    /// Camera-to-world pose.
    pub pose: Pose,
    /// The image (row-major RGB in `[0, 1]`, composited on the loading background, at the
    /// loaded resolution), or `None` when loaded without pixels.
    pub image: Option<Vec<[f32; 3]>>,
    /// Its alpha when loaded for random backgrounds and not opaque (`image` is then
    /// premultiplied); `None`: opaque.
    pub alpha: Option<Vec<f32>>,
}

/// A loaded split: its views, each with its camera.
#[derive(Debug, Clone, PartialEq)]
pub struct SplitData {
    /// Which split.
    pub split: CaptureSplit,
    /// The views in file order.
    pub views: Vec<View>,
}

impl SplitData {
    /// The poses of all views, in order.
    pub fn poses(&self) -> Vec<Pose> {
        self.views.iter().map(|v| v.pose).collect()
    }

    /// The split's camera (its first view's): the run's camera for orbits; `None` when the
    /// split has no views.
    pub fn camera(&self) -> Option<PinholeCamera> {
        self.views.first().map(|v| v.camera)
    }
}

/// Draws training batches: one random image per step, then random pixels of it (optionally
/// only from a central crop, as nerf-pytorch's `precrop_frac` early in training).
#[derive(Debug, Clone)]
pub struct RayBatcher {
    data: SplitData,
    seen: HashSet<usize>,
}

impl RayBatcher {
    /// A batcher over `data` (normally the train split), which must have at least one view and
    /// an image of `width·height` pixels for every view.
    pub fn new(data: SplitData) -> Result<Self> {
        if data.views.is_empty() || data.views.iter().any(|v| v.camera.num_pixels() == 0) {
            return Err(Error::Argument(format!(
                "the {} split has no views or empty images to train on",
                data.split
            )));
        }
        for view in &data.views {
            let n_pixels = view.camera.num_pixels();
            match &view.image {
                None => {
                    return Err(Error::Argument(format!(
                        "view {} of the {} split was loaded without its image",
                        view.file_path, data.split
                    )));
                }
                Some(img) if img.len() != n_pixels => {
                    return Err(Error::Argument(format!(
                        "view {} has {} pixels, expected {}×{}",
                        view.file_path,
                        img.len(),
                        view.camera.width,
                        view.camera.height
                    )));
                }
                Some(_) => {}
            }
        }
        Ok(RayBatcher {
            data,
            seen: HashSet::new(),
        })
    }

    /// The split the batches come from (poses are `data().views[index].pose`).
    pub fn data(&self) -> &SplitData {
        &self.data
    }

    /// Gives the split back.
    pub fn into_data(self) -> SplitData {
        self.data
    }

    /// The `(columns, rows)` pixels eligible for sampling: the whole image for `None` or a
    /// fraction outside `(0, 1)`, else nerf-pytorch's central crop: rows
    /// `[H/2 − dH, H/2 + dH − 1]`, columns `[W/2 − dW, W/2 + dW − 1]` with
    /// `dH = ⌊(H/2)·f⌋`, `dW = ⌊(W/2)·f⌋` (integer halves), at least one pixel either side.
    pub fn sample_region(
        width: u32,
        height: u32,
        precrop_fraction: Option<f32>,
    ) -> (Range<u32>, Range<u32>) {
        match precrop_fraction {
            Some(f) if f > 0.0 && f < 1.0 => (centre_range(width, f), centre_range(height, f)),
            _ => (0..width, 0..height),
        }
    }

    /// One training batch: `(image index, pixels (column i, row j), target rgb)`.
    ///
    /// The image is `rng.below(n_views)`; then `n_rays` pixels of the sampling region (see
    /// [`RayBatcher::sample_region`]) are drawn without replacement (Floyd's algorithm), or
    /// with replacement when `n_rays` exceeds the region. Deterministic for a given `rng` state.
    pub fn next_batch(
        &mut self,
        rng: &mut Rng,
        n_rays: usize,
        precrop_fraction: Option<f32>,
    ) -> (usize, Vec<(u32, u32)>, Vec<[f32; 3]>) {
        let index = rng.below(self.data.views.len());
        let PinholeCamera { width, height, .. } = self.data.views[index].camera;
        let (cols, rows) = Self::sample_region(width, height, precrop_fraction);
        let region_w = (cols.end - cols.start) as usize;
        let region = region_w * (rows.end - rows.start) as usize;
        let mut flat = Vec::with_capacity(n_rays);
        if n_rays <= region {
            self.seen.clear();
            for j in region - n_rays..region {
                let t = rng.below(j + 1);
                let pick = if self.seen.insert(t) { t } else { j };
                self.seen.insert(pick);
                flat.push(pick);
            }
        } else {
            flat.extend((0..n_rays).map(|_| rng.below(region)));
        }
        let image = self.data.views[index]
            .image
            .as_ref()
            .expect("checked in RayBatcher::new");
        let mut pixels = Vec::with_capacity(n_rays);
        let mut targets = Vec::with_capacity(n_rays);
        for p in flat {
            let i = cols.start + (p % region_w) as u32;
            let j = rows.start + (p / region_w) as u32;
            pixels.push((i, j));
            targets.push(image[j as usize * width as usize + i as usize]);
        }
        (index, pixels, targets)
    }
}

fn centre_range(n: u32, f: f32) -> Range<u32> {
    let half = n / 2;
    if half == 0 {
        return 0..n;
    }
    let d = ((half as f32 * f).floor() as u32).clamp(1, half);
    half - d..half + d
}

#[cfg(test)]
mod tests {
    use super::*;

    fn data(width: u32, height: u32, n: usize) -> SplitData {
        // Pixel value encodes (image, column, row) so targets can be checked.
        let views = (0..n)
            .map(|k| View {
                name: format!("r_{k}"),
                file_path: format!("./train/r_{k}"),
                camera: crate::camera::Intrinsics { width, height, focal: 50.0 }.into(),
                pose: Pose::spherical(0.0, -30.0, 4.0),
                image: Some(
                    (0..height)
                        .flat_map(|j| (0..width).map(move |i| [k as f32, i as f32, j as f32]))
                        .collect(),
                ),
                alpha: None,
            })
            .collect();
        SplitData {
            split: CaptureSplit::Train,
            views,
        }
    }

    #[test]
    fn split_names_parse_and_serde() {
        for s in Split::ALL {
            assert_eq!(s.name().parse::<Split>().unwrap(), s);
            assert_eq!(s.to_string(), s.name());
        }
        assert_eq!(serde_json::to_string(&Split::Val).unwrap(), "\"val\"");
        assert_eq!(
            serde_json::from_str::<Split>("\"test\"").unwrap(),
            Split::Test
        );
        let err = "Train".parse::<Split>().unwrap_err().to_string();
        assert!(err.contains("\"Train\""), "{err}");
    }

    #[test]
    fn precrop_bounds_match_nerf_pytorch() {
        // 400×400, f = 0.5: dH = dW = 100 → rows and columns 100..=299.
        assert_eq!(
            RayBatcher::sample_region(400, 400, Some(0.5)),
            (100..300, 100..300)
        );
        // 800×600 (W×H), f = 0.5: dW = 200 → cols 200..=599; dH = 150 → rows 150..=449.
        assert_eq!(
            RayBatcher::sample_region(800, 600, Some(0.5)),
            (200..600, 150..450)
        );
        // Odd sizes use the integer half: W = 15 → 7, dW = ⌊7·0.5⌋ = 3 → cols 4..=9.
        // H = 9 → 4, dH = ⌊4·0.3⌋ = 1 → rows 3..=4.
        assert_eq!(RayBatcher::sample_region(15, 9, Some(0.5)).0, 4..10);
        assert_eq!(RayBatcher::sample_region(15, 9, Some(0.3)).1, 3..5);
        // None, 1.0 and nonsense mean the whole image.
        assert_eq!(RayBatcher::sample_region(15, 9, None), (0..15, 0..9));
        assert_eq!(RayBatcher::sample_region(15, 9, Some(1.0)), (0..15, 0..9));
        assert_eq!(
            RayBatcher::sample_region(15, 9, Some(f32::NAN)),
            (0..15, 0..9)
        );
        // A tiny fraction keeps at least one pixel either side of the centre.
        assert_eq!(
            RayBatcher::sample_region(20, 20, Some(0.01)),
            (9..11, 9..11)
        );
    }

    #[test]
    fn batches_respect_precrop_and_targets() {
        let mut batcher = RayBatcher::new(data(40, 30, 3)).unwrap();
        let mut rng = Rng::new(3);
        let mut images = HashSet::new();
        for _ in 0..20 {
            let (k, pixels, targets) = batcher.next_batch(&mut rng, 64, Some(0.5));
            images.insert(k);
            assert_eq!(pixels.len(), 64);
            // W = 40: dW = 10 → cols 10..=29; H = 30: dH = ⌊15·0.5⌋ = 7 → rows 8..=21.
            for (&(i, j), t) in pixels.iter().zip(&targets) {
                assert!(
                    (10..=29).contains(&i) && (8..=21).contains(&j),
                    "({i}, {j})"
                );
                assert_eq!(*t, [k as f32, i as f32, j as f32]);
            }
            // Without replacement: no pixel twice.
            let unique: HashSet<_> = pixels.iter().collect();
            assert_eq!(unique.len(), 64);
        }
        assert_eq!(images.len(), 3);
        // The full image is reachable without precrop.
        let (mut min_i, mut max_i) = (u32::MAX, 0);
        for _ in 0..20 {
            let (_, pixels, _) = batcher.next_batch(&mut rng, 200, None);
            for (i, _) in pixels {
                min_i = min_i.min(i);
                max_i = max_i.max(i);
            }
        }
        assert_eq!((min_i, max_i), (0, 39));
    }

    #[test]
    fn batches_are_deterministic_and_cover_small_regions() {
        let mut a = RayBatcher::new(data(8, 6, 2)).unwrap();
        let mut b = a.clone();
        let (mut ra, mut rb) = (Rng::new(11), Rng::new(11));
        for _ in 0..5 {
            assert_eq!(
                a.next_batch(&mut ra, 10, Some(0.5)),
                b.next_batch(&mut rb, 10, Some(0.5))
            );
        }
        // Asking for the whole region returns every pixel exactly once.
        let (_, pixels, _) = a.next_batch(&mut ra, 48, None);
        let unique: HashSet<_> = pixels.iter().copied().collect();
        assert_eq!(unique.len(), 48);
        // More rays than pixels falls back to sampling with replacement.
        let (_, pixels, _) = a.next_batch(&mut ra, 100, None);
        assert_eq!(pixels.len(), 100);
        assert!(pixels.iter().all(|&(i, j)| i < 8 && j < 6));
    }

    #[test]
    fn batcher_rejects_views_without_images() {
        let mut d = data(4, 4, 2);
        d.views[1].image = None;
        let err = RayBatcher::new(d).unwrap_err().to_string();
        assert!(err.contains("./train/r_1"), "{err}");
        let mut d = data(4, 4, 1);
        d.views[0].image.as_mut().unwrap().pop();
        assert!(RayBatcher::new(d).is_err());
        assert!(RayBatcher::new(data(4, 4, 0)).is_err());
    }
}
