//! One bundle graph as onnxruntime sessions that follow the graph contract
//! ([`nerf_bundle::graph`]): `points`, `viewdirs` `[N, 3]` in; `rgb [N, 3]`, `sigma [N, 1]` out.
//!
//! # Threads
//! A call is split across `workers` sessions of the same graph, one per core, each running
//! with a single intra-op thread on pieces of at most [`Threading::points_per_run`] points.
//! Measured on 2 cores with the hash-grid field graph of a 20-minute lego model (onnxruntime's
//! Python API, 262,144 random points in the box, best of 3): one session with 2 intra-op
//! threads ran 464–470k points/s on 65,536-point calls and 519–540k on 4,096; two single-thread
//! sessions side by side on 2,048-point pieces 626–637k. The graph's intermediates (`[L, N, 8]`
//! rows and weights) then stay in each core's cache, and no node waits for the other thread.
//! The MLP bundles gain as well (`models/lego`, 200×200, one old and one new `nerf-render` run
//! after the other): 2 marched orbit frames 3.35 → 2.5 s, a dense 64 + 128 frame 11.0 → 5.1 s
//! and 591 → 96 MB, as activations are bounded by the piece, not the chunk. Tables of 1 MiB and
//! more are given to every session as one shared value (a 20-minute lego hash-grid bundle:
//! 225 MB peak with two workers, 176 MB with one; 224 MB before, with one two-thread session).
//!
//! # Hash-grid graphs
//! By default ([`Encoding::Rust`]) a hash-grid graph is cut after its encodings
//! ([`nerf_bundle::ngp::head_graph`]): the core evaluates the hash grid and the harmonics (on
//! all cores, [`ENCODE_BLOCK`] points at a time) and the sessions run the MLPs on them. The
//! pixels are those of the whole graph (docs/rendering.md gives the measurements).

use crate::environment::{Device, environment_for, place};
use crate::error::{Result, RuntimeError};
use nerf_core::field::FieldOutput;
use nerf_bundle::graph::{MAX_GRAPH_BYTES, check_contract, check_initializers, decode_model};
use nerf_bundle::ngp::{FEATURES_TENSOR, SH_TENSOR, SplitNgp};
use nerf_core::field::ngp::spherical_harmonics::SH4_DIM;
use rayon::prelude::*;
use prost::Message;
use ort::memory::{AllocationDevice, Allocator, AllocatorType, MemoryInfo, MemoryType};
use ort::session::Session;
use ort::value::{DynValue, Shape, Tensor, TensorRef, TensorRefMut};
use std::sync::Arc;
use std::path::{Path, PathBuf};

/// How a graph's evaluations use the cores.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Threading {
    /// Sessions run side by side, each on one thread (≥ 1).
    pub workers: usize,
    /// The most points one session evaluates per onnxruntime call (≥ 1): bounds the graph's
    /// intermediates, so they stay in cache.
    pub points_per_run: usize,
    /// Where the sessions run.
    pub device: Device,
}

/// Default [`Threading::points_per_run`] (measured, module doc).
pub const POINTS_PER_RUN: usize = 2048;

/// A call smaller than this many points per worker runs on fewer workers (thread start-up
/// would cost more than it saves).
const MIN_POINTS_PER_WORKER: usize = 256;

impl Threading {
    /// `threads` workers (`None`: one per core) with the default piece size.
    pub fn new(threads: Option<usize>) -> Self {
        let workers = threads.unwrap_or_else(|| std::thread::available_parallelism().map_or(1, |n| n.get())).max(1);
        Threading { workers, points_per_run: POINTS_PER_RUN, device: Device::Cpu }
    }
}

impl Default for Threading {
    fn default() -> Self {
        Threading::new(None)
    }
}

