//! Camera refinement (nerfstudio's camera optimiser, `SO3xR3`): each training image's pose gets
//! a learnt correction, a rotation ω (axis × angle) and a translation τ in the field's frame,
//! applied to its rays as `o' = o + τ`, `d' = exp(ω)·d`: the corrected camera-to-world pose is
//! `[exp(ω)·R | c + τ]`. Gradients reach it from the field through the sample points
//! `p = o' + t·d'` and the view directions `d'/|d'|`.
//!
//! As nerfacto: Adam (ε 1e-15) with a learning rate decaying tenfold over 5,000 steps, and an
//! L2 penalty on the corrections (1e-2 · mean ‖τ‖ + 1e-3 · mean ‖ω‖ over the images) that keeps
//! the cameras from drifting together. Unlike nerfacto, the corrections wait
//! [`WARM_UP_STEPS`] for the field to learn the scene's coarse shape, start at a tenth of its
//! rate (1e-4, not 1e-3), and an image's correction moves only in the steps that drew its rays.
//! Measured on fox (2,000 steps, contracted, docs/captures.md): with nerfacto's rate from the
//! first step the corrections wandered (0.13° RMS) and the held-out views, rendered from their
//! recorded poses, lost 1.3 dB; with these, 0.03° RMS and 0.25 dB.
//!
//! Saved in checkpoints as [`CAMERAS_FILE`], with the images' names and their refined poses
//! (the pose each image's rays were last drawn from).

use crate::error::{Error, Result};
use crate::train::adam::DenseAdam;
use glam::{Mat3, Vec3};
use nerf_core::camera::Pose;
use serde::{Deserialize, Serialize};
use std::path::Path;

/// The corrections and their Adam state in a checkpoint directory.
pub const CAMERAS_FILE: &str = "cameras.json";

/// Steps before the corrections start to move.
pub const WARM_UP_STEPS: usize = 500;
/// The learning rate when they start, at the end of its decay, and the steps the decay takes.
const LR_START: f64 = 1e-4;
const LR_END: f64 = 1e-5;
const LR_DECAY_STEPS: f64 = 5000.0;
/// nerfstudio's `trans_l2_penalty` and `rot_l2_penalty`.
const TRANSLATION_PENALTY: f32 = 1e-2;
const ROTATION_PENALTY: f32 = 1e-3;
const ADAM: DenseAdam = DenseAdam { beta1: 0.9, beta2: 0.999, epsilon: 1e-15 };

/// One correction per training image and the Adam state of the six numbers each.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CameraCorrections {
    /// The training images' names, in the order of the corrections.
    images: Vec<String>,
    /// Per image: ω (3), then τ (3).
    corrections: Vec<[f32; 6]>,
    /// Per image: the Adam steps it took (an image takes one in the steps that drew its rays).
    steps: Vec<u64>,
    first: Vec<[f32; 6]>,
    second: Vec<[f32; 6]>,
    /// The refined camera-to-world poses (field frame), for people and tools; written on save.
    #[serde(default)]
    refined_poses: Vec<Pose>,
}

/// The learning rate at step `step` (`None` during the warm-up): exponential decay from the
/// end of the warm-up.
pub fn learning_rate(step: usize) -> Option<f64> {
    let since = step.checked_sub(WARM_UP_STEPS)?;
    Some(LR_START * (LR_END / LR_START).powf((since as f64 / LR_DECAY_STEPS).min(1.0)))
}

/// Rodrigues: the rotation by `|ω|` about `ω`.
pub fn rotation(omega: Vec3) -> Mat3 {
    let theta2 = omega.length_squared();
    let (a, b) = if theta2 < 1e-8 {
        (1.0 - theta2 / 6.0, 0.5 - theta2 / 24.0)
    } else {
        let theta = theta2.sqrt();
        (theta.sin() / theta, (1.0 - theta.cos()) / theta2)
    };
    let k = skew(omega);
    Mat3::IDENTITY + a * k + b * (k * k)
}

