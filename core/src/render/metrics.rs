//! Image quality metrics (MSE, PSNR, SSIM) and the evaluation report written by `nerf eval`
//! (which adds LPIPS, computed through onnxruntime outside the core).
//!
//! Images are row-major `[f32; 3]` RGB buffers with values in `[0, 1]` (data range 1).

use std::path::Path;

use serde::{Deserialize, Deserializer, Serialize};

use crate::io::atomic::write_atomic;
use crate::error::{Error, Result};

/// Mean squared error over all pixels and channels.
///
/// # Panics
/// If the images differ in length.
pub fn mse(a: &[[f32; 3]], b: &[[f32; 3]]) -> f32 {
    assert_eq!(a.len(), b.len(), "mse: images differ in size");
    if a.is_empty() {
        return 0.0;
    }
    let sum: f64 = a
        .iter()
        .zip(b)
        .map(|(p, q)| (0..3).map(|c| ((p[c] - q[c]) as f64).powi(2)).sum::<f64>())
        .sum();
    (sum / (3 * a.len()) as f64) as f32
}

/// PSNR in dB for a data range of 1: `−10·log10(mse)` (infinite for `mse = 0`).
pub fn psnr_from_mse(mse: f32) -> f32 {
    -10.0 * mse.log10()
}

/// PSNR in dB between two images (see [`mse`]).
pub fn psnr(a: &[[f32; 3]], b: &[[f32; 3]]) -> f32 {
    psnr_from_mse(mse(a, b))
}

/// The SSIM window side for an image: 11, shrunk to the smaller image side (kept odd).
fn window_size(width: usize, height: usize) -> usize {
    let k = 11.min(width).min(height);
    if k.is_multiple_of(2) { k - 1 } else { k }
}

/// Normalised 1-D Gaussian of `size` taps, σ = 1.5, centred on the middle tap.
fn gaussian_taps(size: usize) -> Vec<f64> {
    let centre = (size as f64 - 1.0) / 2.0;
    let raw: Vec<f64> = (0..size)
        .map(|k| (-(k as f64 - centre).powi(2) / (2.0 * 1.5 * 1.5)).exp())
        .collect();
    let total: f64 = raw.iter().sum();
    raw.into_iter().map(|v| v / total).collect()
}

/// Separable 'valid' filtering of a `width×height` map: `(width−k+1)×(height−k+1)` outputs.
fn filter_valid(map: &[f64], width: usize, height: usize, taps: &[f64]) -> Vec<f64> {
    let k = taps.len();
    let (ow, oh) = (width + 1 - k, height + 1 - k);
    // Horizontal pass over all rows.
    let mut horiz = vec![0.0; ow * height];
    for j in 0..height {
        let row = &map[j * width..(j + 1) * width];
        for i in 0..ow {
            horiz[j * ow + i] = taps.iter().zip(&row[i..i + k]).map(|(t, v)| t * v).sum();
        }
    }
    // Vertical pass.
    let mut out = vec![0.0; ow * oh];
    for j in 0..oh {
        for (t, tap) in taps.iter().enumerate() {
            let src = &horiz[(j + t) * ow..(j + t + 1) * ow];
            for (o, s) in out[j * ow..(j + 1) * ow].iter_mut().zip(src) {
                *o += tap * s;
            }
        }
    }
    out
}