/// Where a hash-grid graph's encoding is evaluated.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Encoding {
    /// The core's Rust encodings (the ones training uses: the hash grid of the points, the
    /// harmonics of the view directions) and only the graph's head in onnxruntime, for graphs that can be cut there ([`nerf_bundle::ngp::head_graph`]);
    /// others run whole. onnxruntime's `Gather` of the table's rows is the floor of the whole
    /// graph on a CPU, the Rust encoding reads the same rows at 2–3× the speed.
    #[default]
    Rust,
    /// The whole graph in onnxruntime, as every other consumer runs it.
    Graph,
}

/// Points encoded at a time on the split path: the features of a block (8 MiB at 32 per point)
/// are computed on all cores, then the head's sessions run on them.
const ENCODE_BLOCK: usize = 1 << 16;

/// A graph loaded into onnxruntime.
pub struct OrtNetwork {
    sessions: Vec<Session>,
    /// Set when the hash encoding runs in Rust and the sessions hold the graph's head.
    encoder: Option<SplitNgp>,
    points_per_run: usize,
    path: PathBuf,
    /// Points evaluated so far (for benchmarks: how much work skipping saves).
    pub evaluated: usize,
    /// Seconds spent in onnxruntime so far (for benchmarks: the graph's share of a frame).
    pub seconds: f64,
    /// Seconds spent in the Rust encoding so far (split graphs only).
    pub encoding_seconds: f64,
    /// The split path's inputs (unit points, features, harmonics), kept from call to call:
    /// fresh, zeroed buffers of a block's size each call cost as much as the loop around them.
    scratch: (Vec<[f32; 3]>, Vec<f32>, Vec<f32>),
    /// On a GPU: page-locked host buffers for each call's inputs and outputs.
    pinned: Option<Pinned>,
    device: Device,
}

/// Page-locked ("pinned") host memory from onnxruntime's CUDA provider: a GPU copies it by DMA
/// directly, where ordinary (pageable) memory is staged through a driver buffer. Measured on an
/// H200 (a 400×400 lego-ngp frame, 34 calls): 0.135 s a frame against 0.138 s, since a call's
/// fixed cost (≈ 1 ms) outweighs its copies; never slower, so kept.
struct Pinned {
    allocator: Allocator,
}

impl Pinned {
    fn new(session: &Session, gpu: i32) -> ort::Result<Self> {
        let info = MemoryInfo::new(AllocationDevice::CUDA_PINNED, gpu, AllocatorType::Device, MemoryType::CPUInput)?;
        Ok(Pinned { allocator: Allocator::new(session, info)? })
    }
}

impl OrtNetwork {
    /// Load `path`, checking it decodes and follows the contract before onnxruntime sees it,
    /// whole ([`Encoding::Graph`]). `threads`: workers (`None`: one per core), see [`Threading`].
    pub fn load(path: &Path, threads: Option<usize>) -> Result<Self> {
        Self::load_with(path, Threading::new(threads), Encoding::Graph)
    }

