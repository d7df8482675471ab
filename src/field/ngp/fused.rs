//! The hash-grid field's two MLPs, forward and backward, in plain Rust: every layer of a block of
//! rows runs before the next block starts (as tiny-cuda-nn fuses them on the GPU), so the
//! activations stay in cache, both cores share all the work (burn-flex runs elementwise kernels
//! on one thread) and no autodiff graph is built. The matrix products are `gemm`'s kernels
//! (burn-flex's own, AVX-512 chosen at run time). Same weights and layout as [`NgpMlps`]
//! (`[in, out]`, row-major, bias-free); its gradients are summed in a fixed order, so a step is
//! deterministic whatever the number of threads.

use super::NgpMlps;
use burn::tensor::{Device, Tensor, TensorData};
use nerf_core::field::ngp::NgpSpec;
use nerf_core::field::ngp::spherical_harmonics::SH4_DIM;
use rayon::prelude::*;

/// Rows that go through all the layers together (their activations fit in L2).
const BLOCK_ROWS: usize = 128;
/// Contiguous runs of blocks whose weight gradients add up in one buffer; the runs' sums are
/// added in order. Fixed, so that the result does not depend on the thread count.
const GRADIENT_RUNS: usize = 32;
/// instant-ngp's `trunc_exp`: σ = exp(x), its gradient exp(clamp(x, ±15)).
const TRUNC_EXP_CLAMP: f32 = 15.0;

/// The widths of the two MLPs.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
struct Widths {
    /// Grid features (L·F).
    features: usize,
    density_hidden: usize,
    /// The density MLP's outputs after σ.
    geometry: usize,
    color_hidden: usize,
}

impl Widths {
    fn of(spec: &NgpSpec) -> Self {
        Widths { features: spec.grid.output_dim(), density_hidden: spec.density_hidden, geometry: spec.geometry_features, color_hidden: spec.color_hidden }
    }

    /// The density MLP's outputs: σ's pre-activation, then the geometry features.
    fn density_out(&self) -> usize {
        1 + self.geometry
    }

    /// Sizes of the five weight matrices, in [`NgpSpec::layer_shapes`] order.
    fn weight_lens(&self) -> [usize; 5] {
        let Widths { features: f, density_hidden: h, geometry: g, color_hidden: c } = *self;
        [f * h, h * (1 + g), (g + SH4_DIM) * c, c * c, c * 3]
    }

    /// Floats saved per row between forward and backward: the two MLPs' activations.
    fn saved_per_row(&self) -> usize {
        self.density_hidden + self.density_out() + 2 * self.color_hidden + 3
    }
}

/// The MLPs' weights as plain arrays (a copy of an [`NgpMlps`]).
#[derive(Debug, Clone, PartialEq)]
pub struct FusedMlps {
    widths: Widths,
    /// density.0, density.1, color.0, color.1, color.2, each `[in, out]`.
    weights: [Vec<f32>; 5],
    /// A bias of color.0 for every row: a field's fixed appearance (`[color_hidden]`; see
    /// [`super::appearance`]). `None`: the MLPs are bias-free.
    color_bias: Option<Vec<f32>>,
}

/// Learnt codes added to color.0's pre-activation row by row: row `r` adds code
/// `code_of_row[r]` of `codes` (`[codes, color_hidden]` row-major), the appearance of the
/// image the row's ray came from ([`super::appearance`]).
#[derive(Debug, Clone, Copy)]
pub struct RowCodes<'a> {
    /// The codes, `[codes, color_hidden]`.
    pub codes: &'a [f32],
    /// One code index per row.
    pub code_of_row: &'a [u32],
}

impl<'a> RowCodes<'a> {
    /// The codes of rows `r0..r1`.
    fn rows(self, r0: usize, r1: usize) -> Self {
        RowCodes { codes: self.codes, code_of_row: &self.code_of_row[r0..r1] }
    }
}

/// The weights' gradients, in the same order and layout as the weights, and the codes'
/// gradient when the pass had [`RowCodes`] (else empty).
#[derive(Debug, Clone, PartialEq)]
pub struct MlpGradients {
    /// density.0, density.1, color.0, color.1, color.2, each `[in, out]`.
    pub weights: [Vec<f32>; 5],
    /// `[codes, color_hidden]`, laid out as [`RowCodes::codes`].
    pub codes: Vec<f32>,
}

