//! Import the committed bundle's graphs with burn-import (generated Rust + weights in OUT_DIR).

fn main() {
    for stage in ["coarse", "fine"] {
        let onnx = format!("../../models/spheres/{stage}.onnx");
        println!("cargo:rerun-if-changed={onnx}");
        burn_import::onnx::ModelGen::new().input(&onnx).out_dir("model/").run_from_script();
    }
}
