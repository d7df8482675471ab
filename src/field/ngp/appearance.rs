//! Per-image appearance (nerfacto's appearance embedding): each training image has a learnt
//! code that the colour MLP sees, so exposure and white-balance changes between photos are
//! explained by the code instead of being painted into the scene.
//!
//! nerfacto concatenates a 32-wide embedding to the colour MLP's input; its contribution to
//! color.0's pre-activation is the embedding times the rows of color.0 that read it. Here the
//! code is that contribution itself: `color_hidden` wide, added to color.0's pre-activation
//! (nerfacto's form with the embedding as wide as the layer and those rows the identity). So a
//! fixed appearance (the codes' mean, or one training image's) is exactly a bias of color.0,
//! and a bundle holds it in color.0's `Gemm` bias: every renderer renders it unchanged.
//!
//! The codes start at zero (the field starts as one without appearance) and take dense Adam
//! steps with the MLPs' learning rate and moments. Saved in checkpoints as
//! [`APPEARANCE_FILE`], with the training images' names, so a fixed appearance can name one.

use crate::error::{Error, Result};
use crate::train::adam::DenseAdam;
pub use nerf_bundle::scene::FixedAppearance;
use serde::{Deserialize, Serialize};
use std::path::Path;

/// The codes and their Adam state in a checkpoint directory.
pub const APPEARANCE_FILE: &str = "appearance.json";

/// One code per training image and their Adam state.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Appearance {
    /// The training images' names, in the order of the codes.
    images: Vec<String>,
    /// Floats per code (the colour MLP's hidden width).
    width: usize,
    /// `[images, width]` row-major.
    codes: Vec<f32>,
    /// Adam's steps taken and moments, laid out as `codes`.
    steps: u64,
    first: Vec<f32>,
    second: Vec<f32>,
}

impl Appearance {
    /// Zero codes of `width` for `images`.
    pub fn new(images: Vec<String>, width: usize) -> Self {
        let n = images.len() * width;
        Appearance { images, width, codes: vec![0.0; n], steps: 0, first: vec![0.0; n], second: vec![0.0; n] }
    }

    /// The codes, `[images, width]`.
    pub fn codes(&self) -> &[f32] {
        &self.codes
    }

    /// The training images' names, in the codes' order.
    pub fn images(&self) -> &[String] {
        &self.images
    }

    /// The code that renders, as `fixed` says; an unknown image is an error that lists the
    /// known ones.
    pub fn fixed_code(&self, fixed: &FixedAppearance) -> std::result::Result<Vec<f32>, String> {
        let w = self.width;
        match fixed {
            FixedAppearance::Mean => {
                let n = self.images.len().max(1) as f64;
                Ok((0..w).map(|c| (self.codes.iter().skip(c).step_by(w).map(|&v| v as f64).sum::<f64>() / n) as f32).collect())
            }
            FixedAppearance::Image { image } => match self.images.iter().position(|i| i == image) {
                Some(k) => Ok(self.codes[k * w..(k + 1) * w].to_vec()),
                None => {
                    let shown: Vec<&str> = self.images.iter().take(8).map(String::as_str).collect();
                    let more = if self.images.len() > 8 { format!(", … ({} in all)", self.images.len()) } else { String::new() };
                    Err(format!("no training image is named {image:?} (the run's images: {}{more}); use one of them or \"mean\"", shown.join(", ")))
                }
            },
        }
    }

    /// One Adam step (burn's: bias-corrected moments, ε outside the root) on `grad`, laid out
    /// as the codes.
    pub fn step(&mut self, grad: &[f32], lr: f32, beta1: f32, beta2: f32, epsilon: f32) {
        self.steps += 1;
        DenseAdam { beta1, beta2, epsilon }.update(&mut self.codes, &mut self.first, &mut self.second, grad, self.steps, lr);
    }

    /// The file's bytes (JSON: floats round-trip exactly).
    pub fn to_bytes(&self) -> Vec<u8> {
        serde_json::to_vec(self).expect("appearance serialises")
    }

    /// Read [`APPEARANCE_FILE`] of `dir`, checked against `width` (the run's colour MLP).
    pub fn read(dir: &Path, width: usize) -> Result<Self> {
        let path = dir.join(APPEARANCE_FILE);
        let bytes = crate::run_dir::read(&path)?;
        let bad = |problem: String| Error::invalid(&path, problem);
        let a: Appearance = serde_json::from_slice(&bytes).map_err(|e| bad(format!("not an appearance file: {e}")))?;
        let n = a.images.len() * a.width;
        if a.width != width {
            return Err(bad(format!("codes are {} wide, the run's colour MLP is {width} wide", a.width)));
        }
        if a.images.is_empty() || [a.codes.len(), a.first.len(), a.second.len()].iter().any(|&l| l != n) {
            return Err(bad(format!("{} images of {} floats need {n} codes and moments each (truncated?)", a.images.len(), a.width)));
        }
        if a.codes.iter().chain(&a.first).chain(&a.second).any(|v| !v.is_finite()) {
            return Err(bad("a code or moment is not finite".into()));
        }
        Ok(a)
    }
}

