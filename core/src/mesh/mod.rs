//! Meshes from a field: its density sampled on a lattice over its box, the surface at a density
//! threshold by marching cubes, each vertex coloured by the field, written as a binary PLY in
//! the scene's own coordinates. The burn run (`nerf mesh --run`) and the onnxruntime bundle
//! (`nerf mesh --bundle`) both come here through [`Field`].
//!
//! - [`cases`]: the marching-cubes case table (built from a rule, tested case by case).
//! - [`carve`]: visibility carving, which nodes the training cameras see as empty.
//! - [`cavities`]: which empty nodes count as outside (reached from the border through open
//!   nodes); the others (hollows inside solids, space no camera saw empty) are filled.
//! - [`march`]: marching over a lattice fed one z-slice at a time (memory: a few slices).
//! - [`ply`]: the PLY writer (streamed, written whole or not at all) and reader.
//!
//! # What is sampled
//! The lattice has `resolution + 1` nodes per axis over the cube `[−bound, bound]³` of the field
//! ([`choose_bound`]). With an occupancy grid only the nodes in occupied cells go to the field;
//! the others count as σ = 0 (the grid's own threshold is far below any mesh threshold, so a
//! skipped node would be outside anyway). Densities below 0 (the burn NeRF MLP leaves its ReLU
//! to compositing) count as 0.
//!
//! # Two passes
//! Unless asked to keep them, cavities are filled: a first pass over the slices records which
//! nodes are dense (one bit each) and, given depth views ([`carve`]), which empty nodes some
//! view sees as empty or none has in view (another bit); a flood fill from the lattice's border
//! finds the empty nodes the outside reaches through those ([`cavities`]), and the second pass,
//! which marches, counts the other empty nodes as just above the threshold. Only the outer
//! surface the cameras saw is left; the price is evaluating the densities twice (and rendering
//! the views).
//!
//! # Normals and colours
//! A vertex's normal is the density gradient's opposite, normalised: central differences on the
//! lattice (one-sided at its faces), interpolated along the vertex's edge. No extra field
//! evaluations, and it points from dense to empty, out of the object. The colour is what a
//! camera looking straight at the surface from outside sees: 16 samples along the inverse
//! normal, from a cell outside to three inside, composited and normalised by their opacity
//! ([`colour`]; the vertex alone lies at the surface's faint edge, whose colour the renders
//! hardly train).

pub mod carve;
pub mod cases;
pub mod cavities;
pub mod colour;
pub mod march;
pub mod ply;

use crate::camera::SceneTransform;
use crate::dataset::ScenePlacement;
use crate::error::{Error, Result};
use crate::field::{Field, FieldKind, Stage};
use crate::io::limits::{Origin, check_count};
use crate::sample::occupancy::OccupancyGrid;
use glam::Vec3;
use carve::{DepthView, MARGIN_CELLS, Sight, WIDEN_STEPS, sight_of};
use cavities::{NodeBits, reached_from_border, widen};
use rayon::prelude::*;
use march::{Lattice, LayerMesh, march};
use ply::{PlyVertex, PlyWriter};
use std::cell::RefCell;
use std::path::Path;

/// Lattice cells per axis unless asked otherwise (instant-ngp's mesh default).
pub const DEFAULT_RESOLUTION: usize = 256;
/// Most lattice cells per axis: filling cavities takes two bits per node, 270 MB at 1024; the
/// time (10⁹ points, twice) is the real limit.
pub const MAX_RESOLUTION: usize = 1024;
/// Half the side of the cube meshed when neither the field nor an occupancy grid gives one:
/// the Blender scenes' cube.
pub const DEFAULT_BOUND: f32 = 1.5;
/// Points per field call (bounds the field's working memory).
pub const POINTS_PER_CALL: usize = 1 << 16;

/// The density threshold of a kind's surface unless asked otherwise.
///
/// - `ngp`: 2.5, instant-ngp's own (its `MeshState::thresh`) for the same density activation
///   (exp). Our Blender scenes keep their units where instant-ngp shrinks them by 0.33, so the
///   same σ is ~3× less opaque per unit length here; docs/mesh.md measures what it gives.
/// - `mlp` (the NeRF MLPs, nerf-pytorch imports): 50, the original NeRF's `extract_mesh`
///   notebook's for its lego MLP (ReLU density, noisy at low values).
pub fn default_threshold(kind: FieldKind) -> f32 {
    match kind {
        FieldKind::Mlp => 50.0,
        FieldKind::Ngp => 2.5,
    }
}

/// What to mesh and how finely.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MeshOptions {
    /// Lattice cells per axis.
    pub resolution: usize,
    /// The surface is where σ crosses this.
    pub threshold: f32,
    /// The lattice covers `[−bound, bound]³` in the field's frame.
    pub bound: f32,
    /// Keep the inner walls of hollows inside solids (one pass instead of two).
    pub keep_cavities: bool,
}