impl MlpGradients {
    fn zeros(w: Widths, codes: usize) -> Self {
        MlpGradients { weights: w.weight_lens().map(|len| vec![0.0f32; len]), codes: vec![0.0; codes] }
    }
}

/// What [`FusedMlps::forward_train`] keeps for the backward pass.
#[derive(Debug)]
pub struct SavedActivations {
    /// Per row: density hidden (after ReLU), density outputs, colour hidden 1 and 2 (after
    /// ReLU), rgb.
    saved: Vec<f32>,
    rows: usize,
}

impl FusedMlps {
    /// The weights of `mlps` (shaped by `spec`).
    pub fn from_mlps(spec: &NgpSpec, mlps: &NgpMlps) -> Self {
        let widths = Widths::of(spec);
        let weights = mlps.weights();
        let lens = widths.weight_lens();
        for (w, len) in weights.iter().zip(lens) {
            assert_eq!(w.len(), len, "ngp MLP weights do not match the spec's widths");
        }
        FusedMlps { widths, weights, color_bias: None }
    }

    /// The same MLPs adding `bias` (`[color_hidden]`) to color.0 on every row.
    pub fn with_color_bias(mut self, bias: Vec<f32>) -> Self {
        assert_eq!(bias.len(), self.widths.color_hidden, "color.0's bias is not [color_hidden]");
        self.color_bias = Some(bias);
        self
    }

    /// σ and rgb at `rows` points from grid features `[rows, L·F]` and view harmonics
    /// `[rows, 16]` (no gradient).
    pub fn forward(&self, features: &[f32], sh: &[f32]) -> (Vec<[f32; 3]>, Vec<f32>) {
        let rows = self.rows(features, sh);
        let per_row = self.widths.saved_per_row();
        let mut rgb = vec![[0.0f32; 3]; rows];
        let mut sigma = vec![0.0f32; rows];
        // Nothing is kept for a backward pass: each thread reuses one block's activations.
        rgb.par_chunks_mut(BLOCK_ROWS).zip(sigma.par_chunks_mut(BLOCK_ROWS)).enumerate().for_each_init(
            || vec![0.0f32; BLOCK_ROWS * per_row],
            |scratch, (b, (rgb, sigma))| {
                let (features, sh) = self.block_inputs(features, sh, b, rgb.len());
                self.forward_block(features, sh, None, &mut scratch[..rgb.len() * per_row], rgb, sigma);
            },
        );
        (rgb, sigma)
    }

    /// Rows of `features` `[rows, L·F]`, checked against the harmonics `[rows, 16]`.
    fn rows(&self, features: &[f32], sh: &[f32]) -> usize {
        let rows = features.len() / self.widths.features;
        assert_eq!(features.len(), rows * self.widths.features, "features are not [n, L·F]");
        assert_eq!(sh.len(), rows * SH4_DIM, "harmonics are not [n, 16]");
        rows
    }

