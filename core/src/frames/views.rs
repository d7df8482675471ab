//! Which views to render: the one way `nerf eval`/`render` and `nerf-render` choose them. An
//! orbit (a capture's recorded camera path, else the reference orbit), a split of a dataset
//! (poses mapped through the run's recorded placement, never refitted; ground truth when its
//! images are there), or named poses a bundle stores.

use super::spec::FrameSpec;
use crate::camera::{PinholeCamera, Pose, SceneTransform};
use crate::dataset::{Background, CameraPath, CaptureFormat, CaptureSplit, LoadOptions, SceneFrame, load_dataset};
use crate::error::Result;
use std::path::PathBuf;

/// A split of a dataset to render: directory, format (`None`: detected), split, downscale.
#[derive(Debug, Clone, PartialEq)]
pub struct SplitChoice {
    /// Dataset directory.
    pub dir: PathBuf,
    /// Its format, `None` to detect it.
    pub format: Option<CaptureFormat>,
    /// train, val, test or all.
    pub split: CaptureSplit,
    /// Image downscale factor.
    pub downscale: u32,
}

/// What to do about a split's images.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Images {
    /// Load them as ground truth; missing images are an error (metrics need them).
    Required,
    /// Load them when they are there; otherwise render the poses alone, with a note.
    IfPresent,
    /// Poses only.
    Skip,
}

/// The views of `choice`, poses mapped by `transform` into the field, images composited on
/// `background`. Warnings of the parsers (images skipped) are printed.
pub fn split_views(choice: &SplitChoice, transform: SceneTransform, background: Background, images: Images) -> Result<Vec<FrameSpec>> {
    let options = |load_images| LoadOptions { format: choice.format, downscale: choice.downscale, images: load_images, background, frame: SceneFrame::Recorded(transform) };
    let loaded = match images {
        Images::Required => load_dataset(&choice.dir, choice.split, &options(true))?,
        Images::Skip => load_dataset(&choice.dir, choice.split, &options(false))?,
        Images::IfPresent => match load_dataset(&choice.dir, choice.split, &options(true)) {
            Ok(d) => d,
            Err(with_images) => {
                let d = load_dataset(&choice.dir, choice.split, &options(false))?;
                eprintln!("note: rendering the {} poses without metrics: {with_images}", choice.split);
                d
            }
        },
    };
    for w in &loaded.warnings {
        eprintln!("warning: {w}");
    }
    Ok(FrameSpec::from_split(loaded.data))
}

/// `frames` poses of the orbit: along a capture's recorded `path`, else the reference orbit
/// (radius 4, elevation −30°).
pub fn orbit_poses(path: Option<&CameraPath>, frames: usize) -> Vec<Pose> {
    match path {
        Some(path) => path.poses(frames),
        None => Pose::orbit(frames),
    }
}

/// Named poses (a bundle's test views) seen through `camera`.
pub fn named_views<'a>(camera: &PinholeCamera, poses: impl IntoIterator<Item = (&'a str, Pose)>) -> Vec<FrameSpec> {
    poses.into_iter().map(|(name, pose)| FrameSpec { name: name.to_string(), camera: *camera, pose, target: None }).collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::Intrinsics;
    use crate::dataset::{SyntheticSceneConfig, generate_scene};

    #[test]
    fn orbits_splits_and_named_poses() {
        assert_eq!(orbit_poses(None, 5), Pose::orbit(5));
        let dir = tempfile::tempdir().unwrap();
        generate_scene(dir.path(), &SyntheticSceneConfig::default()).unwrap();
        let choice = SplitChoice { dir: dir.path().to_path_buf(), format: None, split: CaptureSplit::Test, downscale: 1 };
        let white = Background::from_white(true);
        let with = split_views(&choice, SceneTransform::identity(), white, Images::Required).unwrap();
        let without = split_views(&choice, SceneTransform::identity(), white, Images::Skip).unwrap();
        assert!(!with.is_empty() && with.iter().all(|f| f.target.is_some()));
        assert!(without.iter().all(|f| f.target.is_none()));
        assert_eq!(with.iter().map(|f| (&f.name, f.pose)).collect::<Vec<_>>(), without.iter().map(|f| (&f.name, f.pose)).collect::<Vec<_>>());
        // A moved scene: the recorded transform is applied, not refitted.
        let shifted = SceneTransform { translation: [1.0, 0.0, 0.0], ..SceneTransform::identity() };
        let moved = split_views(&choice, shifted, white, Images::Skip).unwrap();
        assert!((moved[0].pose.0[0][3] - with[0].pose.0[0][3] - 1.0).abs() < 1e-5, "{:?} vs {:?}", moved[0].pose, with[0].pose);
        // Images missing: required is an error, if-present falls back to the poses.
        std::fs::remove_dir_all(dir.path().join("test")).unwrap();
        assert!(split_views(&choice, SceneTransform::identity(), white, Images::Required).is_err());
        let fallback = split_views(&choice, SceneTransform::identity(), white, Images::IfPresent).unwrap();
        assert_eq!(fallback.len(), with.len());
        let camera = PinholeCamera::from(Intrinsics { width: 4, height: 4, focal: 4.0 });
        let named = named_views(&camera, [("a", Pose::orbit(1)[0])]);
        assert_eq!((named[0].name.as_str(), named[0].camera), ("a", camera));
    }
}