impl MeshOptions {
    /// Check every value, naming its option.
    pub fn check(&self) -> Result<()> {
        check_count(self.resolution, MAX_RESOLUTION, "cells per axis", Origin::Option("--resolution"))?;
        if self.resolution < 2 {
            return Err(Error::Argument(format!("--resolution {}: give at least 2 cells per axis", self.resolution)));
        }
        if !(self.threshold > 0.0 && self.threshold.is_finite()) {
            return Err(Error::Argument(format!("--threshold {}: the density threshold must be a positive number", self.threshold)));
        }
        if !(self.bound > 0.0 && self.bound.is_finite()) {
            return Err(Error::Argument(format!("--bound {}: the box's half side must be a positive number", self.bound)));
        }
        Ok(())
    }
}

/// Where the meshed cube's size came from.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum BoundSource {
    /// `--bound`.
    Option,
    /// The field's own box (a hash-grid field).
    Field,
    /// The occupancy grid's cube.
    Occupancy,
    /// [`DEFAULT_BOUND`].
    Default,
}

/// The cube to mesh: `--bound` when given, else the field's box, else its occupancy grid's
/// cube, else [`DEFAULT_BOUND`].
pub fn choose_bound(option: Option<f32>, field_box: Option<f32>, occupancy: Option<&OccupancyGrid>) -> (f32, BoundSource) {
    match (option, field_box, occupancy) {
        (Some(b), _, _) => (b, BoundSource::Option),
        (None, Some(b), _) => (b, BoundSource::Field),
        (None, None, Some(g)) => (g.bound(), BoundSource::Occupancy),
        (None, None, None) => (DEFAULT_BOUND, BoundSource::Default),
    }
}

/// The transform that takes the mesh back to the scene's coordinates (the placement's, undone);
/// an error for NDC scenes (`ndc`: the sampling's NDC rays), whose field is in projected
/// coordinates with the far plane at infinity. `source` names the file in the error.
pub fn scene_transform(placement: Option<&ScenePlacement>, ndc: bool, source: &Path) -> Result<SceneTransform> {
    match placement {
        _ if ndc || placement.is_some_and(|p| p.ndc.is_some()) => Err(Error::invalid(
            source,
            "the scene was trained with NDC rays (a forward-facing capture): its field lives in projected coordinates \
             reaching to infinity, which have no box to mesh (train with `--ndc false`, or nerf-pytorch's --no_ndc, to mesh it)",
        )),
        Some(p) => Ok(p.transform),
        None => Ok(SceneTransform::identity()),
    }
}

/// What the user asked for (`nerf mesh` options); the rest comes from the field.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MeshRequest {
    /// Lattice cells per axis.
    pub resolution: usize,
    /// The density threshold (default: the kind's, [`default_threshold`]).
    pub threshold: Option<f32>,
    /// Half the side of the cube to mesh (default: see [`choose_bound`]).
    pub bound: Option<f32>,
    /// Keep the inner walls of hollows ([`MeshOptions::keep_cavities`]).
    pub keep_cavities: bool,
}

impl MeshRequest {
    /// The options for a field of `kind` (`None`: unknown, so `--threshold` is needed) with
    /// `field_box` and `occupancy`; and where the cube came from. `source` names the field's
    /// file in errors.
    pub fn options(&self, kind: Option<FieldKind>, field_box: Option<f32>, occupancy: Option<&OccupancyGrid>, source: &Path) -> Result<(MeshOptions, BoundSource)> {
        let threshold = match (self.threshold, kind) {
            (Some(t), _) => t,
            (None, Some(kind)) => default_threshold(kind),
            (None, None) => return Err(Error::invalid(source, "the field's kind is unknown here, so it has no default threshold: give --threshold")),
        };
        let (bound, from) = choose_bound(self.bound, field_box, occupancy);
        let options = MeshOptions { resolution: self.resolution, threshold, bound, keep_cavities: self.keep_cavities };
        options.check()?;
        Ok((options, from))
    }
}

/// The kind named `name` (`scene.json`'s `field`), for its default threshold.
pub fn kind_named(name: &str) -> Option<FieldKind> {
    FieldKind::ALL.iter().copied().find(|k| k.name() == name)
}

/// What [`extract_mesh`] did.
#[derive(Debug, Clone, PartialEq)]
pub struct MeshReport {
    /// Vertices written.
    pub vertices: usize,
    /// Triangles written.
    pub faces: usize,
    /// Lattice nodes.
    pub nodes: usize,
    /// Of them, those the field evaluated (the others were in empty cells of the grid), in
    /// each pass.
    pub evaluated: usize,
    /// Empty nodes counted as inside: cavities, and with carving the space no view saw empty
    /// (0 when they are kept).
    pub filled: usize,
    /// Views that carved (0: none).
    pub views: usize,
    /// The largest density seen (to choose a threshold by).
    pub max_density: f32,
}