    /// Block `b`'s `n` rows of features and harmonics.
    fn block_inputs<'a>(&self, features: &'a [f32], sh: &'a [f32], b: usize, n: usize) -> (&'a [f32], &'a [f32]) {
        let (r0, f) = (b * BLOCK_ROWS, self.widths.features);
        (&features[r0 * f..(r0 + n) * f], &sh[r0 * SH4_DIM..(r0 + n) * SH4_DIM])
    }

    /// σ alone (the density MLP's first output) from grid features `[rows, L·F]`.
    pub fn density(&self, features: &[f32]) -> Vec<f32> {
        let w = self.widths;
        let rows = features.len() / w.features;
        assert_eq!(features.len(), rows * w.features, "features are not [n, L·F]");
        let (hd, [w0, w1, ..]) = (w.density_hidden, &self.weights);
        let mut sigma = vec![0.0f32; rows];
        sigma.par_chunks_mut(BLOCK_ROWS).enumerate().for_each_init(
            || vec![0.0f32; BLOCK_ROWS * hd],
            |hidden, (b, sigma)| {
                let (n, r0) = (sigma.len(), b * BLOCK_ROWS);
                let hidden = &mut hidden[..n * hd];
                matmul(n, hd, w.features, hidden, hd, false, View::rows(&features[r0 * w.features..(r0 + n) * w.features], w.features), View::rows(w0, hd));
                relu(hidden);
                // σ's column of density.1 only
                matmul(n, 1, hd, sigma, 1, false, View::rows(hidden, hd), View::rows(w1, w.density_out()));
                sigma.iter_mut().for_each(|s| *s = s.exp());
            },
        );
        sigma
    }

    /// [`forward`](Self::forward), keeping the activations for [`backward`](Self::backward);
    /// `codes`, when given, add to color.0 row by row (in place of the fixed bias).
    pub fn forward_train(&self, features: &[f32], sh: &[f32], codes: Option<RowCodes>) -> ((Vec<[f32; 3]>, Vec<f32>), SavedActivations) {
        let rows = self.rows(features, sh);
        self.check_codes(codes, rows);
        let per_row = self.widths.saved_per_row();
        let mut saved = vec![0.0f32; rows * per_row];
        let mut rgb = vec![[0.0f32; 3]; rows];
        let mut sigma = vec![0.0f32; rows];
        saved
            .par_chunks_mut(BLOCK_ROWS * per_row)
            .zip(rgb.par_chunks_mut(BLOCK_ROWS))
            .zip(sigma.par_chunks_mut(BLOCK_ROWS))
            .enumerate()
            .for_each(|(b, ((saved, rgb), sigma))| {
                let (features, sh) = self.block_inputs(features, sh, b, rgb.len());
                let r0 = b * BLOCK_ROWS;
                self.forward_block(features, sh, codes.map(|c| c.rows(r0, r0 + rgb.len())), saved, rgb, sigma);
            });
        ((rgb, sigma), SavedActivations { saved, rows })
    }

    /// `codes` are whole codes, one index per row and each index a code.
    fn check_codes(&self, codes: Option<RowCodes>, rows: usize) {
        if let Some(c) = codes {
            let count = c.codes.len() / self.widths.color_hidden;
            assert!(c.codes.len() == count * self.widths.color_hidden && c.code_of_row.len() == rows, "codes are not [k, color_hidden] with one index per row");
            assert!(c.code_of_row.iter().all(|&k| (k as usize) < count), "a row's code index is past the codes");
        }
    }

    /// One block of `n` rows (`codes` sliced to them); `saved` is the block's
    /// `[n, saved_per_row]` laid out as [`Block`] says.
    fn forward_block(&self, features: &[f32], sh: &[f32], codes: Option<RowCodes>, saved: &mut [f32], rgb: &mut [[f32; 3]], sigma: &mut [f32]) {
        let w = self.widths;
        let n = rgb.len();
        let [w0, w1, c0, c1, c2] = &self.weights;
        let b = Block::split(saved, n, w);
        // density.0 and ReLU
        matmul(n, w.density_hidden, w.features, b.hidden, w.density_hidden, false, View::rows(features, w.features), View::rows(w0, w.density_hidden));
        relu(b.hidden);
        // density.1: σ's pre-activation and the geometry features
        matmul(n, w.density_out(), w.density_hidden, b.density_out, w.density_out(), false, View::rows(b.hidden, w.density_hidden), View::rows(w1, w.density_out()));
        for (s, o) in sigma.iter_mut().zip(b.density_out.chunks_exact(w.density_out())) {
            *s = o[0].exp();
        }
        // color.0 over [geometry, harmonics], as two products (no concatenation)
        let (c0_geometry, c0_sh) = c0.split_at(w.geometry * w.color_hidden);
        matmul(n, w.color_hidden, w.geometry, b.color1, w.color_hidden, false, View::rows(&b.density_out[1..], w.density_out()), View::rows(c0_geometry, w.color_hidden));
        matmul(n, w.color_hidden, SH4_DIM, b.color1, w.color_hidden, true, View::rows(sh, SH4_DIM), View::rows(c0_sh, w.color_hidden));
        let ch = w.color_hidden;
        match (codes, &self.color_bias) {
            (Some(c), _) => {
                for (row, &k) in b.color1.chunks_exact_mut(ch).zip(c.code_of_row) {
                    row.iter_mut().zip(&c.codes[k as usize * ch..(k as usize + 1) * ch]).for_each(|(v, b)| *v += b);
                }
            }
            (None, Some(bias)) => b.color1.chunks_exact_mut(ch).for_each(|row| row.iter_mut().zip(bias).for_each(|(v, b)| *v += b)),
            (None, None) => {}
        }
        relu(b.color1);
        matmul(n, w.color_hidden, w.color_hidden, b.color2, w.color_hidden, false, View::rows(b.color1, w.color_hidden), View::rows(c1, w.color_hidden));
        relu(b.color2);
        matmul(n, 3, w.color_hidden, b.rgb, 3, false, View::rows(b.color2, w.color_hidden), View::rows(c2, 3));
        for (out, z) in rgb.iter_mut().zip(b.rgb.chunks_exact_mut(3)) {
            for (o, z) in out.iter_mut().zip(z.iter_mut()) {
                *z = 1.0 / (1.0 + (-*z).exp());
                *o = *z;
            }
        }
    }

    /// The weights' (and `codes`') gradients and the features' gradient `[rows, L·F]` for a
    /// loss whose gradients with respect to rgb and σ are `grad_rgb` and `grad_sigma`; `codes`
    /// are those of the forward pass. With `grad_sh` (`[rows, 16]`), the harmonics' gradient
    /// too (for gradients that reach the view directions: camera refinement).
    #[allow(clippy::too_many_arguments)]
    pub fn backward(
        &self,
        features: &[f32],
        sh: &[f32],
        codes: Option<RowCodes>,
        saved: &SavedActivations,
        grad_rgb: &[[f32; 3]],
        grad_sigma: &[f32],
        grad_sh: Option<&mut [f32]>,
    ) -> (MlpGradients, Vec<f32>) {
        let w = self.widths;
        let rows = saved.rows;
        self.check_codes(codes, rows);
        let code_len = codes.map_or(0, |c| c.codes.len());
        assert!(features.len() == rows * w.features && sh.len() == rows * SH4_DIM, "backward: inputs are not those of the forward pass");
        assert!(grad_rgb.len() == rows && grad_sigma.len() == rows, "backward: one rgb and one σ gradient per row");
        let per_row = w.saved_per_row();
        let mut grad_features = vec![0.0f32; rows * w.features];
        let blocks = rows.div_ceil(BLOCK_ROWS);
        let run_blocks = blocks.div_ceil(GRADIENT_RUNS).max(1);
        let run_rows = run_blocks * BLOCK_ROWS;
        let runs = rows.div_ceil(run_rows);
        let grad_sh_runs: Vec<Option<&mut [f32]>> = match grad_sh {
            Some(g) => {
                assert_eq!(g.len(), rows * SH4_DIM, "backward: the harmonics' gradient is not [n, 16]");
                g.chunks_mut(run_rows * SH4_DIM).map(Some).collect()
            }
            None => (0..runs).map(|_| None).collect(),
        };
        let partials: Vec<MlpGradients> = grad_features
            .par_chunks_mut(run_rows * w.features)
            .zip(grad_sh_runs)
            .enumerate()
            .map(|(run, (grad_features, mut grad_sh))| {
                let mut grads = MlpGradients::zeros(w, code_len);
                let mut scratch = Scratch::new(w);
                for (k, grad_features) in grad_features.chunks_mut(BLOCK_ROWS * w.features).enumerate() {
                    let r0 = run * run_rows + k * BLOCK_ROWS;
                    let n = grad_features.len() / w.features;
                    let r1 = r0 + n;
                    let grad_sh = grad_sh.as_deref_mut().map(|g| &mut g[k * BLOCK_ROWS * SH4_DIM..(k * BLOCK_ROWS + n) * SH4_DIM]);
                    self.backward_block(
                        &features[r0 * w.features..r1 * w.features],
                        &sh[r0 * SH4_DIM..r1 * SH4_DIM],
                        codes.map(|c| c.rows(r0, r1)),
                        &saved.saved[r0 * per_row..r1 * per_row],
                        &grad_rgb[r0..r1],
                        &grad_sigma[r0..r1],
                        &mut grads,
                        &mut scratch,
                        grad_features,
                        grad_sh,
                    );
                }
                grads
            })
            .collect();
        let mut total = MlpGradients::zeros(w, code_len);
        for p in &partials {
            for (t, g) in total.weights.iter_mut().chain([&mut total.codes]).zip(p.weights.iter().chain([&p.codes])) {
                t.iter_mut().zip(g).for_each(|(t, g)| *t += g);
            }
        }
        (total, grad_features)
    }

    #[allow(clippy::too_many_arguments)]
    fn backward_block(
        &self,
        features: &[f32],
        sh: &[f32],
        codes: Option<RowCodes>,
        saved: &[f32],
        grad_rgb: &[[f32; 3]],
        grad_sigma: &[f32],
        grads: &mut MlpGradients,
        s: &mut Scratch,
        grad_features: &mut [f32],
        grad_sh: Option<&mut [f32]>,
    ) {
        let w = self.widths;
        let n = grad_rgb.len();
        let b = Block::view(saved, n, w);
        let [w0, w1, c0, c1, c2] = &self.weights;
        let [gw0, gw1, gc0, gc1, gc2] = &mut grads.weights;
        let (hd, dout, ch, g) = (w.density_hidden, w.density_out(), w.color_hidden, w.geometry);
        // rgb = sigmoid(z)
        let dz = &mut s.rgb[..n * 3];
        for ((d, rgb), grad) in dz.chunks_exact_mut(3).zip(b.rgb.chunks_exact(3)).zip(grad_rgb) {
            for c in 0..3 {
                d[c] = grad[c] * rgb[c] * (1.0 - rgb[c]);
            }
        }
        // color.2
        matmul(ch, 3, n, gc2, 3, true, View::cols(b.color2, ch), View::rows(dz, 3));
        let dc2 = &mut s.color2[..n * ch];
        matmul(n, ch, 3, dc2, ch, false, View::rows(dz, 3), View::cols(c2, 3));
        relu_backward(dc2, b.color2);
        // color.1
        matmul(ch, ch, n, gc1, ch, true, View::cols(b.color1, ch), View::rows(dc2, ch));
        let dc1 = &mut s.color1[..n * ch];
        matmul(n, ch, ch, dc1, ch, false, View::rows(dc2, ch), View::cols(c1, ch));
        relu_backward(dc1, b.color1);
        // each row's code was added to color.0's pre-activation
        if let Some(c) = codes {
            for (d, &k) in dc1.chunks_exact(ch).zip(c.code_of_row) {
                grads.codes[k as usize * ch..(k as usize + 1) * ch].iter_mut().zip(d).for_each(|(g, d)| *g += d);
            }
        }
        // color.0: its geometry rows, then its harmonic rows
        let (gc0_geometry, gc0_sh) = gc0.split_at_mut(g * ch);
        matmul(g, ch, n, gc0_geometry, ch, true, View::cols(&b.density_out[1..], dout), View::rows(dc1, ch));
        matmul(SH4_DIM, ch, n, gc0_sh, ch, true, View::cols(sh, SH4_DIM), View::rows(dc1, ch));
        if let Some(grad_sh) = grad_sh {
            matmul(n, SH4_DIM, ch, grad_sh, SH4_DIM, false, View::rows(dc1, ch), View::cols(&c0[g * ch..], ch));
        }
        let ddout = &mut s.density_out[..n * dout];
        matmul(n, g, ch, &mut ddout[1..], dout, false, View::rows(dc1, ch), View::cols(&c0[..g * ch], ch));
        // σ = trunc_exp(density_out[0])
        for ((d, o), gs) in ddout.chunks_exact_mut(dout).zip(b.density_out.chunks_exact(dout)).zip(grad_sigma) {
            d[0] = gs * o[0].clamp(-TRUNC_EXP_CLAMP, TRUNC_EXP_CLAMP).exp();
        }
        // density.1
        matmul(hd, dout, n, gw1, dout, true, View::cols(b.hidden, hd), View::rows(ddout, dout));
        let dh = &mut s.hidden[..n * hd];
        matmul(n, hd, dout, dh, hd, false, View::rows(ddout, dout), View::cols(w1, dout));
        relu_backward(dh, b.hidden);
        // density.0
        matmul(w.features, hd, n, gw0, hd, true, View::cols(features, w.features), View::rows(dh, hd));
        matmul(n, w.features, hd, grad_features, w.features, false, View::rows(dh, hd), View::cols(w0, hd));
    }
}

