//! A third field kind plugged in at the seam from this file alone: an analytic ball (σ and
//! colour from the position, nothing to train). It renders through the burn side's renderer,
//! compiles to a bundle through `nerf export`'s path, and `nerf-render` and the numpy consumer
//! render that bundle to the same pixels: no renderer, compiler or bundle reader learns its name.

mod common;

use common::{nerf_render, python, s};
use nerf::config::Preset;
use nerf::field::TrainedField;
use nerf_bundle::proto::{GraphProto, ModelProto};
use nerf_bundle::scene::SceneDescription;
use nerf_core::camera::{ORBIT_FRAMES, Pose};
use nerf_core::field::{Field, FieldOutput, Role, Stage};
use nerf_core::frames::raw::load_npy;
use nerf_core::{Intrinsics, PinholeCamera};
use nerf_export::builder::{Builder, contract_inputs, contract_outputs, model_proto, scene_metadata};
use nerf_export::{CompileField, ExportError, write_bundle};
use std::convert::Infallible;
use std::path::Path;

/// σ = density · sigmoid(sharpness · (radius² − |p|²)), rgb = sigmoid(2p).
#[derive(Debug)]
struct Ball {
    radius: f32,
    density: f32,
    sharpness: f32,
}

fn sigmoid(x: f32) -> f32 {
    1.0 / (1.0 + (-x).exp())
}

impl Field for &Ball {
    type Error = Infallible;
    fn evaluate(&mut self, _: Stage, points: &[[f32; 3]], _: &[[f32; 3]]) -> Result<FieldOutput, Infallible> {
        let sigma = points.iter().map(|p| self.density * sigmoid(self.sharpness * (self.radius * self.radius - (p[0] * p[0] + p[1] * p[1] + p[2] * p[2])))).collect();
        let rgb = points.iter().map(|p| p.map(|v| sigmoid(2.0 * v))).collect();
        Ok(FieldOutput { rgb, sigma })
    }
}

impl TrainedField for Ball {
    fn lowering(&self) -> Box<dyn CompileField + '_> {
        Box::new(self)
    }
    fn bounded(&self) -> Option<f32> {
        None
    }
    fn evaluator<'a>(&'a self, _: &burn::tensor::Device) -> Box<dyn Field<Error = Infallible> + 'a> {
        Box::new(self)
    }
    fn as_any(&self) -> &dyn std::any::Any {
        self
    }
}

impl CompileField for &Ball {
    fn kind(&self) -> &str {
        "ball"
    }
    fn bounded(&self) -> Option<f32> {
        None
    }
    fn compile(&self, scene: &mut SceneDescription, options: &nerf_export::CompileOptions) -> Result<Vec<(Role, ModelProto)>, ExportError> {
        scene.sampling.n_fine = 0;
        let mut g = Builder::default();
        let axes = g.i64_constant("axes", &[1]);
        let squared = g.node("Mul", &["points", "points"], "squared", vec![]);
        let r2 = g.node("ReduceSum", &[&squared, &axes], "r2", vec![nerf_export::builder::int_attribute("keepdims", 1)]);
        let radius2 = g.f32_tensor("radius2", &[1], &[self.radius * self.radius]);
        let sharpness = g.f32_tensor("sharpness", &[1], &[self.sharpness]);
        let density = g.f32_tensor("density", &[1], &[self.density]);
        let inside = g.node("Sub", &[&radius2, &r2], "inside", vec![]);
        let scaled = g.node("Mul", &[&inside, &sharpness], "scaled", vec![]);
        let soft = g.unary("Sigmoid", &scaled, "soft");
        g.node("Mul", &[&soft, &density], "sigma", vec![]);
        let two = g.f32_tensor("two", &[1], &[2.0]);
        let doubled = g.node("Mul", &["points", &two], "doubled", vec![]);
        g.unary("Sigmoid", &doubled, "rgb");
        let graph = GraphProto {
            node: g.nodes,
            name: "field".into(),
            initializer: g.initializers,
            doc_string: "An analytic ball".into(),
            input: contract_inputs(),
            output: contract_outputs("Density, float32 [N, 1]."),
            value_info: vec![],
        };
        Ok(vec![(Role::Field, model_proto(graph, options.opset_or(nerf_export::DEFAULT_OPSET), "A test-only analytic field.", scene_metadata(scene, Role::Field)))])
    }
}

#[test]
fn an_analytic_field_renders_the_same_through_burn_onnxruntime_and_numpy() {
    let ball = Ball { radius: 0.8, density: 30.0, sharpness: 12.0 };
    let field: &dyn TrainedField = &ball;
    let camera = PinholeCamera::from(Intrinsics { width: 24, height: 20, focal: 40.0 });
    let mut config = Preset::Paper.config();
    (config.sampling.n_coarse, config.sampling.n_fine, config.chunk) = (64, 0, 256);
    let pose = Pose::orbit(ORBIT_FRAMES)[0];
    let burn = field.render(&nerf::backend::cpu(), None, &camera, &pose, &config.render_options(), &mut |_, _| {});

    let dir = tempfile::tempdir().unwrap();
    let bundle = dir.path().join("bundle");
    write_bundle(&bundle, &nerf::export::field_bundle(field, &config, &camera, None), &Default::default()).unwrap();
    let scene: serde_json::Value = serde_json::from_slice(&std::fs::read(bundle.join("scene.json")).unwrap()).unwrap();
    assert_eq!((scene["field"].as_str(), scene["bounded"].as_bool()), (Some("ball"), Some(false)));
    assert_eq!(scene["graphs"], serde_json::json!({ "field": "field.onnx" }));

    let out = dir.path().join("ort");
    let (ok, text) = nerf_render(&["--bundle", s(&bundle), "--orbit", "--limit", "1", "--npy", "--out", s(&out)]);
    assert!(ok, "{text}");
    let npy = out.join("frame_000.npy");
    let (_, _, ort) = load_npy(&npy).unwrap();
    let ort_rgb: Vec<[f32; 3]> = ort.chunks_exact(5).map(|p| [p[0], p[1], p[2]]).collect();
    let max = burn.rays.rgb.iter().zip(&ort_rgb).flat_map(|(a, b)| (0..3).map(move |c| (a[c] - b[c]).abs())).fold(0.0f32, f32::max);
    let off_white = burn.rays.rgb.iter().filter(|c| c.iter().any(|&v| v < 0.9)).count();
    println!("burn vs nerf-render: max |Δrgb| {max:.2e}, {off_white} of {} pixels off white", ort_rgb.len());
    assert!(off_white > ort_rgb.len() / 10, "the ball is not in view: parity would mean nothing");
    // 5.9e-5 measured: onnxruntime's Sigmoid against Rust's exp, through 64 samples a ray.
    assert!(max < 2e-4, "burn vs onnxruntime: max |Δrgb| {max}");

    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/python/render_rays.py");
    let out = std::process::Command::new(python()).args([s(&script), s(&bundle), "--npy", s(&npy), "--orbit-pose", "0"]).output().unwrap();
    let text = format!("{}{}", String::from_utf8_lossy(&out.stdout), String::from_utf8_lossy(&out.stderr));
    assert!(out.status.success(), "numpy consumer: {text}");
}
