//! The LPIPS graph (`nerf_export::lpips`: `image0`, `image1` float32 `[N, H, W, 3]` in
//! `[0, 1]` → `lpips` `[N]`) in an onnxruntime session, one pair of images at a time.

use crate::environment::environment;
use crate::error::{Result, RuntimeError};
use ort::session::Session;
use ort::value::TensorRef;
use std::path::{Path, PathBuf};

/// An LPIPS graph loaded into onnxruntime (on the CPU).
pub struct LpipsSession {
    session: Session,
    path: PathBuf,
}

impl LpipsSession {
    /// Load the graph at `path`.
    pub fn open(path: &Path) -> Result<Self> {
        let ort_err = |e: &dyn std::fmt::Display| RuntimeError::Ort { path: path.to_path_buf(), message: e.to_string() };
        let environment = environment()?;
        let session = Session::builder(environment).and_then(|mut b| b.commit_from_file(path)).map_err(|e| ort_err(&e))?;
        Ok(LpipsSession { session, path: path.to_path_buf() })
    }

    /// The LPIPS distance between `a` and `b`, row-major RGB images of `width × height` in
    /// `[0, 1]` (smaller than the AlexNet's smallest input, 31×31, is onnxruntime's error).
    pub fn distance(&mut self, a: &[[f32; 3]], b: &[[f32; 3]], width: usize, height: usize) -> Result<f32> {
        let path = &self.path;
        let ort_err = |e: &dyn std::fmt::Display| RuntimeError::Ort { path: path.clone(), message: e.to_string() };
        if a.len() != width * height || b.len() != width * height {
            return Err(RuntimeError::Other(format!("LPIPS: images of {} and {} pixels are not both {width}×{height}", a.len(), b.len())));
        }
        let shape = [1, height, width, 3];
        let ta = TensorRef::from_array_view((shape, a.as_flattened())).map_err(|e| ort_err(&e))?;
        let tb = TensorRef::from_array_view((shape, b.as_flattened())).map_err(|e| ort_err(&e))?;
        let outputs = self.session.run(ort::inputs!["image0" => ta, "image1" => tb]).map_err(|e| ort_err(&e))?;
        let (_, values) = outputs["lpips"].try_extract_tensor::<f32>().map_err(|e| ort_err(&e))?;
        values.first().copied().ok_or_else(|| RuntimeError::bundle(path, "the LPIPS graph gave no value"))
    }
}
