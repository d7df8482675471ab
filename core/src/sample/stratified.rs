//! Where along each ray the networks are evaluated: stratified samples between near and far,
//! and inverse-CDF resampling from the coarse weights (the reference `sample_pdf`).

use crate::camera::{Rays, point_at};
use crate::camera::ndc::Ndc;
use crate::rng::Rng;
use serde::{Deserialize, Serialize};

/// The sampling knobs of the reference pipeline.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SamplingConfig {
    /// Near bound along the ray (in units of the unnormalised direction).
    pub near: f32,
    /// Far bound.
    pub far: f32,
    /// Stratified (coarse) samples per ray.
    pub n_coarse: usize,
    /// Extra samples per ray drawn from the coarse weights (0 = no fine network).
    pub n_fine: usize,
    /// Sample linearly in inverse depth instead of depth.
    pub lindisp: bool,
    /// Forward-facing captures: rays are warped into normalised device coordinates before
    /// sampling (near/far are then 0 and 1, as nerf-pytorch's LLFF default). Absent: world rays.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub ndc: Option<Ndc>,
}

impl Default for SamplingConfig {
    fn default() -> Self {
        SamplingConfig { near: 2.0, far: 6.0, n_coarse: 64, n_fine: 128, lindisp: false, ndc: None }
    }
}

impl SamplingConfig {
    /// World rays into the space samples are taken in: NDC when configured, else unchanged.
    /// Every ray generator (training, renderers, runtime) goes through here.
    pub fn warp_rays(&self, rays: Rays) -> Rays {
        match &self.ndc {
            Some(ndc) => ndc.rays(rays),
            None => rays,
        }
    }
}

/// Sample distances along a batch of rays, the same count on every ray.
///
/// # Shapes
/// `t`: `[n_rays, n_samples]`, row-major, non-decreasing along each ray.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct DenseSamples {
    /// Number of rays.
    pub n_rays: usize,
    /// Samples per ray.
    pub n_samples: usize,
    /// Distances along the (unnormalised) rays.
    pub t: Vec<f32>,
}

impl DenseSamples {
    /// The distances of ray `r`.
    pub fn ray(&self, r: usize) -> &[f32] {
        &self.t[r * self.n_samples..(r + 1) * self.n_samples]
    }

    /// The samples of rays `range` only (as [`Rays::slice`](crate::Rays::slice) for the rays).
    pub fn slice(&self, range: std::ops::Range<usize>) -> DenseSamples {
        let t = self.t[range.start * self.n_samples..range.end * self.n_samples].to_vec();
        DenseSamples { n_rays: range.len(), n_samples: self.n_samples, t }
    }

    /// World positions `o + t·d` of every sample, `[n_rays · n_samples]` of 3-vectors.
    pub fn points(&self, origins: &[[f32; 3]], directions: &[[f32; 3]]) -> Vec<[f32; 3]> {
        let mut out = Vec::with_capacity(self.t.len());
        for r in 0..self.n_rays {
            let (o, d) = (origins[r], directions[r]);
            for &t in self.ray(r) {
                out.push(point_at(o, d, t));
            }
        }
        out
    }

    /// Merge two sample sets ray by ray, sorting each ray's distances (coarse ∪ fine).
    pub fn merge_sorted(&self, other: &DenseSamples) -> DenseSamples {
        assert_eq!(self.n_rays, other.n_rays, "merging samples of different ray counts");
        let n_samples = self.n_samples + other.n_samples;
        let mut t = Vec::with_capacity(self.n_rays * n_samples);
        for r in 0..self.n_rays {
            let start = t.len();
            t.extend_from_slice(self.ray(r));
            t.extend_from_slice(other.ray(r));
            t[start..].sort_by(f32::total_cmp);
        }
        DenseSamples { n_rays: self.n_rays, n_samples, t }
    }
}

