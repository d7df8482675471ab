//! `nerf bench --only ngp-render`: one lego val view of a hash-grid field at full resolution,
//! through burn and through onnxruntime with each lowering, the field graphs' points/s, and
//! the floor (a graph that only gathers the same table rows and sums them), in one run. Each
//! lowering renders twice in nerf-render: the whole graph in onnxruntime, and split (the Rust
//! hash encoding, the graph's head in onnxruntime; nerf-render's default).

use anyhow::{Context, Result, anyhow, bail};
use nerf::bench::{best_of, random_points, timed_frame};
use nerf::config::Preset;
use nerf_core::dataset::{Split, load_split};
use nerf_core::field::PlainField;
use nerf_core::field::ngp::PlainNgp;
use nerf_core::field::ngp::hash_grid::{HashGrid, corners};
use nerf_core::render::metrics::psnr;
use nerf_export::builder::{Builder, int_attribute, model_proto, value_info};
use nerf_export::field::ngp::hash_grid::table::graph_levels;
use nerf_export::proto::{GraphProto, data_type};
use nerf_export::{Bundle, CompileOptions, TablePrecision, write_bundle};
use nerf_runtime::network::{Encoding, POINTS_PER_RUN};
use nerf_runtime::{OpenOptions, OrtScene};
use prost::Message;
use std::path::Path;

/// Points per call for the graphs' points/s (the yardstick).
const GRAPH_POINTS: usize = 1 << 16;

/// One lowering's frame and graph speed.
#[derive(Debug, serde::Serialize)]
pub struct LoweringBench {
    /// `bitwise`, `bitwise, f16 table` or `portable`, with `, split` for the split path.
    pub lowering: String,
    /// Seconds for the whole frame (rays, marching, encoding, onnxruntime, compositing).
    pub seconds: f64,
    /// Of which in onnxruntime's session runs.
    pub onnxruntime_s: f64,
    /// Of which in the Rust encoding (split path; 0 for the whole graph).
    pub encoding_s: f64,
    /// Split path: PSNR of this frame against the whole graph's (∞ when identical).
    pub psnr_vs_whole_graph_db: Option<f32>,
    /// This frame's time over burn's.
    pub ratio_to_burn: f64,
    /// PSNR against the ground truth.
    pub psnr_db: f32,
    /// PSNR of this frame against burn's (parity; ∞ when identical).
    pub psnr_vs_burn_db: f32,
    /// Size of `field.onnx`.
    pub graph_mb: f64,
    /// The field alone (split: encoding and head): points/s at 65,536 random points in the box
    /// per call.
    pub graph_points_per_s: f64,
}

/// What `nerf bench --only ngp-render` measures.
#[derive(Debug, serde::Serialize)]
pub struct NgpRenderBench {
    /// The bundle measured.
    pub bundle: String,
    /// Where its field came from.
    pub trained: String,
    /// The view.
    pub view: String,
    /// Its size.
    pub width: u32,
    /// Its size.
    pub height: u32,
    /// Field evaluations per pixel (the same for every lowering: one marching).
    pub points_per_ray: f64,
    /// Seconds for the same frame through burn (the bundle's field read back into burn and the
    /// Rust encoding, as `nerf eval` renders the `ngp` preset: 4,096 rays per call).
    pub burn_s: f64,
    /// PSNR of the burn frame against the ground truth.
    pub burn_psnr_db: f32,
    /// Each lowering, compiled here from the bundle's field.
    pub lowerings: Vec<LoweringBench>,
    /// The floor: points/s of a graph that only gathers the same rows of the same table and
    /// sums them per level (row indices given as input, so no index arithmetic).
    pub floor_points_per_s: f64,
}

