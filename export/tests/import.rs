//! The nerf-pytorch importer on checkpoints nerf-pytorch wrote (`tests/fixtures/nerf-pytorch/`
//! at the repository root): both `torch.save` formats read, networks mapped, and the bundle
//! description taken from args.txt and the dataset.

use nerf_core::field::PlainField;
use nerf_core::field::mlp::PlainNetwork;
use nerf_export::field::mlp::import::{NerfPytorchImport, import_nerf_pytorch};
use std::path::{Path, PathBuf};

fn fixture(path: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../tests/fixtures/nerf-pytorch").join(path)
}

/// The coarse and fine networks of an imported field.
fn networks(field: &PlainField) -> (&PlainNetwork, Option<&PlainNetwork>) {
    match field {
        PlainField::Mlp(mlp) => (&mlp.coarse, mlp.fine.as_ref()),
        other => panic!("nerf-pytorch imports NeRF MLPs, got {:?}", other.kind()),
    }
}

fn lego() -> PathBuf {
    let lego = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../shared/data/nerf_synthetic/lego");
    assert!(lego.join("transforms_test.json").is_file(), "{} is missing (CI provides ../shared)", lego.display());
    lego
}

#[test]
fn legacy_coarse_only_checkpoint_without_viewdirs() {
    let opts = NerfPytorchImport { checkpoint: fixture("coarse-only/000000.tar"), args: None, data: Some(lego()) };
    let imported = import_nerf_pytorch(&opts).unwrap();
    assert_eq!(imported.args_file, fixture("coarse-only/args.txt"), "args.txt beside the checkpoint");
    let b = &imported.bundle;
    let (coarse, fine) = networks(&b.field);
    assert!(fine.is_none());
    let spec = &coarse.spec;
    assert_eq!((spec.depth, spec.width, spec.use_viewdirs, spec.position_encoding.n_frequencies), (2, 32, false, 6));
    assert!(spec.skips.is_empty());
    assert_eq!(coarse.layers.last().unwrap().name, "output");
    let s = &b.scene.sampling;
    assert_eq!((s.near, s.far, s.n_coarse, s.n_fine, s.lindisp), (2.0, 6.0, 24, 0, false));
    assert!(b.scene.white_background);
    // The shared lego images are 400×400; lego's 200 test poses.
    assert_eq!((b.scene.camera.camera.width, b.scene.camera.camera.height), (400, 400));
    assert_eq!(b.scene.poses.test.len(), 200);
    assert_eq!(b.scene.poses.test[0].name, "r_0");
}

#[test]
fn trained_zip_checkpoint_with_differing_coarse_and_fine_networks() {
    let opts = NerfPytorchImport { checkpoint: fixture("trained/001000.tar"), args: None, data: Some(lego()) };
    let b = import_nerf_pytorch(&opts).unwrap().bundle;
    let (coarse, fine) = networks(&b.field);
    let fine = fine.unwrap();
    assert_eq!((coarse.spec.depth, coarse.spec.width, coarse.spec.skips.clone()), (4, 64, vec![]));
    assert_eq!((fine.spec.depth, fine.spec.width, fine.spec.skips.clone()), (6, 64, vec![4]));
    assert!(fine.spec.use_viewdirs);
    assert_eq!((b.scene.sampling.n_coarse, b.scene.sampling.n_fine), (32, 32));
}
