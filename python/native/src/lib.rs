//! `nerf_bundle_native`: for the Python package, nerf-render's CPU work in Rust.
//! - [`march_grid`]: the marching loop of nerf-core (`render::grid::render_rays_in`), with the
//!   field a Python callable. Everything but the field's calls runs with the interpreter
//!   released, so other threads (and their onnxruntime calls) go on meanwhile.
//! - [`HashEncoder`]: a hash-grid graph split as nerf-render splits it, the encodings in Rust
//!   (the core's, training's) and the head graph for onnxruntime.

use nerf_bundle::graph::{check_contract, decode_model};
use nerf_bundle::ngp::{FEATURES_TENSOR, SH_TENSOR, SplitNgp};
use nerf_core::camera::Rays;
use nerf_core::field::ngp::spherical_harmonics::SH4_DIM;
use nerf_core::field::{Field, FieldOutput, Stage};
use nerf_core::render::RenderOptions;
use nerf_core::render::grid::{Skipper, render_rays_in};
use nerf_core::sample::{Contraction, OccupancyGrid, SamplingConfig};
use numpy::{PyArray1, PyArray2, PyArrayMethods, PyReadonlyArray1, PyReadonlyArray2, PyUntypedArrayMethods};
use prost::Message;
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;
use pyo3::types::PyBytes;
use std::path::Path;

/// What the Python package checks before it uses this module: bumped whenever the functions'
/// arguments or results change.
const INTERFACE: u32 = 1;

/// An occupancy grid made once from a bundle's cells; its skip tables are made on first use and
/// kept with it.
#[pyclass(frozen)]
struct Grid {
    grid: OccupancyGrid,
}

#[pymethods]
impl Grid {
    /// `occupied` [R³] bool in cell order over ±`bound`; `contraction` None or "linf".
    #[new]
    #[pyo3(signature = (occupied, resolution, bound, contraction=None))]
    fn new(occupied: PyReadonlyArray1<'_, bool>, resolution: usize, bound: f32, contraction: Option<&str>) -> PyResult<Self> {
        let contraction = match contraction {
            None => None,
            Some("linf") => Some(Contraction::Linf),
            Some(other) => return Err(PyValueError::new_err(format!("contraction {other:?}: only \"linf\" is known"))),
        };
        let cells = resolution.checked_pow(3).filter(|_| resolution > 0);
        if cells != Some(occupied.len()) {
            return Err(PyValueError::new_err(format!("{} occupancy flags for a {resolution}³ grid", occupied.len())));
        }
        if !(bound.is_finite() && bound > 0.0) {
            return Err(PyValueError::new_err(format!("bound {bound} is not positive and finite")));
        }
        let flags = occupied.as_array();
        let flags: Vec<bool> = flags.iter().copied().collect();
        Ok(Grid { grid: OccupancyGrid::from_occupied(resolution, bound, &flags).with_contraction(contraction) })
    }
}

/// The field as the loop sees it: the Python callable `(points [n, 3], viewdirs [n, 3]) →
/// (rgb [n, 3], sigma [n])`, float32, called with the interpreter held.
struct PythonField {
    call: Py<PyAny>,
}

impl Field for PythonField {
    type Error = PyErr;

    fn evaluate(&mut self, _stage: Stage, points: &[[f32; 3]], viewdirs: &[[f32; 3]]) -> PyResult<FieldOutput> {
        Python::attach(|py| {
            let n = points.len();
            let p = PyArray1::from_slice(py, points.as_flattened()).reshape([n, 3])?;
            let v = PyArray1::from_slice(py, viewdirs.as_flattened()).reshape([n, 3])?;
            let out = self.call.bind(py).call1((p, v))?;
            let (rgb, sigma): (PyReadonlyArray2<'_, f32>, PyReadonlyArray1<'_, f32>) = out.extract()?;
            if rgb.shape() != [n, 3] || sigma.len() != n {
                return Err(PyValueError::new_err(format!(
                    "the field gave rgb {:?} and sigma {:?} for {n} points (expected [{n}, 3] and [{n}])",
                    rgb.shape(),
                    sigma.shape()
                )));
            }
            let sigma = match sigma.as_slice() {
                Ok(s) => s.to_vec(),
                Err(_) => sigma.as_array().iter().copied().collect(),
            };
            Ok(FieldOutput { rgb: triples(&rgb), sigma })
        })
    }
}