    /// [`OrtNetwork::load`] with the piece size and where a hash grid is encoded.
    pub fn load_with(path: &Path, threading: Threading, encoding: Encoding) -> Result<Self> {
        let bytes = nerf_core::io::limits::read_bounded(path, MAX_GRAPH_BYTES)
            .map_err(|e| RuntimeError::bundle(path, format!("cannot read the graph: {e}")))?;
        let model = decode_model(path, &bytes)?;
        check_contract(&model).map_err(|e| RuntimeError::bundle(path, e))?;
        // Tables and weights the size their shapes say, before onnxruntime indexes into them.
        check_initializers(&model).map_err(|e| RuntimeError::bundle(path, e))?;
        let ort_err = |e: &dyn std::fmt::Display| RuntimeError::Ort { path: path.to_path_buf(), message: e.to_string() };
        let (model, bytes, encoder) = match encoding {
            Encoding::Rust => split(path, model, bytes)?,
            _ => (model, bytes, None),
        };
        // The library first: ort's own calls (a tensor for the shared tables) would otherwise
        // load it themselves and panic where it is missing.
        let environment = environment_for(threading.device)?;
        if threading.device != Device::Cpu && model.graph.as_ref().is_some_and(|g| g.node.iter().any(|n| n.op_type == "BitwiseXor")) {
            // onnxruntime's CUDA provider has no BitwiseXor kernel (measured on an H200: a
            // 400×400 lego-ngp frame 0.88 s bitwise, 0.12 s portable).
            eprintln!(
                "warning: {}: the bitwise lowering's BitwiseXor nodes run on the CPU, with copies to and from {} (`nerf export --bundle <this bundle> --portable --out <dir>` makes one that runs wholly on the GPU, with the same pixels)",
                path.display(),
                threading.device
            );
        }
        // The large tables once for all workers' sessions (onnxruntime uses a value given as an
        // initializer in place of the graph's copy, without copying it).
        let shared = if threading.workers > 1 { shared_initializers(&model).map_err(|e| ort_err(&e))? } else { vec![] };
        drop(model);
        let sessions = (0..threading.workers.max(1))
            .map(|_| {
                let builder = Session::builder(environment).map_err(|e| ort_err(&e))?;
                let mut builder = place(builder.with_intra_threads(1).map_err(|e| ort_err(&e))?, threading.device)?;
                for (name, value) in &shared {
                    builder = builder.with_initializer(name, value.clone()).map_err(|e| ort_err(&e))?;
                }
                builder.commit_from_memory(&bytes).map_err(|e| ort_err(&e))
            })
            .collect::<Result<Vec<_>>>()?;
        let pinned = match threading.device {
            Device::Cuda(gpu) => match Pinned::new(&sessions[0], gpu as i32) {
                Ok(p) => Some(p),
                Err(e) => {
                    eprintln!("warning: {}: no page-locked buffers from onnxruntime's CUDA provider ({e}); inputs and outputs go through ordinary memory (slower)", path.display());
                    None
                }
            },
            Device::Cpu => None,
        };
        Ok(OrtNetwork { sessions, encoder, points_per_run: threading.points_per_run.max(1), path: path.to_path_buf(), evaluated: 0, seconds: 0.0, encoding_seconds: 0.0, scratch: Default::default(), pinned, device: threading.device })
    }

    /// Whether a GPU session's inputs and outputs go through page-locked host buffers.
    pub fn pinned(&self) -> bool {
        self.pinned.is_some()
    }