/// What `nerf mesh` did, through either runtime.
#[derive(Debug, Clone, PartialEq)]
pub struct MeshSummary {
    /// Counts and the largest density seen.
    pub report: MeshReport,
    /// Resolution, threshold and cube used.
    pub options: MeshOptions,
    /// Where the cube came from.
    pub bound_from: BoundSource,
    /// What carved, or why nothing did ([`carve::carving_views`]).
    pub carving: String,
}

/// Mesh `field` (see the module docs) into the PLY file `out` (its directory is created),
/// vertices and normals taken back to the scene's frame by `transform`; `views` carve (none:
/// the cavity fill alone; ignored when cavities are kept). Nothing is written unless the whole
/// mesh is; a mesh with no vertex (no density above the threshold) is an error that says the
/// largest density seen.
pub fn extract_mesh<F, E>(
    field: &mut F,
    occupancy: Option<&OccupancyGrid>,
    views: &[DepthView],
    options: &MeshOptions,
    transform: &SceneTransform,
    out: &Path,
    progress: bool,
) -> std::result::Result<MeshReport, E>
where
    F: Field,
    E: From<F::Error> + From<Error>,
{
    options.check()?;
    if let Some(parent) = out.parent().filter(|p| !p.as_os_str().is_empty()) {
        std::fs::create_dir_all(parent).map_err(|e| Error::io(parent, e))?;
        // The parts a killed `nerf mesh` left beside its output.
        crate::io::atomic::remove_stale_temporaries(parent);
    }
    let mut writer = PlyWriter::create(out)?;
    let (n, threshold) = (options.resolution, options.threshold);
    let lattice = Lattice::cube(n, options.bound);
    let slice_len = lattice.slice_len();
    let field = RefCell::new(field);
    let passes = if options.keep_cavities { n } else { 2 * n + 1 };
    let bar = progress_bar(progress, passes);
    let views = if options.keep_cavities { &[][..] } else { views };
    // Cavities: which nodes the outside reaches (`None`: keep them).
    let reached = if options.keep_cavities {
        None
    } else {
        bar.set_message(if views.is_empty() { "density" } else { "density, carving" });
        let mut dense = NodeBits::new(slice_len * (n + 1));
        let mut open = (!views.is_empty()).then(|| NodeBits::new(slice_len * (n + 1)));
        for k in 0..=n {
            let (values, _) = densities::<F, E>(&field, &lattice, occupancy, k)?;
            for (s, v) in values.iter().enumerate() {
                if *v > threshold {
                    dense.set(k * slice_len + s);
                }
            }
            if let Some(open) = &mut open {
                for (s, seen) in seen_open(&lattice, k, &values, threshold, views).into_iter().enumerate() {
                    if seen {
                        open.set(k * slice_len + s);
                    }
                }
            }
            bar.inc(1);
        }
        // Walls: the dense nodes, and with carving the empty ones left shut.
        let walls = match open {
            None => dense,
            Some(mut open) => {
                widen(n, &mut open, &dense, WIDEN_STEPS);
                drop(dense);
                open.invert();
                open
            }
        };
        Some(reached_from_border(n, &walls))
    };
    bar.set_message("surface");
    let (mut evaluated, mut max_density, mut filled) = (0usize, 0.0f32, 0usize);
    let slice = |k: usize| -> std::result::Result<Vec<f32>, E> {
        let (mut values, asked) = densities::<F, E>(&field, &lattice, occupancy, k)?;
        evaluated += asked;
        max_density = values.iter().fold(max_density, |m, &v| m.max(v));
        if let Some(reached) = &reached {
            // Just above the threshold: inside, and (cavities touch no outside node) on no edge
            // the surface crosses.
            let inside = threshold * (1.0 + 1e-3);
            for (s, v) in values.iter_mut().enumerate() {
                if *v <= threshold && !reached.get(k * slice_len + s) {
                    *v = inside;
                    filled += 1;
                }
            }
        }
        Ok(values)
    };
    let emit = |_: usize, layer: LayerMesh| -> std::result::Result<(), E> {
        let mut vertices = Vec::with_capacity(layer.vertices.len());
        for chunk in layer.vertices.chunks(POINTS_PER_CALL / colour::SAMPLES) {
            let points: Vec<[f32; 3]> = chunk.iter().flat_map(|v| colour::sample_points(v.position, v.normal, lattice.spacing)).collect();
            let inward: Vec<[f32; 3]> = chunk.iter().flat_map(|v| [v.normal.map(|x| -x); colour::SAMPLES]).collect();
            let out = field.borrow_mut().evaluate(Stage::Fine, &points, &inward)?;
            let rgb = out.sigma.chunks_exact(colour::SAMPLES).zip(out.rgb.chunks_exact(colour::SAMPLES)).map(|(sigma, rgb)| colour::seen_colour(sigma, rgb, lattice.spacing));
            vertices.extend(chunk.iter().zip(rgb).map(|(v, c)| PlyVertex {
                position: transform.invert_point(Vec3::from_array(v.position)).to_array(),
                normal: (transform.rotation_matrix().transpose() * Vec3::from_array(v.normal)).to_array(),
                color: c.map(|x| (x.clamp(0.0, 1.0) * 255.0).round() as u8),
            }));
        }
        writer.push_vertices(&vertices)?;
        writer.push_faces(&layer.faces)?;
        bar.inc(1);
        Ok(())
    };
    march(&lattice, threshold, slice, emit, |problem| E::from(Error::Argument(format!("mesh: {problem}; lower --resolution"))))?;
    bar.finish_and_clear();
    // Filled nodes alone (space no view saw empty, with nothing dense around) are no surface of
    // the field.
    if writer.vertex_count() == 0 || max_density <= threshold {
        return Err(Error::Argument(format!(
            "no density above --threshold {threshold} in the box ±{} (the largest seen is {max_density:.3}): lower --threshold, or check --bound",
            options.bound
        ))
        .into());
    }
    let comments = vec![
        format!("nerf-rs mesh: marching cubes at density {threshold} on {n}^3 cells over [-{b}, {b}]^3 of the field", b = options.bound),
        match (options.keep_cavities, views.len()) {
            (true, _) => "cavities: kept".to_string(),
            (false, 0) => "cavities: filled".to_string(),
            (false, v) => format!("cavities: filled, and the space none of {v} views saw empty"),
        },
        "coordinates: the scene's own (its placement in the field undone)".to_string(),
    ];
    let (vertices, faces) = writer.finish(&comments)?;
    Ok(MeshReport { vertices, faces, nodes: slice_len * (n + 1), evaluated, filled, views: views.len(), max_density })
}