/// Rows of a [n, 3] float32 array (a copy; one pass over memory where it is row-major).
fn triples(a: &PyReadonlyArray2<'_, f32>) -> Vec<[f32; 3]> {
    // `as_slice` also takes a column-major array, whose memory is not rows.
    match a.as_slice() {
        Ok(s) if a.is_c_contiguous() => s.chunks_exact(3).map(|r| [r[0], r[1], r[2]]).collect(),
        _ => a.as_array().rows().into_iter().map(|r| [r[0], r[1], r[2]]).collect(),
    }
}

/// Rows of the [n, 3] float32 argument `name`.
fn rows(a: &PyReadonlyArray2<'_, f32>, name: &str) -> PyResult<Vec<[f32; 3]>> {
    if a.shape()[1] != 3 {
        return Err(PyValueError::new_err(format!("{name}: shape {:?}, expected [n, 3]", a.shape())));
    }
    Ok(triples(a))
}

type Pixels<'py> = (Bound<'py, PyArray2<f32>>, Bound<'py, PyArray1<f32>>, Bound<'py, PyArray1<f32>>);

/// Render rays `origins`, `directions` [n, 3] (NDC-warped where the bundle is forward-facing;
/// `view`: the directions the field sees, normalised here as nerf-render does) through `grid`:
/// `steps` intervals over [`near`, `far`], rounds of at most 16 samples per live ray, a ray
/// stopping once its transmittance is below `min_transmittance` (None: never). The rays go
/// `rays_per_pass` at a time; with `overlap`, each pass as two halves taking turns (one
/// marches while the field evaluates the other's round). Returns rgb [n, 3], depth [n], acc
/// [n]; an exception from `field` ends the render and is raised here.
#[pyfunction]
#[pyo3(signature = (field, grid, origins, directions, view, near, far, steps, min_transmittance, white_background, rays_per_pass, overlap))]
#[allow(clippy::too_many_arguments)]
fn march_grid<'py>(
    py: Python<'py>,
    field: Py<PyAny>,
    grid: &Bound<'py, Grid>,
    origins: PyReadonlyArray2<'py, f32>,
    directions: PyReadonlyArray2<'py, f32>,
    view: PyReadonlyArray2<'py, f32>,
    near: f32,
    far: f32,
    steps: usize,
    min_transmittance: Option<f32>,
    white_background: bool,
    rays_per_pass: usize,
    overlap: bool,
) -> PyResult<Pixels<'py>> {
    let rays = Rays { origins: rows(&origins, "origins")?, directions: rows(&directions, "directions")?, viewdirs: Some(rows(&view, "view")?) };
    let n = rays.origins.len();
    if rays.directions.len() != n || rays.viewdirs.as_ref().is_some_and(|v| v.len() != n) {
        return Err(PyValueError::new_err(format!(
            "{n} origins, {} directions and {} view directions: one of each per ray",
            rays.directions.len(),
            view.shape()[0]
        )));
    }
    let chunk = rays_per_pass.max(1);
    let mut options = RenderOptions::new(SamplingConfig { near, far, ..Default::default() }, white_background, chunk, true);
    options.min_transmittance = min_transmittance;
    options.march_steps = steps.max(1);
    options.overlap = overlap;
    let grid = &grid.get().grid;
    let mut field = PythonField { call: field };
    let out = py.detach(|| {
        let skipper = Skipper::new(grid);
        let mut out = Vec::with_capacity(n);
        for start in (0..n).step_by(chunk) {
            out.extend(render_rays_in(&mut field, &skipper, &rays.slice(start..(start + chunk).min(n)), &options)?);
        }
        Ok::<_, PyErr>(out)
    })?;
    let rgb: Vec<f32> = out.iter().flat_map(|r| r.rgb).collect();
    let depth: Vec<f32> = out.iter().map(|r| r.depth).collect();
    let acc: Vec<f32> = out.iter().map(|r| r.acc).collect();
    Ok((PyArray1::from_vec(py, rgb).reshape([n, 3])?, PyArray1::from_vec(py, depth), PyArray1::from_vec(py, acc)))
}