/// Stratified samples: `n` evenly spaced distances in [near, far] (or evenly in 1/t with
/// `lindisp`), each jittered uniformly within its interval when `jitter` is given (training),
/// exactly on the grid otherwise (test time).
pub fn stratified(config: &SamplingConfig, n_rays: usize, mut jitter: Option<&mut Rng>) -> DenseSamples {
    let n = config.n_coarse;
    let (near, far) = (config.near, config.far);
    let grid: Vec<f32> = (0..n)
        .map(|k| {
            let s = if n > 1 { k as f32 / (n - 1) as f32 } else { 0.0 };
            if config.lindisp {
                1.0 / (1.0 / near * (1.0 - s) + 1.0 / far * s)
            } else {
                near * (1.0 - s) + far * s
            }
        })
        .collect();
    let mut t = Vec::with_capacity(n_rays * n);
    for _ in 0..n_rays {
        match jitter.as_deref_mut() {
            None => t.extend_from_slice(&grid),
            Some(rng) => {
                // Interval k spans [mid(k−1,k), mid(k,k+1)], clamped to the grid's ends.
                for k in 0..n {
                    let lower = if k == 0 { grid[0] } else { 0.5 * (grid[k - 1] + grid[k]) };
                    let upper = if k + 1 == n { grid[n - 1] } else { 0.5 * (grid[k] + grid[k + 1]) };
                    t.push(lower + (upper - lower) * rng.uniform());
                }
            }
        }
    }
    DenseSamples { n_rays, n_samples: n, t }
}

/// Inverse-CDF sampling of one ray (the reference `sample_pdf`).
///
/// `bins` are the `m + 1` edges, `weights` the `m` weights of the bins between them; `u` the
/// quantiles to invert (sorted for deterministic sampling). Returns one distance per quantile.
/// As in the reference: weights + 1e-5, a CDF starting at 0, right-side search, and a
/// denominator below 1e-5 replaced by 1.
pub fn sample_pdf_ray(bins: &[f32], weights: &[f32], u: &[f32], out: &mut Vec<f32>) {
    debug_assert_eq!(bins.len(), weights.len() + 1);
    let total: f32 = weights.iter().map(|w| w + 1e-5).sum();
    let mut cdf = Vec::with_capacity(bins.len());
    cdf.push(0.0f32);
    let mut acc = 0.0f32;
    for w in weights {
        acc += (w + 1e-5) / total;
        cdf.push(acc);
    }
    let last = cdf.len() - 1;
    for &q in u {
        // Right-side search: the first index whose cdf is strictly greater than q.
        let above_index = cdf.partition_point(|&c| c <= q);
        let below = above_index.saturating_sub(1);
        let above = above_index.min(last);
        let (c0, c1) = (cdf[below], cdf[above]);
        let denom = if c1 - c0 < 1e-5 { 1.0 } else { c1 - c0 };
        let frac = (q - c0) / denom;
        out.push(bins[below] + frac * (bins[above] - bins[below]));
    }
}

