//! What a user chooses when compiling a field: the opset, portable operators only, and the
//! precision of lookup tables. Each kind applies what concerns it.

pub use nerf_bundle::ngp::TablePrecision;

/// How to compile a field's graphs.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct CompileOptions {
    /// ONNX opset (`None`: the field's default, [`crate::CompileField::default_opset`]).
    pub opset: Option<i64>,
    /// Only operators that every runtime implements on its accelerators: no bitwise operator
    /// and no int64 data (onnxruntime's CUDA provider and onnxruntime-web's WebGPU have no
    /// Bitwise kernels). The MLP fields are portable anyway; the hash grid then takes its
    /// portable lowering (about 1.5× the CPU time of the bitwise one).
    pub portable: bool,
    /// Precision of lookup tables.
    pub tables: TablePrecision,
}

impl CompileOptions {
    /// The opset asked for, else `default`.
    pub fn opset_or(&self, default: i64) -> i64 {
        self.opset.unwrap_or(default)
    }
}