/// A field's codes and the fixed one it renders with.
#[derive(Debug, Clone, PartialEq)]
pub struct RenderedAppearance {
    codes: Appearance,
    fixed: FixedAppearance,
    code: Vec<f32>,
}

impl RenderedAppearance {
    /// `codes` rendering as `fixed` says (an error names an unknown image).
    pub fn new(codes: Appearance, fixed: FixedAppearance) -> std::result::Result<Self, String> {
        let code = codes.fixed_code(&fixed)?;
        Ok(RenderedAppearance { codes, fixed, code })
    }

    /// The code every point is rendered with, color.0's bias (`[color_hidden]`).
    pub fn code(&self) -> &[f32] {
        &self.code
    }

    /// Which code that is.
    pub fn fixed(&self) -> &FixedAppearance {
        &self.fixed
    }

    /// The same codes rendering as `fixed` says.
    pub fn refixed(&self, fixed: FixedAppearance) -> std::result::Result<Self, String> {
        Self::new(self.codes.clone(), fixed)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn names(n: usize) -> Vec<String> {
        (0..n).map(|i| format!("img_{i}")).collect()
    }

    #[test]
    fn fixed_codes_are_the_mean_or_one_image() {
        let mut a = Appearance::new(names(3), 2);
        a.codes = vec![1.0, -2.0, 2.0, 0.0, 6.0, 5.0];
        assert_eq!(a.fixed_code(&FixedAppearance::Mean).unwrap(), vec![3.0, 1.0]);
        assert_eq!(a.fixed_code(&FixedAppearance::parse("img_1")).unwrap(), vec![2.0, 0.0]);
        let err = a.fixed_code(&FixedAppearance::parse("img_7")).unwrap_err();
        assert!(err.contains("img_7") && err.contains("img_0, img_1, img_2") && err.contains("mean"), "{err}");
        let rendered = RenderedAppearance::new(a.clone(), FixedAppearance::parse("img_2")).unwrap();
        assert_eq!((rendered.code(), rendered.fixed()), (&[6.0f32, 5.0][..], &FixedAppearance::parse("img_2")));
        assert!(RenderedAppearance::new(a, FixedAppearance::parse("nope")).is_err());
    }

    #[test]
    fn adam_steps_match_hand_computed_values() {
        let mut a = Appearance::new(names(1), 2);
        a.step(&[0.5, -2.0], 0.1, 0.9, 0.99, 1e-15);
        // First step: m̂ = g, v̂ = g², so each value moves by lr·sign(g).
        assert!((a.codes[0] + 0.1).abs() < 1e-6 && (a.codes[1] - 0.1).abs() < 1e-6, "{:?}", a.codes);
        a.step(&[0.5, 0.0], 0.1, 0.9, 0.99, 1e-15);
        // Second step, first value: m = 0.095, v = 0.0049875 → m̂ = 0.5, v̂ = 0.25 → −0.1 again.
        assert!((a.codes[0] + 0.2).abs() < 1e-6, "{:?}", a.codes);
        // second value: m = −0.18 → m̂ = −0.947…, v = 0.0396 → v̂ = 1.9900… → +0.1·0.6715
        let m_hat = -0.18f32 / (1.0 - 0.81);
        let v_hat = 0.0396f32 / (1.0 - 0.9801);
        assert!((a.codes[1] - (0.1 - 0.1 * m_hat / v_hat.sqrt())).abs() < 1e-6, "{:?}", a.codes);
    }

    #[test]
    fn files_round_trip_and_bad_ones_name_the_file() {
        let dir = tempfile::tempdir().unwrap();
        let mut a = Appearance::new(names(2), 3);
        a.step(&[0.1, 0.2, 0.3, -0.1, 1e-7, 3.0], 0.01, 0.9, 0.99, 1e-15);
        std::fs::write(dir.path().join(APPEARANCE_FILE), a.to_bytes()).unwrap();
        assert_eq!(Appearance::read(dir.path(), 3).unwrap(), a, "floats round-trip exactly");
        let err = Appearance::read(dir.path(), 4).unwrap_err().to_string();
        assert!(err.contains(APPEARANCE_FILE) && err.contains("4 wide"), "{err}");
        let mut short = a.clone();
        short.codes.pop();
        std::fs::write(dir.path().join(APPEARANCE_FILE), short.to_bytes()).unwrap();
        let err = Appearance::read(dir.path(), 3).unwrap_err().to_string();
        assert!(err.contains("truncated"), "{err}");
        std::fs::write(dir.path().join(APPEARANCE_FILE), b"{\"images\": 3}").unwrap();
        assert!(Appearance::read(dir.path(), 3).unwrap_err().to_string().contains("not an appearance file"));
    }
}