/// Which of slice `k`'s nodes (densities `values`) are open to the outside by the views: empty,
/// and seen empty by one of `views` or in none of them ([`carve`]). Rows go to the cores.
fn seen_open(lattice: &Lattice, k: usize, values: &[f32], threshold: f32, views: &[DepthView]) -> Vec<bool> {
    let margin = MARGIN_CELLS * lattice.spacing;
    let nodes = lattice.slice_nodes(k);
    let row = lattice.n + 1;
    let rows: Vec<Vec<bool>> = nodes
        .par_chunks(row)
        .zip(values.par_chunks(row))
        .map(|(points, values)| {
            let mut hint = 0;
            points.iter().zip(values).map(|(p, &v)| v <= threshold && sight_of(views, Vec3::from_array(*p), margin, &mut hint) != Sight::Hidden).collect()
        })
        .collect();
    rows.concat()
}

/// Slice `k`'s densities (σ ≥ 0; 0 in the grid's empty cells) and how many nodes the field
/// evaluated.
fn densities<F, E>(field: &RefCell<&mut F>, lattice: &Lattice, occupancy: Option<&OccupancyGrid>, k: usize) -> std::result::Result<(Vec<f32>, usize), E>
where
    F: Field,
    E: From<F::Error>,
{
    let nodes = lattice.slice_nodes(k);
    let wanted: Vec<usize> = match occupancy {
        Some(grid) => grid.occupied_indices(&nodes),
        None => (0..nodes.len()).collect(),
    };
    let mut values = vec![0.0f32; nodes.len()];
    for chunk in wanted.chunks(POINTS_PER_CALL) {
        let points: Vec<[f32; 3]> = chunk.iter().map(|&i| nodes[i]).collect();
        let sigma = field.borrow_mut().evaluate(Stage::Fine, &points, &vec![[0.0, 0.0, 1.0]; points.len()])?.sigma;
        for (&i, s) in chunk.iter().zip(sigma) {
            // `max` also turns NaN into 0.
            values[i] = s.max(0.0);
        }
    }
    Ok((values, wanted.len()))
}

fn progress_bar(show: bool, layers: usize) -> indicatif::ProgressBar {
    let bar = if show { indicatif::ProgressBar::new(layers as u64) } else { indicatif::ProgressBar::hidden() };
    bar.set_style(indicatif::ProgressStyle::with_template("mesh {msg} [{elapsed_precise}<{eta_precise}] {wide_bar} {pos}/{len} slabs").expect("valid template"));
    bar
}

#[cfg(test)]
mod tests;