impl MlpGradients {
    /// The gradients as burn's optimizer takes them, keyed by `mlps`' parameters.
    pub fn to_params(&self, mlps: &NgpMlps, device: &Device) -> burn::optim::GradientsParams {
        let mut params = burn::optim::GradientsParams::new();
        for ((id, [i, o]), g) in mlps.weight_ids().into_iter().zip(&self.weights) {
            params.register::<2>(id, Tensor::from_data(TensorData::new(g.clone(), [i, o]), device));
        }
        params
    }
}

/// One block's saved activations, split by layer.
struct Block<S> {
    hidden: S,
    density_out: S,
    color1: S,
    color2: S,
    rgb: S,
}

impl<'a> Block<&'a mut [f32]> {
    fn split(saved: &'a mut [f32], n: usize, w: Widths) -> Self {
        let (hidden, rest) = saved.split_at_mut(n * w.density_hidden);
        let (density_out, rest) = rest.split_at_mut(n * w.density_out());
        let (color1, rest) = rest.split_at_mut(n * w.color_hidden);
        let (color2, rgb) = rest.split_at_mut(n * w.color_hidden);
        Block { hidden, density_out, color1, color2, rgb }
    }
}

impl<'a> Block<&'a [f32]> {
    fn view(saved: &'a [f32], n: usize, w: Widths) -> Self {
        let (hidden, rest) = saved.split_at(n * w.density_hidden);
        let (density_out, rest) = rest.split_at(n * w.density_out());
        let (color1, rest) = rest.split_at(n * w.color_hidden);
        let (color2, rgb) = rest.split_at(n * w.color_hidden);
        Block { hidden, density_out, color1, color2, rgb }
    }
}