/// SO(3)'s left Jacobian at ω: `exp(ω + δ) ≈ exp(J·δ)·exp(ω)`.
fn left_jacobian(omega: Vec3) -> Mat3 {
    let theta2 = omega.length_squared();
    let (b, c) = if theta2 < 1e-8 {
        (0.5 - theta2 / 24.0, 1.0 / 6.0 - theta2 / 120.0)
    } else {
        let theta = theta2.sqrt();
        ((1.0 - theta.cos()) / theta2, (theta - theta.sin()) / (theta2 * theta))
    };
    let k = skew(omega);
    Mat3::IDENTITY + b * k + c * (k * k)
}

/// `[v]×`: `skew(v)·u = v × u`.
fn skew(v: Vec3) -> Mat3 {
    Mat3::from_cols(Vec3::new(0.0, v.z, -v.y), Vec3::new(-v.z, 0.0, v.x), Vec3::new(v.y, -v.x, 0.0))
}

/// The gradients of the corrections, accumulated ray by ray, and which images had rays.
#[derive(Debug, Clone)]
pub struct CorrectionGradient(Vec<[f32; 6]>, Vec<bool>);

impl CorrectionGradient {
    /// Image `image`'s: ω then τ.
    pub fn of(&self, image: usize) -> [f32; 6] {
        self.0[image]
    }
}

impl CameraCorrections {
    /// No correction yet for each of `images`.
    pub fn new(images: Vec<String>) -> Self {
        let n = images.len();
        CameraCorrections { images, corrections: vec![[0.0; 6]; n], steps: vec![0; n], first: vec![[0.0; 6]; n], second: vec![[0.0; 6]; n], refined_poses: vec![] }
    }

    /// The training images' names, in order.
    pub fn images(&self) -> &[String] {
        &self.images
    }

    fn omega(&self, image: usize) -> Vec3 {
        Vec3::from_slice(&self.corrections[image][..3])
    }

    fn tau(&self, image: usize) -> Vec3 {
        Vec3::from_slice(&self.corrections[image][3..])
    }

    /// Image `image`'s pose, corrected: `[exp(ω)·R | c + τ]`.
    pub fn corrected(&self, image: usize, pose: &Pose) -> Pose {
        let r = rotation(self.omega(image)) * pose.rotation();
        let c = pose.origin() + self.tau(image);
        let col = |k: usize| r.col(k);
        Pose([0, 1, 2].map(|i| [col(0)[i], col(1)[i], col(2)[i], c[i]]))
    }

    /// A zero gradient.
    pub fn zero_gradient(&self) -> CorrectionGradient {
        CorrectionGradient(vec![[0.0; 6]; self.images.len()], vec![false; self.images.len()])
    }

    /// Add one ray of image `image` to `grad`: its corrected direction `d'`, and the loss's
    /// gradients with respect to its origin and its (unnormalised) direction.
    pub fn add_ray(&self, grad: &mut CorrectionGradient, image: usize, direction: [f32; 3], grad_origin: [f32; 3], grad_direction: [f32; 3]) {
        // d' = exp(ω)·d: ∂d'/∂ω = −[d']×·J(ω), so ∂L/∂ω = J(ω)ᵀ·(d' × ∂L/∂d').
        let g_omega = left_jacobian(self.omega(image)).transpose() * Vec3::from(direction).cross(Vec3::from(grad_direction));
        grad.1[image] = true;
        let g = &mut grad.0[image];
        for a in 0..3 {
            g[a] += g_omega[a];
            g[3 + a] += grad_origin[a];
        }
    }

    /// One Adam step at `lr` on `grad` plus the penalty's gradient, for the images that had
    /// rays (sparse, as the hash table's Adam: an image not drawn keeps its correction and
    /// moments rather than drifting on its momentum).
    pub fn step(&mut self, grad: &CorrectionGradient, lr: f32) {
        let n = self.images.len().max(1) as f32;
        for (k, g) in grad.0.iter().enumerate().filter(|&(k, _)| grad.1[k]) {
            self.steps[k] += 1;
            // ∂(λ·mean‖v‖)/∂v = λ·v/(n‖v‖), 0 at v = 0.
            let penalty = |v: Vec3, lambda: f32| if v.length() > 0.0 { v * (lambda / (n * v.length())) } else { Vec3::ZERO };
            let (p_omega, p_tau) = (penalty(self.omega(k), ROTATION_PENALTY), penalty(self.tau(k), TRANSLATION_PENALTY));
            let g: [f32; 6] = std::array::from_fn(|a| g[a] + if a < 3 { p_omega[a] } else { p_tau[a - 3] });
            ADAM.update(&mut self.corrections[k], &mut self.first[k], &mut self.second[k], &g, self.steps[k], lr);
        }
    }