    /// Evaluate `n` points whose inputs (`points`, `viewdirs`: `[n, 3]` f32) lie in the memory
    /// of this session's device (GPU memory for a GPU session, host memory for a CPU one),
    /// writing its outputs (`rgb` `[n, 3]`, `sigma` `[n, 1]` f32) there too (onnxruntime's IO
    /// binding), pieces of `points_per_run` points. The whole graph's inputs only.
    ///
    /// # Safety
    /// Each address must be memory of this session's device holding (inputs) or with room for
    /// (outputs) `n` rows, not otherwise in use until the call returns.
    pub unsafe fn run_on_device(&mut self, n: usize, inputs: [u64; 2], outputs: [u64; 2]) -> Result<()> {
        let path = self.path.clone();
        let ort_err = |e: &dyn std::fmt::Display| RuntimeError::Ort { path: path.clone(), message: e.to_string() };
        if self.encoder.is_some() {
            return Err(RuntimeError::Other(format!("{}: run_on_device needs the whole graph (its hash encoding is split off to Rust)", self.path.display())));
        }
        let (device, id) = match self.device {
            Device::Cuda(gpu) => (AllocationDevice::CUDA, gpu as i32),
            Device::Cpu => (AllocationDevice::CPU, 0),
        };
        let start = std::time::Instant::now();
        let session = &mut self.sessions[0];
        for first in (0..n).step_by(self.points_per_run) {
            let k = self.points_per_run.min(n - first);
            // Rows `first..first + k` of a `[n, width]` f32 buffer at `ptr`.
            let rows = |ptr: u64, width: usize| -> Result<TensorRefMut<'static, f32>> {
                let info = MemoryInfo::new(device.clone(), id, AllocatorType::Device, MemoryType::Default).map_err(|e| ort_err(&e))?;
                let at = (ptr + (first * width * 4) as u64) as *mut std::ffi::c_void;
                // SAFETY: the caller's buffers hold n rows of `width` f32.
                unsafe { TensorRefMut::from_raw(info, at, Shape::new([k as i64, width as i64])) }.map_err(|e| ort_err(&e))
            };
            let mut binding = session.create_binding().map_err(|e| ort_err(&e))?;
            let (points, viewdirs) = (rows(inputs[0], 3)?, rows(inputs[1], 3)?);
            // SAFETY: the tensors outlive the run below.
            unsafe {
                bind_in_place(&mut binding, c"points", &points).map_err(|e| ort_err(&e))?;
                bind_in_place(&mut binding, c"viewdirs", &viewdirs).map_err(|e| ort_err(&e))?;
            }
            binding.bind_output("rgb", rows(outputs[0], 3)?).map_err(|e| ort_err(&e))?;
            binding.bind_output("sigma", rows(outputs[1], 1)?).map_err(|e| ort_err(&e))?;
            session.run_binding(&binding).map_err(|e| ort_err(&e))?;
            drop((points, viewdirs));
        }
        self.seconds += start.elapsed().as_secs_f64();
        self.evaluated += n;
        Ok(())
    }

    /// Use ordinary host memory for a GPU session's inputs and outputs from now on (for
    /// benchmarks: what page-locked buffers save).
    pub fn unpin(&mut self) {
        self.pinned = None;
    }

    /// Where this graph's encoding runs ([`Encoding::Graph`] for graphs that are not split).
    pub fn encoding(&self) -> Encoding {
        if self.encoder.is_some() { Encoding::Rust } else { Encoding::Graph }
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
        let Some(encoder) = &self.encoder else {
            let start = std::time::Instant::now();
            let inputs = [Input { name: "points", values: points.as_flattened(), width: 3 }, Input { name: "viewdirs", values: viewdirs.as_flattened(), width: 3 }];
            let out = self.run_sessions(inputs, n);
            self.seconds += start.elapsed().as_secs_f64();
            return out;
        };
        let width = encoder.grid.output_dim();
        let block = n.min(ENCODE_BLOCK);
        let (mut unit, mut features, mut sh) = std::mem::take(&mut self.scratch);
        // Every value is written before it is read: growing zeroes only the new part.
        for (v, len) in [(&mut features, block * width), (&mut sh, block * SH4_DIM)] {
            if v.len() < len {
                v.resize(len, 0.0);
            }
        }
        if unit.len() < block {
            unit.resize(block, [0.0; 3]);
        }
        let mut out = FieldOutput { rgb: Vec::with_capacity(n), sigma: Vec::with_capacity(n) };
        for (points, viewdirs) in points.chunks(ENCODE_BLOCK).zip(viewdirs.chunks(ENCODE_BLOCK)) {
            let start = std::time::Instant::now();
            let m = points.len();
            let encoder = self.encoder.as_ref().expect("split");
            let (unit, features, sh) = (&mut unit[..m], &mut features[..m * width], &mut sh[..m * SH4_DIM]);
            encoder.encode_into(points, viewdirs, unit, features, sh);
            let encoded = std::time::Instant::now();
            self.encoding_seconds += (encoded - start).as_secs_f64();
            let inputs = [Input { name: FEATURES_TENSOR, values: features, width }, Input { name: SH_TENSOR, values: sh, width: SH4_DIM }];
            let part = self.run_sessions(inputs, m)?;
            self.seconds += encoded.elapsed().as_secs_f64();
            out.rgb.extend(part.rgb);
            out.sigma.extend(part.sigma);
        }
        self.scratch = (unit, features, sh);
        Ok(out)
    }

    /// The sessions on `inputs` (`n` rows each), split across the workers.
    fn run_sessions(&mut self, inputs: [Input; 2], n: usize) -> Result<FieldOutput> {
        let workers = self.sessions.len().min(n.div_ceil(MIN_POINTS_PER_WORKER)).max(1);
        let (path, piece) = (self.path.as_path(), self.points_per_run);
        if workers == 1 {
            return run_pieces(&mut self.sessions[0], path, inputs, piece, self.pinned.as_ref());
        }
        // Equal contiguous shares, one per worker, outputs concatenated in order.
        let share = n.div_ceil(workers);
        let parts = std::thread::scope(|s| {
            let handles: Vec<_> = self
                .sessions
                .iter_mut()
                .take(workers)
                .enumerate()
                .map(|(k, session)| s.spawn(move || run_pieces(session, path, inputs.map(|i| i.rows(k * share, share)), piece, None)))
                .collect();
            handles.into_iter().map(|h| h.join().unwrap_or_else(|e| std::panic::resume_unwind(e))).collect::<Vec<_>>()
        });
        let mut out = FieldOutput { rgb: Vec::with_capacity(n), sigma: Vec::with_capacity(n) };
        for part in parts {
            let part = part?;
            out.rgb.extend(part.rgb);
            out.sigma.extend(part.sigma);
        }
        Ok(out)
    }
}