/// The structural similarity index (Wang et al. 2004) as reported by the NeRF papers and
/// computed by `tf.image.ssim` / skimage (`gaussian_weights=True`, `use_sample_covariance=False`):
/// an 11×11 Gaussian window with σ = 1.5, C1 = 0.01², C2 = 0.03² (data range 1), evaluated per
/// channel on the 'valid' region (no padding), then averaged over positions and channels.
/// Images smaller than 11 pixels in a side use the largest odd window that fits. Variances are
/// clamped at 0 against round-off.
///
/// # Panics
/// If the images differ in length, or their length is not `width·height`, or either is empty.
pub fn ssim(a: &[[f32; 3]], b: &[[f32; 3]], width: usize, height: usize) -> f32 {
    assert_eq!(a.len(), b.len(), "ssim: images differ in size");
    assert_eq!(
        a.len(),
        width * height,
        "ssim: {} pixels is not {width}×{height}",
        a.len()
    );
    assert!(width > 0 && height > 0, "ssim: empty image");
    const C1: f64 = 0.01 * 0.01;
    const C2: f64 = 0.03 * 0.03;
    let taps = gaussian_taps(window_size(width, height));
    let mut total = 0.0;
    let mut count = 0usize;
    for c in 0..3 {
        let x: Vec<f64> = a.iter().map(|p| p[c] as f64).collect();
        let y: Vec<f64> = b.iter().map(|p| p[c] as f64).collect();
        let xx: Vec<f64> = x.iter().map(|v| v * v).collect();
        let yy: Vec<f64> = y.iter().map(|v| v * v).collect();
        let xy: Vec<f64> = x.iter().zip(&y).map(|(u, v)| u * v).collect();
        let f = |m: &[f64]| filter_valid(m, width, height, &taps);
        let (mx, my, mxx, myy, mxy) = (f(&x), f(&y), f(&xx), f(&yy), f(&xy));
        for k in 0..mx.len() {
            let (ux, uy) = (mx[k], my[k]);
            let vx = (mxx[k] - ux * ux).max(0.0);
            let vy = (myy[k] - uy * uy).max(0.0);
            let cov = mxy[k] - ux * uy;
            let s = ((2.0 * ux * uy + C1) * (2.0 * cov + C2))
                / ((ux * ux + uy * uy + C1) * (vx + vy + C2));
            total += s;
            count += 1;
        }
    }
    (total / count as f64) as f32
}

/// Metrics of one rendered image against its ground truth.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ImageMetrics {
    /// The view's name (file stem, e.g. `r_0`).
    pub name: String,
    /// PSNR in dB (JSON `null`, read back as NaN, when infinite).
    #[serde(deserialize_with = "f32_or_nan")]
    pub psnr: f32,
    /// SSIM.
    #[serde(deserialize_with = "f32_or_nan")]
    pub ssim: f32,
    /// LPIPS (AlexNet), when it was computed (`nerf eval` with the weights installed).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub lpips: Option<f32>,
}

/// The evaluation report (`metrics.json`): means and per-image values.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct EvalReport {
    /// Mean PSNR over the images (dB); NaN (JSON `null`) when there are none.
    #[serde(deserialize_with = "f32_or_nan")]
    pub psnr_mean: f32,
    /// Mean SSIM over the images; NaN (JSON `null`) when there are none.
    #[serde(deserialize_with = "f32_or_nan")]
    pub ssim_mean: f32,
    /// Mean LPIPS over the images, when every image has one.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub lpips_mean: Option<f32>,
    /// Why LPIPS is missing, when it was asked for and could not be computed.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub lpips_skipped: Option<String>,
    /// One entry per image, in evaluation order.
    pub per_image: Vec<ImageMetrics>,
}

/// serde_json writes non-finite floats as `null`; read those back as NaN instead of failing.
fn f32_or_nan<'de, D: Deserializer<'de>>(d: D) -> std::result::Result<f32, D::Error> {
    Ok(Option::<f32>::deserialize(d)?.unwrap_or(f32::NAN))
}

impl EvalReport {
    /// The report with the arithmetic means of the per-image PSNR, SSIM and (when every image
    /// has one) LPIPS, computed in f64.
    pub fn from_images(per_image: Vec<ImageMetrics>) -> Self {
        let n = per_image.len() as f64;
        let mean = |f: fn(&ImageMetrics) -> f32| {
            (per_image.iter().map(|m| f(m) as f64).sum::<f64>() / n) as f32
        };
        let lpips: Option<Vec<f32>> = per_image.iter().map(|m| m.lpips).collect();
        let lpips_mean = lpips.filter(|l| !l.is_empty()).map(|l| (l.iter().map(|&v| v as f64).sum::<f64>() / n) as f32);
        EvalReport {
            psnr_mean: mean(|m| m.psnr),
            ssim_mean: mean(|m| m.ssim),
            lpips_mean,
            lpips_skipped: None,
            per_image,
        }
    }

