//! Visibility carving: which lattice nodes a training camera sees as empty.
//!
//! A trained field is free wherever no camera looked: inside solids (foam, hollows) and in the
//! pockets and shadows no view reaches (under a scene's base). The cavity fill
//! ([`super::cavities`]) closes what the outside cannot reach, but that space is often joined
//! to the outside through other unseen space. Carving asks the cameras instead: a node is seen
//! empty when some view's ray through it meets the view's surface only behind it.
//!
//! # A view's depth
//! Each view is rendered (small: [`CARVE_SIZE`] pixels on its long side) by the same renderer
//! as `nerf eval`. A pixel's surface depth is the renderer's expected depth over its opacity
//! when the pixel is mostly opaque (acc ≥ [`SEE_THROUGH_ACC`]), else infinity: the ray sees
//! through. Each pixel then takes the nearest depth of itself and its 8 neighbours, so that a
//! node projecting next to a silhouette (whose own pixel may miss the object) counts as behind
//! the object. Depths are ray parameters `t` along the unnormalised directions, whose camera
//! z is −1 ([`crate::camera`]): a point's `t` is its depth in front of the camera, `−z` in the
//! camera frame.
//!
//! # A node in a view
//! [`Sight::Empty`] when the node projects inside the image (pixel `(i, j)` is the area
//! `[i − ½, i + ½) × [j − ½, j + ½)` around its ray, in either pixel-centre convention), lies
//! within the rendered span `[near, far]`, and its `t` is less than the pixel's surface depth
//! minus a margin (half a lattice cell, [`MARGIN_CELLS`]); [`Sight::Hidden`] when it is inside
//! the image and the span but not in front; [`Sight::Unseen`] otherwise (outside the image,
//! behind the camera, before near or past far).

use crate::camera::{PinholeCamera, Pose};
use crate::dataset::{Background, CaptureFormat, CaptureSplit};
use crate::error::{Error, Result};
use crate::frames::spec::FrameSpec;
use crate::frames::views::{Images, SplitChoice, split_views};
use crate::render::RenderedImage;
use crate::SceneTransform;
use glam::{Mat3, Vec3};
use std::path::{Path, PathBuf};

/// Long side of the carving renders, in pixels: a lego view (800 px) at 128 px has pixels of
/// about 0.02 at the object, a 128³ cell over ±1.5; finer costs render time (quadratic).
pub const CARVE_SIZE: u32 = 128;
/// A pixel at least this opaque has a surface; a fainter one sees through to infinity.
pub const SEE_THROUGH_ACC: f32 = 0.5;
/// How far in front of a view's surface a node must be to be seen empty, in lattice cells.
/// Half a cell: the views' depths are good to a small part of a cell along the ray (the
/// neighbourhood minimum takes care of the sideways error), and every empty node within the
/// margin that no view sees is filled, pushing the surface out. On the generated scene's tiny
/// run (docs/mesh.md) a whole cell (widened by 2) gave a 95th percentile of 0.117 at 32³
/// against 0.105 for half a cell (widened by 1) and 0.104 for none.
pub const MARGIN_CELLS: f32 = 0.5;
/// Steps the seen-empty nodes are widened by into hidden empty ones beside them
/// ([`super::cavities::widen`]): the empty nodes just outside a surface that no view sees
/// empty (within the margin, or where the views' surface lies behind the density threshold's)
/// stay open, so that the surface falls between them and the dense ones. Each step also opens
/// hollows one node further under a surface with a gap: two steps reopened foam inside the
/// generated scene's red sphere.
pub const WIDEN_STEPS: usize = 1;

/// Which views carve (`nerf mesh`'s choice).
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum CarveViews {
    /// None: the cavity fill alone (`--no-carve`, or every surface kept with `--keep-cavities`).
    Off,
    /// The field's own: a run's recorded dataset's train views (when the dataset is still
    /// there); none for a bundle, which holds no training views.
    Own,
    /// The train views of this dataset (`--data`), mapped into the field by its placement.
    Data(PathBuf),
}

/// What a view says about a point.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Sight {
    /// In front of the view's surface: empty.
    Empty,
    /// In the view, at or behind its surface.
    Hidden,
    /// Outside the view (its image, or its span [near, far]).
    Unseen,
}