/// Render lego val view 0 at full resolution from the hash-grid bundle `bundle`'s field, or
/// from one trained here for `steps` steps of the ngp preset (in a temporary directory).
pub fn bench_ngp_render(bundle: Option<&Path>, steps: usize, data: &Path, progress: bool) -> Result<NgpRenderBench> {
    let temporary = tempfile::tempdir()?;
    let (bundle, trained) = match bundle {
        Some(b) => (b.to_path_buf(), "given".to_string()),
        None => {
            let run = temporary.path().join("run");
            let mut config = Preset::Ngp.config();
            config.eval_every_min = 0.0;
            let options = nerf::train::TrainOptions { format: None, data: data.to_path_buf(), run: run.clone(), config, ndc: None, contract: None, downscale: 1, time_budget_min: None, iters: Some(steps), progress };
            let summary = nerf::train::train(&options)?;
            let out = temporary.path().join("bundle");
            nerf::export::export_run(&run, &out, &CompileOptions::default(), None)?;
            (out, format!("ngp preset, {} steps here ({:.1} min)", summary.steps, summary.minutes))
        }
    };
    let (read, _) = nerf::export::ngp_bundle(&bundle)?;
    let (plain, scene, occupancy) = (read.field, read.scene, read.occupancy);
    let val = load_split(data, Split::Val, 1, true)?;
    let view = &val.views[0];
    let k = view.camera;
    let truth = view.image.as_ref().expect("loaded with images");

    // burn: the same field, marched through the same grid.
    let device = nerf::backend::cpu();
    let field = nerf::field::ngp::NgpField::from_plain(&plain, &device).map_err(|e| anyhow!("{}: {e}", bundle.display()))?;
    let field: &dyn nerf::field::TrainedField = &field;
    let first = compile(&plain, &scene, &occupancy, CompileOptions::default(), &temporary.path().join("bitwise"))?;
    let render_options = nerf_core::render::RenderOptions { chunk: 4096, ..first.options.clone() };
    let (burn_image, burn_s) = timed_frame(progress, "ngp frame (burn)", k.num_pixels(), |p| field.render(&device, first.occupancy.as_ref(), &k, &view.pose, &render_options, p));

    let variants = [
        ("bitwise", CompileOptions::default()),
        ("bitwise, f16 table", CompileOptions { tables: TablePrecision::F16, ..Default::default() }),
        ("portable", CompileOptions { portable: true, ..Default::default() }),
    ];
    let (points, dirs) = random_points(GRAPH_POINTS, 2);
    let mut lowerings = Vec::new();
    let mut points_per_ray = 0.0;
    let mut opened = Some(first);
    for (name, options) in variants {
        let dir = temporary.path().join(name.replace([',', ' '], ""));
        let whole = match opened.take() {
            Some(o) => o,
            None => compile(&plain, &scene, &occupancy, options, &dir)?,
        };
        let split = OrtScene::open(&dir, &OpenOptions::default())?;
        if split.field.graphs[0].1.encoding() != Encoding::Rust {
            bail!("{}: the graph could not be split", dir.display());
        }
        let mut whole_image = None;
        for (mut ort, label) in [(whole, name.to_string()), (split, format!("{name}, split"))] {
            let (image, seconds) = timed_frame(progress, &format!("ngp frame ({label})"), k.num_pixels(), |p| ort.render(&k, &view.pose, p));
            let image = image?;
            let net = &mut ort.field.graphs[0].1;
            let (onnxruntime_s, encoding_s, evaluated) = (net.seconds, net.encoding_seconds, net.evaluated);
            points_per_ray = evaluated as f64 / k.num_pixels() as f64;
            let graph_s = best_of(3, || net.run(&points, &dirs).map(|_| ()))?;
            lowerings.push(LoweringBench {
                lowering: label,
                seconds,
                onnxruntime_s,
                encoding_s,
                psnr_vs_whole_graph_db: whole_image.as_ref().map(|w: &nerf_core::render::RenderedImage| psnr(&image.rays.rgb, &w.rays.rgb)),
                ratio_to_burn: seconds / burn_s,
                psnr_db: psnr(&image.rays.rgb, truth),
                psnr_vs_burn_db: psnr(&image.rays.rgb, &burn_image.rays.rgb),
                graph_mb: std::fs::metadata(net.path())?.len() as f64 / 1e6,
                graph_points_per_s: GRAPH_POINTS as f64 / graph_s,
            });
            whole_image.get_or_insert(image);
        }
    }
    let floor_points_per_s = floor(&plain, &points, temporary.path())?;
    Ok(NgpRenderBench {
        bundle: bundle.display().to_string(),
        trained,
        view: view.name.clone(),
        width: k.width,
        height: k.height,
        points_per_ray,
        burn_s,
        burn_psnr_db: psnr(&burn_image.rays.rgb, truth),
        lowerings,
        floor_points_per_s,
    })
}