/// One thread's buffers for a block's activation gradients.
struct Scratch {
    hidden: Vec<f32>,
    density_out: Vec<f32>,
    color1: Vec<f32>,
    color2: Vec<f32>,
    rgb: Vec<f32>,
}

impl Scratch {
    fn new(w: Widths) -> Self {
        let n = BLOCK_ROWS;
        Scratch { hidden: vec![0.0; n * w.density_hidden], density_out: vec![0.0; n * w.density_out()], color1: vec![0.0; n * w.color_hidden], color2: vec![0.0; n * w.color_hidden], rgb: vec![0.0; n * 3] }
    }
}

fn relu(x: &mut [f32]) {
    x.iter_mut().for_each(|v| *v = v.max(0.0));
}

/// `grad ⊙ (y > 0)` where `y` is the ReLU's output.
fn relu_backward(grad: &mut [f32], y: &[f32]) {
    grad.iter_mut().zip(y).for_each(|(g, &y)| {
        if y <= 0.0 {
            *g = 0.0;
        }
    });
}

/// A matrix operand: a slice read with a row stride and a column stride.
#[derive(Clone, Copy)]
struct View<'a> {
    data: &'a [f32],
    row_stride: usize,
    col_stride: usize,
}

impl<'a> View<'a> {
    /// Row-major with `width` floats a row.
    fn rows(data: &'a [f32], width: usize) -> Self {
        View { data, row_stride: width, col_stride: 1 }
    }

