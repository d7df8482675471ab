//! One bundle graph as an onnxruntime session that follows the graph contract
//! ([`nerf_bundle::graph`]): `points`, `viewdirs` `[N, 3]` in; `rgb [N, 3]`, `sigma [N, 1]` out.

use crate::environment::environment;
use crate::error::{Result, RuntimeError};
use nerf_core::field::FieldOutput;
use nerf_bundle::graph::{MAX_GRAPH_BYTES, check_contract, check_initializers, decode_model};
use ort::session::Session;
use ort::value::TensorRef;
use std::path::{Path, PathBuf};

/// A graph loaded into onnxruntime.
pub struct OrtNetwork {
    session: Session,
    path: PathBuf,
    /// Points evaluated so far (for benchmarks: how much work skipping saves).
    pub evaluated: usize,
    /// Seconds spent in onnxruntime so far (for benchmarks: the graph's share of a frame).
    pub seconds: f64,
}

impl OrtNetwork {
    /// Load `path`, checking it decodes and follows the contract before onnxruntime sees it.
    /// `threads`: onnxruntime's intra-op threads (`None`: one per core).
    pub fn load(path: &Path, threads: Option<usize>) -> Result<Self> {
        let bytes = nerf_core::io::limits::read_bounded(path, MAX_GRAPH_BYTES)
            .map_err(|e| RuntimeError::bundle(path, format!("cannot read the graph: {e}")))?;
        let model = decode_model(path, &bytes)?;
        check_contract(&model).map_err(|e| RuntimeError::bundle(path, e))?;
        // Tables and weights the size their shapes say, before onnxruntime indexes into them.
        check_initializers(&model).map_err(|e| RuntimeError::bundle(path, e))?;
        let ort_err = |e: &dyn std::fmt::Display| RuntimeError::Ort { path: path.to_path_buf(), message: e.to_string() };
        let mut builder = Session::builder(environment()?).map_err(|e| ort_err(&e))?;
        if let Some(n) = threads {
            builder = builder.with_intra_threads(n).map_err(|e| ort_err(&e))?;
        }
        let session = builder.commit_from_memory(&bytes).map_err(|e| ort_err(&e))?;
        Ok(OrtNetwork { session, path: path.to_path_buf(), evaluated: 0, seconds: 0.0 })
    }

    /// The graph file.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// Evaluate the network on `points` with unit `viewdirs` (same length).
    pub fn run(&mut self, points: &[[f32; 3]], viewdirs: &[[f32; 3]]) -> Result<FieldOutput> {
        assert_eq!(points.len(), viewdirs.len(), "one view direction per point");
        let n = points.len();
        if n == 0 {
            return Ok(FieldOutput::default());
        }
        self.evaluated += n;
        let path = self.path.clone();
        let ort_err = |e: &dyn std::fmt::Display| RuntimeError::Ort { path: path.clone(), message: e.to_string() };
        let p = TensorRef::from_array_view(([n, 3], points.as_flattened())).map_err(|e| ort_err(&e))?;
        let d = TensorRef::from_array_view(([n, 3], viewdirs.as_flattened())).map_err(|e| ort_err(&e))?;
        let start = std::time::Instant::now();
        let outputs = self.session.run(ort::inputs!["points" => p, "viewdirs" => d]).map_err(|e| ort_err(&e))?;
        self.seconds += start.elapsed().as_secs_f64();
        let column = |name: &str, cols: usize| -> Result<&[f32]> {
            let value = outputs.get(name).ok_or_else(|| RuntimeError::bundle(&path, format!("no output {name}")))?;
            let (shape, data) = value.try_extract_tensor::<f32>().map_err(|e| ort_err(&e))?;
            if shape[..] != [n as i64, cols as i64] {
                return Err(RuntimeError::bundle(&path, format!("output {name} has shape {:?} for {n} points, expected [{n}, {cols}]", &shape[..])));
            }
            Ok(data)
        };
        let rgb = column("rgb", 3)?.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect();
        let sigma = column("sigma", 1)?.to_vec();
        Ok(FieldOutput { rgb, sigma })
    }
}