    /// Rotation angle (radians) and translation length of the largest corrections.
    pub fn largest(&self) -> (f32, f32) {
        (0..self.images.len()).fold((0.0f32, 0.0f32), |(r, t), k| (r.max(self.omega(k).length()), t.max(self.tau(k).length())))
    }

    /// The file's bytes, with the refined poses of `poses` (the training images' recorded ones).
    pub fn to_bytes(&self, poses: &[Pose]) -> Vec<u8> {
        let refined_poses = poses.iter().enumerate().map(|(k, p)| self.corrected(k, p)).collect();
        serde_json::to_vec(&CameraCorrections { refined_poses, ..self.clone() }).expect("corrections serialise")
    }

    /// Read [`CAMERAS_FILE`] of `dir`.
    pub fn read(dir: &Path) -> Result<Self> {
        let path = dir.join(CAMERAS_FILE);
        let bytes = crate::run_dir::read(&path)?;
        let bad = |problem: String| Error::invalid(&path, problem);
        let c: CameraCorrections = serde_json::from_slice(&bytes).map_err(|e| bad(format!("not a camera-corrections file: {e}")))?;
        let n = c.images.len();
        if n == 0 || c.corrections.len() != n || c.steps.len() != n || c.first.len() != n || c.second.len() != n {
            return Err(bad(format!("{n} images need {n} corrections and moments each (truncated?)")));
        }
        if c.corrections.iter().chain(&c.first).chain(&c.second).flatten().any(|v| !v.is_finite()) {
            return Err(bad("a correction or moment is not finite".into()));
        }
        Ok(CameraCorrections { refined_poses: vec![], ..c })
    }

    /// The same corrections with parameter `a` (ω then τ) of image `image` moved by `delta`
    /// (finite differences in tests).
    pub fn nudged(&self, image: usize, a: usize, delta: f32) -> Self {
        let mut out = self.clone();
        out.corrections[image][a] += delta;
        out
    }