    /// Writes the report as pretty JSON, atomically.
    pub fn write_json(&self, path: &Path) -> Result<()> {
        let mut text = serde_json::to_string_pretty(self).map_err(|source| Error::Json {
            path: path.to_path_buf(),
            source,
        })?;
        text.push('\n');
        write_atomic(path, text.as_bytes())
    }

    /// Reads a report written by [`EvalReport::write_json`].
    pub fn read_json(path: &Path) -> Result<Self> {
        let text = std::fs::read_to_string(path).map_err(|e| Error::io(path, e))?;
        serde_json::from_str(&text).map_err(|source| Error::Json {
            path: path.to_path_buf(),
            source,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn mse_and_psnr_known_values() {
        assert_eq!(psnr_from_mse(0.01), 20.0);
        assert!((psnr_from_mse(0.001) - 30.0).abs() < 1e-5);
        assert_eq!(psnr_from_mse(1.0), 0.0);
        // Errors 0.1 on every channel → mse 0.01 → 20 dB.
        let a = vec![[0.2, 0.4, 0.6]; 6];
        let b = vec![[0.3, 0.5, 0.7]; 6];
        assert!((mse(&a, &b) - 0.01).abs() < 1e-7);
        assert!((psnr(&a, &b) - 20.0).abs() < 1e-4);
        // One channel of one pixel off by 0.6 out of 2 pixels × 3 channels: 0.36 / 6 = 0.06.
        let c = vec![[0.0; 3], [0.0; 3]];
        let d = vec![[0.0; 3], [0.0, 0.6, 0.0]];
        assert!((mse(&c, &d) - 0.06).abs() < 1e-7);
        assert_eq!(psnr(&c, &c), f32::INFINITY);
    }

    #[test]
    fn gaussian_window() {
        assert_eq!(window_size(400, 400), 11);
        assert_eq!(window_size(8, 20), 7);
        assert_eq!(window_size(1, 5), 1);
        // 3 taps: exp(−1/4.5) = 0.800737 → [0.800737, 1, 0.800737] / 2.601475 = [0.307801, 0.384397, 0.307801].
        let t = gaussian_taps(3);
        assert!(
            (t[0] - 0.307801).abs() < 1e-6 && (t[1] - 0.384397).abs() < 1e-6 && t[0] == t[2],
            "{t:?}"
        );
        assert!((gaussian_taps(11).iter().sum::<f64>() - 1.0).abs() < 1e-12);
    }

    #[test]
    fn ssim_identical_is_one() {
        let (w, h) = (16, 13);
        let img: Vec<[f32; 3]> = (0..w * h)
            .map(|k| {
                [
                    (k % 7) as f32 / 7.0,
                    (k % 5) as f32 / 5.0,
                    ((k * 3) % 11) as f32 / 11.0,
                ]
            })
            .collect();
        assert!((ssim(&img, &img, w, h) - 1.0).abs() < 1e-6);
    }

    #[test]
    fn ssim_hand_computed_cases() {
        // Constant 0.5 vs constant 0.6: variances and covariance vanish, so SSIM is the
        // luminance term (2·0.5·0.6 + C1) / (0.25 + 0.36 + C1) = 0.6001 / 0.6101 everywhere.
        let a = vec![[0.5f32; 3]; 20 * 15];
        let b = vec![[0.6f32; 3]; 20 * 15];
        let s = ssim(&a, &b, 20, 15);
        assert!((s - 0.6001 / 0.6101).abs() < 1e-6, "{s}");
        assert!(s < 1.0);

        // 1×1 images: the window shrinks to 1 tap; σ terms are 0, so
        // SSIM = (2xy + C1)/(x² + y² + C1) = (0.25 + 1e-4)/(0.3125 + 1e-4).
        let s = ssim(&[[0.5, 0.5, 0.5]], &[[0.25, 0.25, 0.25]], 1, 1);
        assert!((s - 0.2501 / 0.3126).abs() < 1e-6, "{s}");

        // 3×3: a = 0.5 with a 1.0 centre, b = 0.5. Centre weight w = 0.384397² = 0.147761.
        // μx = 0.5 + 0.5w = 0.573882, μy = 0.5, σx² = 0.25(w − w²) = 0.031482, σy² = σxy = 0.
        // SSIM = (2·0.573882·0.5 + C1)/(0.573882² + 0.25 + C1) · C2/(0.031482 + C2)
        //      = 0.990580 · 0.027793 = 0.027531.
        let mut a = vec![[0.5f32; 3]; 9];
        a[4] = [1.0; 3];
        let b = vec![[0.5f32; 3]; 9];
        let s = ssim(&a, &b, 3, 3);
        assert!((s - 0.027531).abs() < 2e-6, "{s}");
        // Symmetric in its arguments.
        assert!((ssim(&b, &a, 3, 3) - s).abs() < 1e-7);
    }

    #[test]
    fn ssim_valid_region_and_channel_mean() {
        // 12×11 image (window 11 → 2×1 valid positions); only the green channel differs,
        // by a constant shift of 0.1 on a flat 0.3 image: red and blue give 1, green gives
        // (2·0.3·0.4 + C1)/(0.09 + 0.16 + C1) = 0.2401/0.2501. Mean over channels:
        let a = vec![[0.3f32; 3]; 12 * 11];
        let b = vec![[0.3f32, 0.4, 0.3]; 12 * 11];
        let expected = (2.0 + 0.2401 / 0.2501) / 3.0;
        assert!((ssim(&a, &b, 12, 11) - expected).abs() < 1e-6);
    }

    #[test]
    fn report_means_and_json_round_trip() {
        let report = EvalReport::from_images(vec![
            ImageMetrics {
                name: "r_0".into(),
                psnr: 30.0,
                ssim: 0.9,
                lpips: Some(0.1),
            },
            ImageMetrics {
                name: "r_1".into(),
                psnr: 20.0,
                ssim: 0.8,
                lpips: Some(0.2),
            },
            ImageMetrics {
                name: "r_2".into(),
                psnr: 25.0,
                ssim: 1.0,
                lpips: Some(0.6),
            },
        ]);
        assert!((report.psnr_mean - 25.0).abs() < 1e-6);
        assert!((report.ssim_mean - 0.9).abs() < 1e-6);
        assert!((report.lpips_mean.unwrap() - 0.3).abs() < 1e-6);
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("metrics.json");
        report.write_json(&path).unwrap();
        let text = std::fs::read_to_string(&path).unwrap();
        assert!(text.contains("\"psnr_mean\": 25.0"), "{text}");
        assert!(text.contains("\n  \"per_image\""), "pretty: {text}");
        assert_eq!(EvalReport::read_json(&path).unwrap(), report);
        // A perfect image has infinite PSNR: written as null, read back as NaN.
        let inf = EvalReport::from_images(vec![ImageMetrics {
            name: "r_0".into(),
            psnr: f32::INFINITY,
            ssim: 1.0,
            lpips: None,
        }]);
        inf.write_json(&path).unwrap();
        let back = EvalReport::read_json(&path).unwrap();
        assert!(back.psnr_mean.is_nan() && back.per_image[0].psnr.is_nan());
        assert_eq!(back.ssim_mean, 1.0);
        // Without LPIPS the report has no LPIPS keys (and older reports read as such).
        let text = std::fs::read_to_string(&path).unwrap();
        assert!(!text.contains("lpips"), "{text}");
        assert_eq!((back.lpips_mean, back.per_image[0].lpips), (None, None));
        assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 1);
    }
}
