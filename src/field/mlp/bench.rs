//! The paper network's measurements for `nerf bench`: seeded weights, its forward throughput in
//! burn, the paper preset's coarse + fine model.

use super::{NerfMlp, NerfModel};
use crate::bench::{NetworkBench, best_of};
use crate::config::{Preset, TrainConfig};
use crate::error::{Error, Result};
use crate::inference::vec3_tensor;
use nerf_core::field::mlp::{NetworkSpec, PlainNetwork};

/// The paper network with seeded weights, as plain data and in burn (the same weights the
/// onnxruntime side compiles).
pub fn paper_network(seed: u64) -> Result<(PlainNetwork, NerfMlp)> {
    let plain = PlainNetwork::seeded(&NetworkSpec::paper(), seed);
    let net = NerfMlp::from_plain(&plain, &crate::backend::cpu())?;
    Ok((plain, net))
}

/// Best of `repeats` forward passes of `net` in burn on `points` and `dirs`.
pub fn bench_mlp_burn(net: &NerfMlp, points: &[[f32; 3]], dirs: &[[f32; 3]], repeats: usize) -> Result<NetworkBench> {
    let device = crate::backend::cpu();
    let seconds = best_of(repeats, || {
        let (rgb, sigma) = net.forward(vec3_tensor(points, &device), vec3_tensor(dirs, &device));
        let _ = (rgb.into_data(), sigma.into_data());
        Ok::<_, Error>(())
    })?;
    Ok(NetworkBench::new("burn", points.len(), seconds, net.macs_per_point()))
}

/// The paper preset with `chunk` rays per call, and its networks with seeded weights (as plain
/// data for the compiler and in burn).
pub fn paper_model(chunk: usize) -> Result<(TrainConfig, PlainNetwork, PlainNetwork, NerfModel)> {
    let mut config = Preset::Paper.config();
    config.chunk = chunk;
    let coarse = PlainNetwork::seeded(&config.shapes.network, 3);
    let fine = PlainNetwork::seeded(&config.shapes.network, 4);
    let device = crate::backend::cpu();
    let model = NerfModel { coarse: NerfMlp::from_plain(&coarse, &device)?, fine: Some(NerfMlp::from_plain(&fine, &device)?) };
    Ok((config, coarse, fine, model))
}