/// The camera carving renders a view with: `camera` shrunk to at most [`CARVE_SIZE`] pixels
/// on its long side (the same field of view), or as it is when smaller.
///
/// Example: 800×600 → 128×96; 64×64 → 64×64.
pub fn carving_camera(camera: &PinholeCamera) -> PinholeCamera {
    let long = camera.width.max(camera.height);
    if long <= CARVE_SIZE {
        return *camera;
    }
    let scale = |side: u32| ((side as u64 * CARVE_SIZE as u64 + long as u64 / 2) / long as u64).max(1) as u32;
    camera.resized(scale(camera.width), scale(camera.height))
}

/// A pixel's surface depth: the expected depth over the opacity when acc ≥ [`SEE_THROUGH_ACC`],
/// else infinity. Example: depth 2.7 at acc 0.9 → 3.0; acc 0.3 → ∞.
pub fn surface_depth(depth: f32, acc: f32) -> f32 {
    if acc >= SEE_THROUGH_ACC && depth.is_finite() { depth / acc } else { f32::INFINITY }
}

/// Each pixel's least value over itself and its 8 neighbours (those inside the image).
///
/// Example: 3×1 `[5, ∞, ∞]` → `[5, 5, ∞]`.
pub fn nearest_around(depth: &[f32], width: usize, height: usize) -> Vec<f32> {
    assert_eq!(depth.len(), width * height, "a {width}×{height} depth map");
    let mut out = vec![f32::INFINITY; depth.len()];
    for j in 0..height {
        for i in 0..width {
            let mut least = f32::INFINITY;
            for y in j.saturating_sub(1)..(j + 2).min(height) {
                for x in i.saturating_sub(1)..(i + 2).min(width) {
                    least = least.min(depth[y * width + x]);
                }
            }
            out[j * width + i] = least;
        }
    }
    out
}

/// One view's camera and surface depths, ready to classify points.
#[derive(Debug, Clone, PartialEq)]
pub struct DepthView {
    camera: PinholeCamera,
    /// World → camera rotation (the pose's, transposed).
    to_camera: Mat3,
    /// The camera centre.
    origin: Vec3,
    near: f32,
    far: f32,
    /// Row-major surface depths, each the nearest of its pixel and neighbours ([`nearest_around`]).
    surface: Vec<f32>,
}

impl DepthView {
    /// The view of `camera` at `pose` whose renderer gave per-pixel expected `depth` and opacity
    /// `acc` (row-major, the camera's size) over the span `near..far`.
    pub fn new(camera: PinholeCamera, pose: &Pose, (near, far): (f32, f32), depth: &[f32], acc: &[f32]) -> Self {
        let (w, h) = (camera.width as usize, camera.height as usize);
        assert!(depth.len() == w * h && acc.len() == w * h, "depth and acc of a {w}×{h} view");
        let surface: Vec<f32> = depth.iter().zip(acc).map(|(&d, &a)| surface_depth(d, a)).collect();
        DepthView { camera, to_camera: pose.rotation().transpose(), origin: pose.origin(), near, far, surface: nearest_around(&surface, w, h) }
    }

    /// The view of a rendered image.
    pub fn from_render(camera: PinholeCamera, pose: &Pose, near_far: (f32, f32), image: &RenderedImage) -> Self {
        DepthView::new(camera, pose, near_far, &image.rays.depth, &image.rays.acc)
    }

    /// Pixel `(column, row)` and ray parameter `t` of `point`, when it projects inside the image
    /// and in front of the camera.
    pub fn pixel(&self, point: Vec3) -> Option<((usize, usize), f32)> {
        let local = self.to_camera * (point - self.origin);
        let (u, v) = self.camera.project(local)?;
        // Pixel i's ray is at image coordinate i; its area reaches half a pixel either side.
        let (i, j) = ((u + 0.5).floor(), (v + 0.5).floor());
        let inside = i >= 0.0 && j >= 0.0 && i < self.camera.width as f32 && j < self.camera.height as f32;
        inside.then_some(((i as usize, j as usize), -local.z))
    }