/// Compile `plain` as `options` ask into a bundle at `dir` and open it, whole graph.
fn compile(plain: &PlainNgp, scene: &nerf_bundle::scene::SceneDescription, occupancy: &Option<nerf_core::sample::occupancy::OccupancyGrid>, options: CompileOptions, dir: &Path) -> Result<OrtScene> {
    let bundle = Bundle { field: PlainField::Ngp(plain.clone()), scene: scene.clone(), occupancy: occupancy.clone() };
    write_bundle(dir, &bundle, &options)?;
    Ok(OrtScene::open(dir, &OpenOptions { whole_graph: true, ..OpenOptions::default() })?)
}

/// Points/s of the floor graph on `points` (the rows their corners read, computed here), run as
/// the renderer runs field graphs: one single-thread session per core, 2,048-point pieces.
fn floor(plain: &PlainNgp, points: &[[f32; 3]], dir: &Path) -> Result<f64> {
    let grid = HashGrid::from_params(plain.spec.grid, plain.table.clone())?;
    let levels = grid.levels();
    let (places, rows) = graph_levels(levels);
    let f = grid.config().features_per_level;
    let width = levels.len() * 8;
    // Row indices as float32 (exact below 2²⁴), point-major [N, L·8].
    let indices: Vec<f32> = points
        .iter()
        .flat_map(|&p| {
            let unit = plain.spec.bound.to_unit(p);
            levels.iter().zip(&places).flat_map(move |(level, place)| corners(level, unit).index.map(|i| (place.offset + i as u64) as f32))
        })
        .collect();
    let mut g = Builder::default();
    let table = g.f32_tensor("table", &[rows as usize, f], &nerf_export::field::ngp::hash_grid::table::graph_table(&grid));
    let cast = g.node("Cast", &["rows"], "rows_int", vec![int_attribute("to", data_type::INT32 as i64)]);
    let values = g.node("Gather", &[&table, &cast], "values", vec![int_attribute("axis", 0)]);
    let shape = g.i64_constant("shape", &[0, levels.len() as i64, 8 * f as i64]);
    let flat = g.node("Reshape", &[&values, &shape], "flat", vec![]);
    let sum = g.f32_tensor("corner_sum", &[8 * f, f], &nerf_export::field::ngp::hash_grid::corner_sum(f));
    let summed = g.node("MatMul", &[&flat, &sum], "summed", vec![]);
    let shape = g.i64_constant("out_shape", &[0, (levels.len() * f) as i64]);
    g.node("Reshape", &[&summed, &shape], "features", vec![]);
    let graph = GraphProto {
        node: g.nodes,
        name: "floor".into(),
        initializer: g.initializers,
        doc_string: String::new(),
        input: vec![value_info(("rows", width as i64), "Table rows, float32 [N, L·8].")],
        output: vec![value_info(("features", (levels.len() * f) as i64), "Summed rows.")],
        value_info: vec![],
    };
    let path = dir.join("floor.onnx");
    std::fs::write(&path, model_proto(graph, 18, "gather floor", vec![]).encode_to_vec())?;
    let workers = std::thread::available_parallelism().map_or(1, |n| n.get());
    let mut sessions = (0..workers)
        .map(|_| -> Result<_> {
            let e = |e: &dyn std::fmt::Display| anyhow!("{}: {e}", path.display());
            let builder = ort::session::Session::builder(nerf_runtime::environment::environment()?).map_err(|x| e(&x))?;
            let mut builder = builder.with_intra_threads(1).map_err(|x| e(&x))?;
            builder.commit_from_file(&path).map_err(|x| e(&x))
        })
        .collect::<Result<Vec<_>>>()
        .context("the floor graph")?;
    let n = points.len();
    let share = n.div_ceil(workers);
    let seconds = best_of(3, || -> Result<()> {
        std::thread::scope(|s| {
            let handles: Vec<_> = sessions
                .iter_mut()
                .zip(indices.chunks(share * width))
                .map(|(session, part)| {
                    s.spawn(move || -> Result<()> {
                        for piece in part.chunks(POINTS_PER_RUN * width) {
                            let input = ort::value::TensorRef::from_array_view(([piece.len() / width, width], piece))?;
                            session.run(ort::inputs!["rows" => input])?;
                        }
                        Ok(())
                    })
                })
                .collect();
            handles.into_iter().try_for_each(|h| h.join().map_err(|_| anyhow!("a floor worker panicked"))?)
        })
    })?;
    Ok(n as f64 / seconds)
}
