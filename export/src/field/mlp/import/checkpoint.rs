//! nerf-pytorch's checkpoint (`NNNNNN.tar`, a `torch.save` of `{global_step,
//! network_fn_state_dict, network_fine_state_dict, optimizer_state_dict}`) read with the
//! burn-free `pytorch-reader`, and its `NeRF` modules mapped onto [`PlainNetwork`]s.
//!
//! nerf-pytorch's `NeRF(D, W, input_ch, input_ch_views, output_ch, skips, use_viewdirs)` holds
//! `pts_linears.0 … D−1` (layer `i + 1` takes `W + input_ch` inputs when `i` is a skip),
//! then either `alpha_linear [1, W]`, `feature_linear [W, W]`, `views_linears.0
//! [W/2, W + input_ch_views]`, `rgb_linear [3, W/2]` (use_viewdirs) or `output_linear
//! [output_ch, W]` (4, or 5 when the run has a fine network; only the first 4 are used).
//! Weights are `[out, in]`; ours are `[in, out]`.

use nerf_core::field::mlp::{EncodingSpec, NetworkSpec, PlainNetwork};
use nerf_core::field::DenseLayer;
use std::collections::BTreeMap;
use std::path::Path;

/// The top-level key of the coarse network's state dict.
pub const COARSE_KEY: &str = "network_fn_state_dict";
/// The top-level key of the fine network's state dict.
pub const FINE_KEY: &str = "network_fine_state_dict";

/// One `torch.nn.Module.state_dict()` as float32 arrays: name → (shape, values row-major).
pub type StateDict = BTreeMap<String, (Vec<usize>, Vec<f32>)>;

/// The networks found in a checkpoint.
#[derive(Debug, Clone, Default)]
pub struct CheckpointNetworks {
    /// `network_fn_state_dict`.
    pub coarse: StateDict,
    /// `network_fine_state_dict` (empty when it is `None` or absent).
    pub fine: StateDict,
}

/// Read the two state dicts of a nerf-pytorch checkpoint (zip or legacy `torch.save` format).
pub fn read_checkpoint(path: &Path) -> Result<CheckpointNetworks, String> {
    let reader = pytorch_reader::PytorchReader::new(path)
        .map_err(|e| format!("not a readable PyTorch checkpoint (truncated, or not written by torch.save?): {e}"))?;
    let mut nets = CheckpointNetworks::default();
    for (name, tensor) in reader.tensors() {
        let (dict, short) = match name.split_once('.') {
            Some((COARSE_KEY, rest)) => (&mut nets.coarse, rest),
            Some((FINE_KEY, rest)) => (&mut nets.fine, rest),
            _ => continue,
        };
        let bytes = tensor.read().map_err(|e| format!("{name}: {e}"))?;
        let values: Vec<f32> = match tensor.dtype() {
            pytorch_reader::DType::F32 => bytes.chunks_exact(4).map(|c| f32::from_ne_bytes([c[0], c[1], c[2], c[3]])).collect(),
            pytorch_reader::DType::F64 => bytes.chunks_exact(8).map(|c| f64::from_ne_bytes(c.try_into().expect("8 bytes")) as f32).collect(),
            other => return Err(format!("{name}: element type {other:?}, expected float32")),
        };
        dict.insert(short.to_string(), (tensor.shape().to_vec(), values));
    }
    if nets.coarse.is_empty() {
        let mut found: Vec<&String> = reader.tensors().keys().collect();
        found.sort();
        let shown: Vec<&str> = found.iter().take(5).map(|s| s.as_str()).collect();
        return Err(format!(
            "no {COARSE_KEY}: not a nerf-pytorch checkpoint (its tensors: {}{})",
            if shown.is_empty() { "none".to_string() } else { shown.join(", ") },
            if found.len() > 5 { ", …" } else { "" }
        ));
    }
    Ok(nets)
}

/// What a nerf-pytorch network should look like, from the run's settings.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ExpectedNetwork {
    /// `netdepth` / `netdepth_fine`.
    pub depth: usize,
    /// `netwidth` / `netwidth_fine`.
    pub width: usize,
    /// Position encoding (`multires`).
    pub position: EncodingSpec,
    /// Direction encoding (`multires_views`).
    pub direction: EncodingSpec,
    /// `use_viewdirs`.
    pub use_viewdirs: bool,
}

/// A mismatch between the checkpoint and the settings, or a missing tensor.
#[derive(Debug, Clone, PartialEq)]
pub struct MappingError {
    /// The setting that disagrees (`netwidth`, `multires`, …), if one does.
    pub setting: Option<&'static str>,
    /// What is wrong.
    pub message: String,
}

fn mismatch(setting: &'static str, message: String) -> MappingError {
    MappingError { setting: Some(setting), message }
}