/// The head's inputs: features [n, L·F] and harmonics [n, 16].
type HeadInputs<'py> = (Bound<'py, PyArray2<f32>>, Bound<'py, PyArray2<f32>>);

/// A hash-grid field graph split where nerf-render splits it ([`SplitNgp`]): the hash grid of
/// the points and the harmonics of the view directions in Rust, the rest (the head) for
/// onnxruntime.
#[pyclass(frozen)]
struct HashEncoder {
    split: SplitNgp,
    /// The head, encoded once.
    head: Vec<u8>,
}

#[pymethods]
impl HashEncoder {
    /// The head's inputs: the features [N, L·F] and the harmonics [N, 16].
    #[classattr]
    const FEATURES: &'static str = FEATURES_TENSOR;
    #[classattr]
    const SH: &'static str = SH_TENSOR;

    /// The encoder of the graph `model` (ONNX bytes; `path` names it in errors), or None where
    /// it is not a hash-grid field or cannot be cut (older graphs: they run whole).
    #[staticmethod]
    fn of_graph(path: &str, model: &[u8]) -> PyResult<Option<Self>> {
        let path = Path::new(path);
        let model = decode_model(path, model).map_err(|e| PyValueError::new_err(e.to_string()))?;
        check_contract(&model).map_err(|e| PyValueError::new_err(format!("{}: {e}", path.display())))?;
        let split = SplitNgp::of(&model).map_err(|e| PyValueError::new_err(format!("{}: {e}", path.display())))?;
        Ok(split.map(|(head, split)| HashEncoder { head: head.encode_to_vec(), split }))
    }

    /// The head graph, ONNX bytes: inputs [`Self::FEATURES`] and [`Self::SH`], outputs rgb, sigma.
    #[getter]
    fn head<'py>(&self, py: Python<'py>) -> Bound<'py, PyBytes> {
        PyBytes::new(py, &self.head)
    }

    /// The head's inputs for `points` and unit `viewdirs` [n, 3]: features [n, L·F] and
    /// harmonics [n, 16], float32 (the interpreter released meanwhile).
    fn encode<'py>(&self, py: Python<'py>, points: PyReadonlyArray2<'py, f32>, viewdirs: PyReadonlyArray2<'py, f32>) -> PyResult<HeadInputs<'py>> {
        let (points, viewdirs) = (rows(&points, "points")?, rows(&viewdirs, "viewdirs")?);
        if points.len() != viewdirs.len() {
            return Err(PyValueError::new_err(format!("{} points and {} view directions", points.len(), viewdirs.len())));
        }
        let (n, width) = (points.len(), self.split.grid.output_dim());
        let (features, sh) = py.detach(|| {
            let (mut unit, mut features, mut sh) = (vec![[0.0; 3]; n], vec![0.0; n * width], vec![0.0; n * SH4_DIM]);
            self.split.encode_into(&points, &viewdirs, &mut unit, &mut features, &mut sh);
            (features, sh)
        });
        Ok((PyArray1::from_vec(py, features).reshape([n, width])?, PyArray1::from_vec(py, sh).reshape([n, SH4_DIM])?))
    }
}

#[pymodule]
fn nerf_bundle_native(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add("INTERFACE", INTERFACE)?;
    m.add_class::<Grid>()?;
    m.add_class::<HashEncoder>()?;
    m.add_function(wrap_pyfunction!(march_grid, m)?)?;
    Ok(())
}