/// Bind `value` as input `name` where it lies. ort's `IoBinding::bind_input` copies a borrowed
/// tensor that already lies on the session's device, through a copy session of its own whose
/// lock the copy's own binding then takes again: on device memory it never returns.
///
/// # Safety
/// `value` must outlive every run of `binding` with this input.
unsafe fn bind_in_place(binding: &mut ort::session::IoBinding, name: &std::ffi::CStr, value: &TensorRefMut<'_, f32>) -> std::result::Result<(), String> {
    use ort::AsPointer;
    let api = ort::api();
    // SAFETY: live binding and value; a NUL-terminated name.
    let status = unsafe { (api.BindInput)(binding.ptr_mut(), name.as_ptr(), (**value).ptr()) };
    if status.0.is_null() {
        return Ok(());
    }
    // SAFETY: a status onnxruntime returned, released once after its message is read.
    unsafe {
        let message = std::ffi::CStr::from_ptr((api.GetErrorMessage)(status.0)).to_string_lossy().into_owned();
        (api.ReleaseStatus)(status.0);
        Err(format!("binding input {}: {message}", name.to_string_lossy()))
    }
}

/// A hash-grid graph split for [`Encoding::Rust`]: its head (checked like any graph) and the
/// encoder, or the graph unchanged where it is not a hash grid or cannot be cut (written before
/// the features were named) — it then runs whole, as before.
#[allow(clippy::type_complexity)]
fn split(path: &Path, model: nerf_bundle::proto::ModelProto, bytes: Vec<u8>) -> Result<(nerf_bundle::proto::ModelProto, Vec<u8>, Option<SplitNgp>)> {
    match SplitNgp::of(&model).map_err(|e| RuntimeError::bundle(path, e))? {
        Some((head, split)) => {
            let bytes = head.encode_to_vec();
            Ok((head, bytes, Some(split)))
        }
        None => Ok((model, bytes, None)),
    }
}

/// A session input: `width` values per point.
#[derive(Clone, Copy)]
struct Input<'a> {
    name: &'a str,
    values: &'a [f32],
    width: usize,
}

impl<'a> Input<'a> {
    /// Rows `start..start + count` (fewer at the end).
    fn rows(self, start: usize, count: usize) -> Self {
        let rows = self.values.len() / self.width;
        let (a, b) = (start.min(rows), (start + count).min(rows));
        Input { values: &self.values[a * self.width..b * self.width], ..self }
    }

    fn len(&self) -> usize {
        self.values.len() / self.width
    }
}