/// Map one nerf-pytorch `NeRF` state dict onto a [`PlainNetwork`], checking every shape
/// against `expected`. `fine` picks the setting names used in errors (`netwidth_fine`, …).
pub fn to_plain_network(dict: &StateDict, expected: &ExpectedNetwork, fine: bool) -> Result<PlainNetwork, MappingError> {
    let (depth_key, width_key) = if fine { ("netdepth_fine", "netwidth_fine") } else { ("netdepth", "netwidth") };
    let get = |name: &str| -> Result<&(Vec<usize>, Vec<f32>), MappingError> {
        dict.get(name).ok_or_else(|| MappingError { setting: None, message: format!("{name} is missing from the state dict") })
    };
    let linear = |name: &str| -> Result<(usize, usize), MappingError> {
        let (w, _) = get(&format!("{name}.weight"))?;
        let (b, _) = get(&format!("{name}.bias"))?;
        match (w.as_slice(), b.as_slice()) {
            ([o, i], [ob]) if o == ob => Ok((*o, *i)),
            _ => Err(MappingError { setting: None, message: format!("{name}: weight {w:?} and bias {b:?} are not a linear layer's") }),
        }
    };
    let x_dim = expected.position.output_dim();
    let w = expected.width;

    let depth = (0..).take_while(|i| dict.contains_key(&format!("pts_linears.{i}.weight"))).count();
    if depth != expected.depth {
        return Err(mismatch(depth_key, format!("{depth_key} = {} but the checkpoint has {depth} pts_linears", expected.depth)));
    }
    let mut skips = Vec::new();
    for i in 0..depth {
        let (out, inp) = linear(&format!("pts_linears.{i}"))?;
        if out != w {
            return Err(mismatch(width_key, format!("{width_key} = {w} but pts_linears.{i} has {out} outputs")));
        }
        let plain_in = if i == 0 { x_dim } else { w };
        if i > 0 && inp == w + x_dim {
            skips.push(i - 1);
        } else if inp != plain_in {
            let setting = if i == 0 { "multires" } else { width_key };
            return Err(mismatch(setting, format!(
                "pts_linears.{i} takes {inp} inputs; {width_key} = {w} and multires = {} ({x_dim} encoded inputs) give {plain_in}{}",
                expected.position.n_frequencies,
                if i > 0 { format!(" (or {} after a skip)", w + x_dim) } else { String::new() }
            )));
        }
    }
    // nerf-pytorch concatenates after every layer in `skips = [4]`; after the last one the heads
    // would get W + input_ch inputs and the network could not run.
    if depth == 5 {
        return Err(mismatch(depth_key, format!("{depth_key} = 5: nerf-pytorch's skip after layer 4 would feed the heads W + input_ch values; such a network cannot run")));
    }

    let has_views = dict.contains_key("rgb_linear.weight");
    if has_views != expected.use_viewdirs {
        return Err(mismatch("use_viewdirs", format!(
            "use_viewdirs = {} but the checkpoint has {}",
            if expected.use_viewdirs { "True" } else { "False" },
            if has_views { "rgb_linear (a view-dependent network)" } else { "output_linear (no view dependence)" }
        )));
    }
    let spec = NetworkSpec {
        depth,
        width: w,
        skips,
        position_encoding: expected.position,
        direction_encoding: expected.direction,
        use_viewdirs: expected.use_viewdirs,
    };
    let mut layers = Vec::new();
    for (i, (name, in_dim, out_dim)) in spec.layer_shapes().into_iter().enumerate() {
        let source = match name.as_str() {
            _ if i < depth => format!("pts_linears.{i}"),
            "sigma" => "alpha_linear".into(),
            "feature" => "feature_linear".into(),
            "view" => "views_linears.0".into(),
            "rgb" => "rgb_linear".into(),
            "output" => "output_linear".into(),
            other => unreachable!("layer {other} is not in nerf-pytorch's NeRF"),
        };
        let (out, inp) = linear(&source)?;
        // output_linear has a 5th, unused output when the run has a fine network.
        let out_ok = out == out_dim || (name == "output" && out == 5);
        if !out_ok || inp != in_dim {
            let setting = if name == "view" && inp != in_dim { "multires_views" } else { width_key };
            return Err(mismatch(setting, format!("{source} is [{out}, {inp}], expected [{out_dim}, {in_dim}] from the settings")));
        }
        layers.push(transposed(&name, &dict[&format!("{source}.weight")].1, &dict[&format!("{source}.bias")].1, inp, out, out_dim));
    }
    let net = PlainNetwork { spec, layers };
    net.validate().map_err(|message| MappingError { setting: None, message })?;
    Ok(net)
}