/// Hierarchical resampling for a batch: for each ray, the bins are the midpoints of its coarse
/// samples and the weights its coarse weights without the first and last (`weights[1:-1]`).
/// `rng` draws the quantiles (training); without it they are `linspace(0, 1, n_fine)`.
///
/// # Shapes
/// `coarse.t`, `weights`: `[n_rays, n_coarse]` → `[n_rays, n_fine]`, unsorted per ray only in
/// the random case (the caller merges and sorts).
pub fn importance(coarse: &DenseSamples, weights: &[f32], n_fine: usize, mut rng: Option<&mut Rng>) -> DenseSamples {
    let n = coarse.n_samples;
    assert!(n >= 3, "hierarchical sampling needs at least 3 coarse samples");
    assert_eq!(weights.len(), coarse.t.len());
    let det_u: Vec<f32> = (0..n_fine)
        .map(|k| if n_fine > 1 { k as f32 / (n_fine - 1) as f32 } else { 0.0 })
        .collect();
    let mut u = det_u.clone();
    let mut t = Vec::with_capacity(coarse.n_rays * n_fine);
    let mut mids = Vec::with_capacity(n - 1);
    for r in 0..coarse.n_rays {
        let z = coarse.ray(r);
        mids.clear();
        mids.extend(z.windows(2).map(|w| 0.5 * (w[0] + w[1])));
        if let Some(rng) = rng.as_deref_mut() {
            u.iter_mut().for_each(|q| *q = rng.uniform());
        }
        sample_pdf_ray(&mids, &weights[r * n + 1..(r + 1) * n - 1], &u, &mut t);
    }
    DenseSamples { n_rays: coarse.n_rays, n_samples: n_fine, t }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn stratified_grid_and_jitter_stay_in_intervals() {
        let cfg = SamplingConfig { near: 2.0, far: 6.0, n_coarse: 5, n_fine: 0, lindisp: false, ndc: None };
        let det = stratified(&cfg, 2, None);
        assert_eq!(det.ray(1), &[2.0, 3.0, 4.0, 5.0, 6.0]);
        let mut rng = Rng::new(1);
        let jit = stratified(&cfg, 100, Some(&mut rng));
        let bounds = [(2.0, 2.5), (2.5, 3.5), (3.5, 4.5), (4.5, 5.5), (5.5, 6.0)];
        for r in 0..100 {
            for (k, &(lo, hi)) in bounds.iter().enumerate() {
                let t = jit.ray(r)[k];
                assert!(t >= lo && t <= hi, "sample {k} = {t} outside [{lo}, {hi}]");
            }
        }
        assert_ne!(jit.ray(0), det.ray(0));
        let lin = SamplingConfig { lindisp: true, ..cfg };
        let inv = stratified(&lin, 1, None);
        // Evenly spaced in 1/t: 1/2, 1/2 − 1/12·k ... ending at 1/6.
        for (k, t) in inv.ray(0).iter().enumerate() {
            let expect = 1.0 / (0.5 - (0.5 - 1.0 / 6.0) * k as f32 / 4.0);
            assert!((t - expect).abs() < 1e-5);
        }
    }

    #[test]
    fn sample_pdf_inverts_a_piecewise_constant_pdf_exactly() {
        // Bins [0,1],[1,2],[2,3] with weights 0, 3, 1 (+1e-5 each, total 4.00003).
        // cdf = [0, 1e-5/4.00003, 3.00002/4.00003, 1].
        let bins = [0.0, 1.0, 2.0, 3.0];
        let weights = [0.0, 3.0, 1.0];
        let total = 4.00003f32;
        let c1 = 1e-5 / total;
        let c2 = (1e-5 + 3.00001) / total;
        let u = [0.0, 0.25, 0.5, 0.75, 1.0];
        let mut out = Vec::new();
        sample_pdf_ray(&bins, &weights, &u, &mut out);
        let expect = [
            // u=0: right search gives index 1 → bin [0,1]; (0 − 0)/c1 = 0 → 0.
            0.0,
            // u in the second bin: 1 + (u − c1)/(c2 − c1).
            1.0 + (0.25 - c1) / (c2 - c1),
            1.0 + (0.5 - c1) / (c2 - c1),
            // u=0.75 > c2 ≈ 0.750004? no: c2 = 3.00002/4.00003 = 0.7500006 > 0.75.
            1.0 + (0.75 - c1) / (c2 - c1),
            // u=1: index past the end → below = above = 3, denominator 0 → 1: t = 3.
            3.0,
        ];
        for (o, e) in out.iter().zip(expect) {
            assert!((o - e).abs() < 1e-5, "{out:?} vs {expect:?}");
        }
        // Concretely: half the mass lies in [1, 2], so u = 0.5 lands at ≈ 1.6667.
        assert!((out[2] - 1.666_67).abs() < 1e-3);
    }

    #[test]
    fn importance_uses_midpoints_and_inner_weights() {
        // Coarse t = 0..=5 → mids 0.5..4.5 (5 edges, 4 bins), inner weights = w[1..5].
        let coarse = DenseSamples { n_rays: 1, n_samples: 6, t: (0..6).map(|k| k as f32).collect() };
        // All mass on inner weight index 2 → bin [2.5, 3.5].
        let weights = [100.0, 0.0, 0.0, 1.0, 0.0, 100.0];
        let fine = importance(&coarse, &weights, 3, None);
        assert_eq!(fine.n_samples, 3);
        let t = fine.ray(0);
        assert!(t[0] < 2.5 + 1e-3, "{t:?}");
        assert!((t[1] - 3.0).abs() < 1e-3, "{t:?}");
        // u = 1 sits at the end of the CDF: the top of the last bin with mass or beyond.
        assert!(t[2] >= 3.5 - 1e-3 && t[2] <= 4.5, "{t:?}");
        let merged = coarse.merge_sorted(&fine);
        assert_eq!(merged.n_samples, 9);
        assert!(merged.ray(0).windows(2).all(|w| w[0] <= w[1]));
    }
}
