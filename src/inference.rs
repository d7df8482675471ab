//! Moving points between plain Rust and burn tensors, for every field kind.

use burn::tensor::{Device, Tensor, TensorData};

/// `[n]` 3-vectors as an `[n, 3]` tensor.
pub fn vec3_tensor(v: &[[f32; 3]], device: &Device) -> Tensor<2> {
    Tensor::from_data(TensorData::new(v.as_flattened().to_vec(), [v.len(), 3]), device)
}

/// An `[n, 3]` tensor as `[n]` 3-vectors.
pub fn tensor_vec3(t: Tensor<2>) -> Vec<[f32; 3]> {
    let flat = t.into_data().try_to_vec::<f32>().expect("f32 tensor");
    flat.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect()
}