/// Initializers of at least [`SHARED_BYTES`] (float32 or float16, checked sizes) as values the
/// sessions of one graph share.
fn shared_initializers(model: &nerf_bundle::proto::ModelProto) -> ort::Result<Vec<(String, Arc<DynValue>)>> {
    use nerf_bundle::proto::data_type;
    let Some(graph) = model.graph.as_ref() else { return Ok(vec![]) };
    let mut shared = Vec::new();
    for t in graph.initializer.iter().filter(|t| t.raw_data.len() >= SHARED_BYTES) {
        let dims: Vec<usize> = t.dims.iter().map(|&d| d as usize).collect();
        let value = match t.data_type {
            data_type::FLOAT => Tensor::from_array((dims, t.raw_data.chunks_exact(4).map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]])).collect::<Vec<_>>()))?.into_dyn(),
            data_type::FLOAT16 => Tensor::from_array((dims, t.raw_data.chunks_exact(2).map(|c| half::f16::from_le_bytes([c[0], c[1]])).collect::<Vec<_>>()))?.into_dyn(),
            _ => continue,
        };
        shared.push((t.name.clone(), Arc::new(value)));
    }
    Ok(shared)
}

/// Initializers this large are shared between a graph's sessions (hash tables; the paper
/// network's largest layer is 0.26 MB).
const SHARED_BYTES: usize = 1 << 20;

/// Evaluate `points` on one session, `piece` points per onnxruntime call; through `pinned`
/// host buffers where given (a GPU session).
fn run_pieces(session: &mut Session, path: &Path, inputs: [Input; 2], piece: usize, pinned: Option<&Pinned>) -> Result<FieldOutput> {
    let ort_err = |e: &dyn std::fmt::Display| RuntimeError::Ort { path: path.to_path_buf(), message: e.to_string() };
    let rows = inputs[0].len();
    let mut out = FieldOutput { rgb: Vec::with_capacity(rows), sigma: Vec::with_capacity(rows) };
    for start in (0..rows).step_by(piece) {
        let [a, b] = inputs.map(|i| i.rows(start, piece));
        let n = a.len();
        // Outlives the outputs it names.
        let binding;
        let outputs = match pinned {
            None => {
                let ta = TensorRef::from_array_view(([n, a.width], a.values)).map_err(|e| ort_err(&e))?;
                let tb = TensorRef::from_array_view(([n, b.width], b.values)).map_err(|e| ort_err(&e))?;
                session.run(ort::inputs![a.name => ta, b.name => tb]).map_err(|e| ort_err(&e))?
            }
            Some(pinned) => {
                let mut bound = session.create_binding().map_err(|e| ort_err(&e))?;
                for input in [a, b] {
                    let mut tensor = Tensor::<f32>::new(&pinned.allocator, [n, input.width]).map_err(|e| ort_err(&e))?;
                    let (_, data) = tensor.extract_tensor_mut();
                    data.par_chunks_mut(1 << 16).zip(input.values.par_chunks(1 << 16)).for_each(|(d, s)| d.copy_from_slice(s));
                    bound.bind_input(input.name, &tensor).map_err(|e| ort_err(&e))?;
                }
                for name in ["rgb", "sigma"] {
                    bound.bind_output_to_device(name, pinned.allocator.memory_info()).map_err(|e| ort_err(&e))?;
                }
                binding = bound;
                session.run_binding(&binding).map_err(|e| ort_err(&e))?
            }
        };
        let column = |name: &str, cols: usize| -> Result<&[f32]> {
            let value = outputs.get(name).ok_or_else(|| RuntimeError::bundle(path, format!("no output {name}")))?;
            let (shape, data) = value.try_extract_tensor::<f32>().map_err(|e| ort_err(&e))?;
            if shape[..] != [n as i64, cols as i64] {
                return Err(RuntimeError::bundle(path, format!("output {name} has shape {:?} for {n} points, expected [{n}, {cols}]", &shape[..])));
            }
            Ok(data)
        };
        out.rgb.extend(column("rgb", 3)?.chunks_exact(3).map(|c| [c[0], c[1], c[2]]));
        out.sigma.extend_from_slice(column("sigma", 1)?);
    }
    Ok(out)
}