/// A torch `Linear` (`weight [out, in]`) as our dense layer (`[in, out]`), keeping only the
/// first `keep` outputs.
fn transposed(name: &str, weight: &[f32], bias: &[f32], in_dim: usize, out: usize, keep: usize) -> DenseLayer {
    let mut w = vec![0.0; in_dim * keep];
    for o in 0..keep {
        for i in 0..in_dim {
            w[i * keep + o] = weight[o * in_dim + i];
        }
    }
    debug_assert_eq!(weight.len(), out * in_dim);
    DenseLayer { name: name.to_string(), in_dim, out_dim: keep, weight: w, bias: bias[..keep].to_vec() }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn enc(l: usize) -> EncodingSpec {
        EncodingSpec { n_frequencies: l, include_input: true }
    }

    /// A nerf-pytorch state dict with value `k + 0.001·index` in layer k, so transposes show.
    fn torch_dict(depth: usize, w: usize, x: usize, d: usize, viewdirs: bool, out_ch: usize) -> StateDict {
        let mut dict = StateDict::new();
        let mut add = |name: String, out: usize, inp: usize| {
            let k = dict.len() as f32;
            dict.insert(format!("{name}.weight"), (vec![out, inp], (0..out * inp).map(|j| k + 0.001 * j as f32).collect()));
            dict.insert(format!("{name}.bias"), (vec![out], (0..out).map(|j| -k - 0.001 * j as f32).collect()));
        };
        for i in 0..depth {
            let inp = if i == 0 { x } else if i == 5 { w + x } else { w };
            add(format!("pts_linears.{i}"), w, inp);
        }
        add("views_linears.0".into(), w / 2, w + if viewdirs { d } else { 0 });
        if viewdirs {
            add("feature_linear".into(), w, w);
            add("alpha_linear".into(), 1, w);
            add("rgb_linear".into(), 3, w / 2);
        } else {
            add("output_linear".into(), out_ch, w);
        }
        dict
    }

    fn expected(depth: usize, width: usize, use_viewdirs: bool) -> ExpectedNetwork {
        ExpectedNetwork { depth, width, position: enc(2), direction: enc(1), use_viewdirs }
    }

    #[test]
    fn maps_layers_and_transposes() {
        let dict = torch_dict(7, 8, 15, 9, true, 4);
        let net = to_plain_network(&dict, &expected(7, 8, true), false).unwrap();
        assert_eq!(net.spec.skips, vec![4], "pts_linears.5 takes W + input_ch");
        let names: Vec<&str> = net.layers.iter().map(|l| l.name.as_str()).collect();
        assert_eq!(names[7..], ["sigma", "feature", "view", "rgb"]);
        // torch weight[o][i] = our weight[i][o]: pts_linears.0 is [8, 15].
        let (_, w0) = &dict["pts_linears.0.weight"];
        assert_eq!(net.layers[0].weight[3 * 8 + 2], w0[2 * 15 + 3]);
        let view = &net.layers[9];
        assert_eq!((view.in_dim, view.out_dim), (8 + 9, 4));
        assert_eq!(view.bias, dict["views_linears.0.bias"].1);
    }

    #[test]
    fn output_linear_drops_the_unused_fifth_output() {
        let dict = torch_dict(2, 6, 15, 9, false, 5);
        let net = to_plain_network(&dict, &expected(2, 6, false), false).unwrap();
        let out = net.layers.last().unwrap();
        assert_eq!((out.name.as_str(), out.in_dim, out.out_dim), ("output", 6, 4));
        let (_, w) = &dict["output_linear.weight"];
        assert_eq!(out.weight[5 * 4 + 3], w[3 * 6 + 5]);
        assert_eq!(out.bias, dict["output_linear.bias"].1[..4]);
    }

    #[test]
    fn disagreements_name_the_setting() {
        let dict = torch_dict(4, 8, 15, 9, true, 4);
        let setting = |e: ExpectedNetwork, fine: bool| to_plain_network(&dict, &e, fine).unwrap_err().setting;
        assert_eq!(setting(expected(6, 8, true), false), Some("netdepth"));
        assert_eq!(setting(expected(4, 16, true), true), Some("netwidth_fine"));
        assert_eq!(setting(expected(4, 8, false), false), Some("use_viewdirs"));
        assert_eq!(setting(ExpectedNetwork { position: enc(3), ..expected(4, 8, true) }, false), Some("multires"));
        assert_eq!(setting(ExpectedNetwork { direction: enc(2), ..expected(4, 8, true) }, false), Some("multires_views"));
        let mut missing = dict.clone();
        missing.remove("alpha_linear.bias");
        let e = to_plain_network(&missing, &expected(4, 8, true), false).unwrap_err();
        assert!(e.message.contains("alpha_linear.bias is missing"), "{e:?}");
    }
}