    /// The transpose of a row-major matrix with `width` floats a row.
    fn cols(data: &'a [f32], width: usize) -> Self {
        View { data, row_stride: 1, col_stride: width }
    }

    /// The last element `[rows, cols]` reads is inside the slice.
    fn covers(&self, rows: usize, cols: usize) -> bool {
        rows == 0 || cols == 0 || (rows - 1) * self.row_stride + (cols - 1) * self.col_stride < self.data.len()
    }
}

/// `out[m, n] (+)= a[m, k] · b[k, n]`, `out` row-major with `out_stride` floats a row,
/// single-threaded (the blocks are the parallelism).
#[allow(clippy::too_many_arguments)]
fn matmul(m: usize, n: usize, k: usize, out: &mut [f32], out_stride: usize, accumulate: bool, a: View, b: View) {
    assert!(a.covers(m, k) && b.covers(k, n), "matmul: an operand is smaller than its shape");
    if m == 0 || n == 0 {
        return;
    }
    assert!(n <= out_stride && (m - 1) * out_stride + n <= out.len(), "matmul: the output is smaller than its shape");
    if k == 0 {
        if !accumulate {
            out.chunks_mut(out_stride).take(m).for_each(|row| row[..n].fill(0.0));
        }
        return;
    }
    // SAFETY: every operand covers its shape with its strides (asserted above), and `out` is
    // borrowed mutably, so nothing else reads or writes it meanwhile.
    unsafe {
        gemm::gemm(
            m,
            n,
            k,
            out.as_mut_ptr(),
            1,
            out_stride as isize,
            accumulate,
            a.data.as_ptr(),
            a.col_stride as isize,
            a.row_stride as isize,
            b.data.as_ptr(),
            b.col_stride as isize,
            b.row_stride as isize,
            1.0,
            1.0,
            false,
            false,
            false,
            gemm::Parallelism::None,
        )
    }
}

#[cfg(test)]
mod tests;
