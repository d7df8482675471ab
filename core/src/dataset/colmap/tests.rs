use super::*;

/// `cameras.bin` and `images.bin` bytes as COLMAP writes them.
fn cameras_bin(cameras: &[(i32, i32, u64, u64, &[f64])]) -> Vec<u8> {
    let mut b = (cameras.len() as u64).to_le_bytes().to_vec();
    for (id, model, w, h, params) in cameras {
        b.extend(id.to_le_bytes());
        b.extend(model.to_le_bytes());
        b.extend(w.to_le_bytes());
        b.extend(h.to_le_bytes());
        params.iter().for_each(|p| b.extend(p.to_le_bytes()));
    }
    b
}

fn images_bin(images: &[(i32, [f64; 4], [f64; 3], i32, &str, usize)]) -> Vec<u8> {
    let mut b = (images.len() as u64).to_le_bytes().to_vec();
    for (id, q, t, camera, name, points) in images {
        b.extend(id.to_le_bytes());
        q.iter().chain(t).for_each(|v| b.extend(v.to_le_bytes()));
        b.extend(camera.to_le_bytes());
        b.extend(name.as_bytes());
        b.push(0);
        b.extend((*points as u64).to_le_bytes());
        for k in 0..*points {
            b.extend((k as f64).to_le_bytes());
            b.extend(2.0f64.to_le_bytes());
            b.extend((-1i64).to_le_bytes());
        }
    }
    b
}

fn close(a: [[f64; 4]; 3], b: [[f64; 4]; 3]) {
    for (ra, rb) in a.iter().zip(&b) {
        for (x, y) in ra.iter().zip(rb) {
            assert!((x - y).abs() < 1e-12, "{a:?} vs {b:?}");
        }
    }
}

#[test]
fn camera_to_world_follows_the_written_conventions_on_hand_values() {
    // Identity rotation, t = (1, 2, 3): the centre is −t; OpenGL flips the y and z axes.
    let image = |qvec, tvec| ColmapImage { id: 1, qvec, tvec, camera_id: 1, name: "a.png".into() };
    close(camera_to_world(&image([1.0, 0.0, 0.0, 0.0], [1.0, 2.0, 3.0])), [[1.0, 0.0, 0.0, -1.0], [0.0, -1.0, 0.0, -2.0], [0.0, 0.0, -1.0, -3.0]]);
    // 90° about z (w = cos 45°, z = sin 45°): R = [[0, −1, 0], [1, 0, 0], [0, 0, 1]], so
    // Rᵀ = [[0, 1, 0], [−1, 0, 0], [0, 0, 1]]; t = (1, 0, 0): centre −Rᵀt = (0, 1, 0).
    // A quaternion given unnormalised (×2) means the same rotation.
    let h = std::f64::consts::FRAC_1_SQRT_2 * 2.0;
    close(camera_to_world(&image([h, 0.0, 0.0, h], [1.0, 0.0, 0.0])), [[0.0, -1.0, 0.0, 0.0], [-1.0, 0.0, 0.0, 1.0], [0.0, 0.0, -1.0, 0.0]]);
}

#[test]
fn binary_and_text_models_read_the_same_and_convert_to_transforms() {
    let dir = tempfile::tempdir().unwrap();
    let bin = dir.path().join("bin");
    std::fs::create_dir_all(&bin).unwrap();
    std::fs::write(bin.join("cameras.bin"), cameras_bin(&[(1, 4, 384, 216, &[275.0, 274.5, 192.0, 108.0, 0.05, -0.01, 0.001, 0.002])])).unwrap();
    let q = [0.9, 0.1, -0.3, 0.2];
    std::fs::write(bin.join("images.bin"), images_bin(&[(2, q, [0.5, -1.0, 2.0], 1, "b.jpg", 3), (1, [1.0, 0.0, 0.0, 0.0], [0.0; 3], 1, "a b.jpg", 0)])).unwrap();
    let txt = dir.path().join("txt");
    std::fs::create_dir_all(&txt).unwrap();
    std::fs::write(txt.join("cameras.txt"), "# Camera list\n1 OPENCV 384 216 275 274.5 192 108 0.05 -0.01 0.001 0.002\n").unwrap();
    std::fs::write(txt.join("images.txt"), "# Image list\n2 0.9 0.1 -0.3 0.2 0.5 -1 2 1 b.jpg\n0 1 -1 1 2 -1 2 2 -1\n1 1 0 0 0 0 0 0 1 a b.jpg\n\n").unwrap();
    let a = read_model(&bin).unwrap();
    let b = read_model(&txt).unwrap();
    assert_eq!(a, b);
    assert_eq!(a.cameras[0].model, CameraModel::OpenCv);
    let json = transforms_json(&bin, &a, "images", Coordinates::Colmap).unwrap();
    assert_eq!((json["fl_x"].as_f64(), json["cy"].as_f64(), json["k1"].as_f64(), json["p2"].as_f64()), (Some(275.0), Some(108.0), Some(0.05), Some(0.002)));
    assert_eq!((json["w"].as_u64(), json["camera_model"].as_str()), (Some(384), Some("OPENCV")));
    let frames = json["frames"].as_array().unwrap();
    assert_eq!(frames[0]["file_path"], "images/a b.jpg", "sorted by name, spaces kept");
    assert_eq!(frames[1]["transform_matrix"][3], serde_json::json!([0.0, 0.0, 0.0, 1.0]));
    let m = camera_to_world(&a.images[0]);
    assert_eq!(frames[1]["transform_matrix"][1][3].as_f64(), Some(m[1][3]));
    // The converted file is read by our instant-ngp loader's checks (shared OPENCV camera).
    assert!(model_dirs(&bin) == vec![bin.clone()]);
}