    /// The pose of the image named `name`, corrected, if it is one of them.
    pub fn corrected_by_name(&self, name: &str, pose: &Pose) -> Option<Pose> {
        self.images.iter().position(|i| i == name).map(|k| self.corrected(k, pose))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn pose() -> Pose {
        Pose::from_mat4(glam::Mat4::from_rotation_translation(glam::Quat::from_euler(glam::EulerRot::XYZ, 0.3, -0.7, 1.1), Vec3::new(0.5, -1.0, 2.0)))
    }

    #[test]
    fn rotations_and_corrections_match_hand_computed_values() {
        // A quarter turn about z takes x to y.
        let r = rotation(Vec3::new(0.0, 0.0, std::f32::consts::FRAC_PI_2));
        assert!((r * Vec3::X - Vec3::Y).length() < 1e-6);
        assert!((rotation(Vec3::new(1e-6, 0.0, 0.0)) - Mat3::IDENTITY).abs_diff_eq(Mat3::ZERO, 1e-5));
        let mut c = CameraCorrections::new(vec!["a".into(), "b".into()]);
        assert_eq!(c.corrected(0, &pose()), pose(), "no correction at the start");
        c.corrections[1] = [0.0, 0.0, std::f32::consts::FRAC_PI_2, 1.0, 2.0, 3.0];
        let moved = c.corrected(1, &pose());
        assert!((moved.origin() - pose().origin() - Vec3::new(1.0, 2.0, 3.0)).length() < 1e-6);
        let d = Vec3::new(0.2, -0.4, -1.0);
        assert!((moved.rotation() * d - r * (pose().rotation() * d)).length() < 1e-5);
        assert_eq!(c.corrected_by_name("b", &pose()), Some(moved));
        assert_eq!(c.corrected_by_name("z", &pose()), None);
        assert_eq!((learning_rate(0), learning_rate(WARM_UP_STEPS - 1)), (None, None));
        let lr = |step: usize| learning_rate(WARM_UP_STEPS + step).unwrap();
        assert!((lr(0) - 1e-4).abs() < 1e-15 && (lr(2500) - 1e-4 * 0.1f64.sqrt()).abs() < 1e-12 && lr(9000) == 1e-5);
    }

    #[test]
    fn the_gradient_matches_finite_differences() {
        // A loss on one ray's points and direction: L = Σ_s g_s·(o' + t_s·d') + h·d'.
        let mut c = CameraCorrections::new(vec!["a".into()]);
        c.corrections[0] = [0.3, -0.2, 0.5, 0.1, 0.2, -0.3];
        let camera_dir = Vec3::new(0.1, -0.3, -1.0);
        let ts = [0.5f32, 1.7, 3.0];
        let gs = [Vec3::new(0.3, -1.0, 0.2), Vec3::new(-0.5, 0.4, 0.9), Vec3::new(0.7, 0.1, -0.6)];
        let h = Vec3::new(0.2, 0.8, -0.4);
        let loss = |c: &CameraCorrections| {
            let p = c.corrected(0, &pose());
            let (o, d) = (p.origin(), p.rotation() * camera_dir);
            ts.iter().zip(&gs).map(|(&t, g)| g.dot(o + t * d) as f64).sum::<f64>() + h.dot(d) as f64
        };
        let p = c.corrected(0, &pose());
        let d = p.rotation() * camera_dir;
        let grad_origin: Vec3 = gs.iter().sum();
        let grad_direction = ts.iter().zip(&gs).map(|(&t, &g)| t * g).sum::<Vec3>() + h;
        let mut grad = c.zero_gradient();
        c.add_ray(&mut grad, 0, d.to_array(), grad_origin.to_array(), grad_direction.to_array());
        for a in 0..6 {
            let eps = 1e-3f32;
            let (mut hi, mut lo) = (c.clone(), c.clone());
            hi.corrections[0][a] += eps;
            lo.corrections[0][a] -= eps;
            let numeric = (loss(&hi) - loss(&lo)) / (2.0 * eps as f64);
            assert!((grad.0[0][a] as f64 - numeric).abs() < 2e-3 * (1.0 + numeric.abs()), "parameter {a}: {} vs {numeric}", grad.0[0][a]);
        }
    }

    #[test]
    fn steps_move_against_the_gradient_and_files_round_trip() {
        let mut c = CameraCorrections::new(vec!["a".into(), "b".into()]);
        let mut grad = c.zero_gradient();
        grad.0[0] = [1.0, -1.0, 0.0, 0.5, 0.0, -2.0];
        grad.1[0] = true;
        c.step(&grad, 1e-3);
        // The first Adam step moves each value with a gradient by lr against its sign.
        assert_eq!(c.corrections[0].map(|v| (v * 1e4).round() / 1e4), [-1e-3, 1e-3, 0.0, -1e-3, 0.0, 1e-3]);
        assert_eq!(c.corrections[1], [0.0; 6]);
        // With no gradient from the images, the penalty pulls a correction back towards zero.
        let mut held = CameraCorrections::new(vec!["a".into()]);
        held.corrections[0] = [0.02, 0.0, -0.01, 0.3, -0.4, 0.0];
        let mut drawn = held.zero_gradient();
        drawn.1[0] = true;
        held.step(&drawn, 1e-3);
        assert_eq!(held.steps, [1]);
        // An image without rays this step is left as it is.
        let before = held.clone();
        held.step(&held.zero_gradient(), 1e-3);
        assert_eq!(held, before);
        assert_eq!(held.corrections[0].map(|v| (v * 1e4).round() / 1e4), [0.019, 0.0, -0.009, 0.299, -0.399, 0.0]);
        let dir = tempfile::tempdir().unwrap();
        std::fs::write(dir.path().join(CAMERAS_FILE), c.to_bytes(&[pose(), pose()])).unwrap();
        let text = std::fs::read_to_string(dir.path().join(CAMERAS_FILE)).unwrap();
        assert!(text.contains("refined_poses"), "the refined poses are written for people and tools");
        assert_eq!(CameraCorrections::read(dir.path()).unwrap(), c, "floats round-trip exactly");
        std::fs::write(dir.path().join(CAMERAS_FILE), b"{\"images\": []}").unwrap();
        let err = CameraCorrections::read(dir.path()).unwrap_err().to_string();
        assert!(err.contains(CAMERAS_FILE) && err.contains("not a camera-corrections file"), "{err}");
    }
}