    /// What this view says about `point`: in front of its surface by more than `margin`, or not.
    pub fn sight(&self, point: Vec3, margin: f32) -> Sight {
        match self.pixel(point) {
            Some(((i, j), t)) if t >= self.near && t <= self.far => {
                if t < self.surface[j * self.camera.width as usize + i] - margin { Sight::Empty } else { Sight::Hidden }
            }
            _ => Sight::Unseen,
        }
    }
}

/// What `views` say about `point` together: empty when one sees it empty, unseen when none has
/// it in view, else hidden. `hint`: the view to ask first (the last one that saw a point empty;
/// neighbouring nodes tend to share it), updated.
pub fn sight_of(views: &[DepthView], point: Vec3, margin: f32, hint: &mut usize) -> Sight {
    let mut in_view = false;
    for k in 0..views.len() {
        let at = (*hint + k) % views.len();
        match views[at].sight(point, margin) {
            Sight::Empty => {
                *hint = at;
                return Sight::Empty;
            }
            Sight::Hidden => in_view = true,
            Sight::Unseen => {}
        }
    }
    if in_view { Sight::Hidden } else { Sight::Unseen }
}

/// The train views of the dataset in `dir` (`format`: as recorded, `None` to detect it), poses
/// mapped into the field by `transform`, and the sentence that says what carves; an error
/// naming the dataset when it has none.
pub fn dataset_views(dir: &Path, format: Option<CaptureFormat>, transform: SceneTransform) -> Result<(Vec<FrameSpec>, String)> {
    let choice = SplitChoice { dir: dir.to_path_buf(), format, split: CaptureSplit::Train, downscale: 1 };
    let views = split_views(&choice, transform, Background::White, Images::Skip)?;
    let Some(first) = views.first() else {
        return Err(Error::invalid(dir, "the train split has no views to carve with (give another --data, or --no-carve)"));
    };
    let k = carving_camera(&first.camera);
    let what = format!("carved with the {} train views of {}, rendered at {}×{}", views.len(), dir.display(), k.width, k.height);
    Ok((views, what))
}

/// The views `choice` carves with and the sentence that says so: none with `keep_cavities`
/// (every surface is kept) or [`CarveViews::Off`]; `own()` for [`CarveViews::Own`]; a
/// dataset's train views (detected `format`, mapped into the field by `transform`) for
/// [`CarveViews::Data`].
pub fn carving_views(
    choice: &CarveViews,
    keep_cavities: bool,
    transform: SceneTransform,
    own: impl FnOnce() -> Result<(Vec<FrameSpec>, String)>,
) -> Result<(Vec<FrameSpec>, String)> {
    let hint = |e: Error| Error::Argument(format!("{e} (carving renders the dataset's train views: give another --data DIR, or --no-carve)"));
    match choice {
        _ if keep_cavities => Ok((vec![], "not carved (--keep-cavities keeps every surface)".into())),
        CarveViews::Off => Ok((vec![], "not carved (--no-carve)".into())),
        CarveViews::Own => own().map_err(hint),
        CarveViews::Data(dir) => dataset_views(dir, None, transform).map_err(hint),
    }
}

/// Render `frames` at their carving size ([`carving_camera`]) through `render` into depth
/// views over `near_far`, with a progress bar when `progress`.
pub fn render_depth_views<E>(
    frames: &[FrameSpec],
    near_far: (f32, f32),
    mut render: impl FnMut(&PinholeCamera, &Pose) -> std::result::Result<RenderedImage, E>,
    progress: bool,
) -> std::result::Result<Vec<DepthView>, E> {
    let bar = if progress { indicatif::ProgressBar::new(frames.len() as u64) } else { indicatif::ProgressBar::hidden() };
    bar.set_style(indicatif::ProgressStyle::with_template("carve [{elapsed_precise}<{eta_precise}] {wide_bar} {pos}/{len} views").expect("valid template"));
    let mut views = Vec::with_capacity(frames.len());
    for frame in frames {
        let camera = carving_camera(&frame.camera);
        let image = render(&camera, &frame.pose)?;
        views.push(DepthView::from_render(camera, &frame.pose, near_far, &image));
        bar.inc(1);
    }
    bar.finish_and_clear();
    Ok(views)
}

#[cfg(test)]
mod tests;