#[test]
fn bad_models_are_refused_by_name() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("cameras.bin");
    let good = cameras_bin(&[(1, 1, 100, 80, &[90.0, 91.0, 50.0, 40.0])]);
    let err = |bytes: &[u8]| parse_cameras_bin(&path, bytes).unwrap_err().to_string();
    assert!(err(&good[..good.len() - 3]).contains("truncated"), "{}", err(&good[..good.len() - 3]));
    let mut huge = good.clone();
    huge[..8].copy_from_slice(&u64::MAX.to_le_bytes());
    assert!(err(&huge).contains("does not fit"), "{}", err(&huge));
    let mut extra = good.clone();
    extra.push(7);
    assert!(err(&extra).contains("unexpected bytes"));
    assert!(err(&cameras_bin(&[(1, 42, 100, 80, &[])])).contains("unknown model id 42"));
    assert!(err(&cameras_bin(&[(1, 1, 100, 80, &[f64::NAN, 1.0, 1.0, 1.0])])).contains("not finite"));
    assert!(err(&cameras_bin(&[(1, 1, 100, 80, &[-1.0, 1.0, 1.0, 1.0])])).contains("not positive"));
    assert!(err(&cameras_bin(&[(1, 1, 0, 80, &[1.0, 1.0, 1.0, 1.0])])).contains("cameras.bin"));

    let ipath = dir.path().join("images.bin");
    let ierr = |bytes: &[u8]| parse_images_bin(&ipath, bytes).unwrap_err().to_string();
    let image = images_bin(&[(1, [1.0, 0.0, 0.0, 0.0], [0.0; 3], 1, "a.png", 2)]);
    assert!(ierr(&image[..image.len() - 1]).contains("truncated"));
    // Cut inside a long name (past the smallest size an image can have): its NUL is missing.
    let long = images_bin(&[(1, [1.0, 0.0, 0.0, 0.0], [0.0; 3], 1, "a_rather_long_name.png", 0)]);
    let header = 8 + 4 + 56 + 4;
    assert!(ierr(&long[..header + 15]).contains("no end"), "{}", ierr(&long[..header + 15]));
    assert!(ierr(&images_bin(&[(1, [0.0; 4], [0.0; 3], 1, "a.png", 0)])).contains("quaternion is zero"));
    assert!(ierr(&images_bin(&[(1, [1.0, 0.0, 0.0, 0.0], [0.0; 3], 1, "../../etc/passwd", 0)])).contains("not a path inside"));

    let tpath = dir.path().join("cameras.txt");
    let terr = parse_cameras_txt(&tpath, "1 PINHOLE 100 80 90 91 50\n").unwrap_err().to_string();
    assert!(terr.contains("line 1") && terr.contains("4 parameters"), "{terr}");
    assert!(parse_cameras_txt(&tpath, "1 MAGIC 100 80 1\n").unwrap_err().to_string().contains("unknown camera model"));

    // Fisheye cameras are read, not converted (our loader takes OPENCV and PINHOLE).
    let fisheye = ColmapCamera { id: 3, model: CameraModel::OpenCvFisheye, width: 10, height: 10, params: vec![5.0; 8] };
    assert!(camera_fields(&path, &fisheye).unwrap_err().to_string().contains("cannot be converted"));
    // A model whose images name a camera it lacks, and a folder that is no model.
    let m = dir.path().join("m");
    std::fs::create_dir_all(&m).unwrap();
    std::fs::write(m.join("cameras.bin"), &good).unwrap();
    std::fs::write(m.join("images.bin"), images_bin(&[(1, [1.0, 0.0, 0.0, 0.0], [0.0; 3], 9, "a.png", 0)])).unwrap();
    assert!(read_model(&m).unwrap_err().to_string().contains("camera 9"));
    assert!(read_model(dir.path()).unwrap_err().to_string().contains("not a COLMAP sparse model"));
}
