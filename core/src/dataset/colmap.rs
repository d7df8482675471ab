//! COLMAP sparse models (`cameras.bin`/`images.bin` or their `.txt` forms) and their conversion
//! into the instant-ngp/nerfstudio `transforms.json` that [`super::instant_ngp`] reads.
//!
//! # Conventions, written once
//! COLMAP stores, per image, the world-to-camera rotation as a unit quaternion `(w, x, y, z)`
//! and translation `t` in OpenCV camera axes (+x right, +y down, looking along +z). A
//! `transform_matrix` is the OpenGL camera-to-world matrix (+x right, +y up, looking along −z):
//! `c2w = [Rᵀ | −Rᵀt]` with its second and third columns negated. The principal point is in
//! pixel-edge coordinates in both (the centre of the first pixel is at 0.5).
//!
//! The binary reader checks every count against the bytes left, so a truncated or hostile file
//! is an error naming the file and what is wrong, never a huge allocation.

use crate::error::{Error, Result};
use crate::io::limits;
use std::path::{Path, PathBuf};

/// Largest `images.bin` read (its 2-D points dominate: ≈ 24 bytes each).
pub const MAX_MODEL_BYTES: u64 = 1 << 30;
/// Most cameras or images in a model.
pub const MAX_MODEL_ENTRIES: u64 = 1_000_000;

/// A COLMAP camera model, by COLMAP's id and name, with its parameter count.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum CameraModel {
    /// f, cx, cy.
    SimplePinhole,
    /// fx, fy, cx, cy.
    Pinhole,
    /// f, cx, cy, k.
    SimpleRadial,
    /// f, cx, cy, k1, k2.
    Radial,
    /// fx, fy, cx, cy, k1, k2, p1, p2.
    OpenCv,
    /// fx, fy, cx, cy, k1, k2, k3, k4.
    OpenCvFisheye,
    /// Any other COLMAP model (id, parameter count), read but not converted.
    Other(i32, usize),
}

impl CameraModel {
    /// COLMAP's model ids (src/colmap/sensor/models.h) and parameter counts.
    pub fn from_id(id: i32) -> Option<Self> {
        Some(match id {
            0 => CameraModel::SimplePinhole,
            1 => CameraModel::Pinhole,
            2 => CameraModel::SimpleRadial,
            3 => CameraModel::Radial,
            4 => CameraModel::OpenCv,
            5 => CameraModel::OpenCvFisheye,
            6 => CameraModel::Other(6, 12),  // FULL_OPENCV
            7 => CameraModel::Other(7, 5),   // FOV
            8 => CameraModel::Other(8, 4),   // SIMPLE_RADIAL_FISHEYE
            9 => CameraModel::Other(9, 5),   // RADIAL_FISHEYE
            10 => CameraModel::Other(10, 12), // THIN_PRISM_FISHEYE
            _ => return None,
        })
    }

    /// The model named as in `cameras.txt`.
    pub fn from_name(name: &str) -> Option<Self> {
        const NAMES: [&str; 11] = ["SIMPLE_PINHOLE", "PINHOLE", "SIMPLE_RADIAL", "RADIAL", "OPENCV", "OPENCV_FISHEYE", "FULL_OPENCV", "FOV", "SIMPLE_RADIAL_FISHEYE", "RADIAL_FISHEYE", "THIN_PRISM_FISHEYE"];
        NAMES.iter().position(|n| *n == name).and_then(|i| Self::from_id(i as i32))
    }

    /// Parameters this model has.
    pub fn num_params(self) -> usize {
        match self {
            CameraModel::SimplePinhole => 3,
            CameraModel::Pinhole | CameraModel::SimpleRadial => 4,
            CameraModel::Radial => 5,
            CameraModel::OpenCv | CameraModel::OpenCvFisheye => 8,
            CameraModel::Other(_, n) => n,
        }
    }
}

/// One camera of a model.
#[derive(Debug, Clone, PartialEq)]
pub struct ColmapCamera {
    /// COLMAP's id.
    pub id: i64,
    /// The model.
    pub model: CameraModel,
    /// Image size.
    pub width: u64,
    /// Image size.
    pub height: u64,
    /// The model's parameters, in COLMAP's order.
    pub params: Vec<f64>,
}

/// One registered image of a model.
#[derive(Debug, Clone, PartialEq)]
pub struct ColmapImage {
    /// COLMAP's id.
    pub id: i64,
    /// World-to-camera rotation, (w, x, y, z).
    pub qvec: [f64; 4],
    /// World-to-camera translation.
    pub tvec: [f64; 3],
    /// Its camera's id.
    pub camera_id: i64,
    /// The image's path relative to the image folder COLMAP read.
    pub name: String,
}

/// A sparse model: its cameras and registered images.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct ColmapModel {
    /// Cameras.
    pub cameras: Vec<ColmapCamera>,
    /// Registered images.
    pub images: Vec<ColmapImage>,
}

/// Read the model in `dir` (`cameras.bin` + `images.bin`, else `cameras.txt` + `images.txt`).
pub fn read_model(dir: &Path) -> Result<ColmapModel> {
    let (cameras, images) = if dir.join("cameras.bin").is_file() {
        let c = dir.join("cameras.bin");
        let i = dir.join("images.bin");
        (parse_cameras_bin(&c, &limits::read_bounded(&c, MAX_MODEL_BYTES)?)?, parse_images_bin(&i, &limits::read_bounded(&i, MAX_MODEL_BYTES)?)?)
    } else if dir.join("cameras.txt").is_file() {
        let c = dir.join("cameras.txt");
        let i = dir.join("images.txt");
        (parse_cameras_txt(&c, &text(&c)?)?, parse_images_txt(&i, &text(&i)?)?)
    } else {
        return Err(Error::invalid(dir, "not a COLMAP sparse model: no cameras.bin or cameras.txt (COLMAP writes them to <project>/sparse/0)"));
    };
    for image in &images {
        if !cameras.iter().any(|c| c.id == image.camera_id) {
            return Err(Error::invalid(dir, format!("image {:?} uses camera {}, which the model does not have", image.name, image.camera_id)));
        }
    }
    Ok(ColmapModel { cameras, images })
}

fn text(path: &Path) -> Result<String> {
    String::from_utf8(limits::read_bounded(path, MAX_MODEL_BYTES)?).map_err(|_| Error::invalid(path, "not UTF-8 text"))
}

/// A little-endian reader over a file's bytes that names the file when it runs short.
struct Cursor<'a> {
    path: &'a Path,
    bytes: &'a [u8],
    at: usize,
}

impl<'a> Cursor<'a> {
    fn take(&mut self, n: usize, what: &str) -> Result<&'a [u8]> {
        if self.bytes.len() - self.at < n {
            return Err(Error::invalid(self.path, format!("truncated at byte {} (reading {what})", self.at)));
        }
        let out = &self.bytes[self.at..self.at + n];
        self.at += n;
        Ok(out)
    }
    fn u64(&mut self, what: &str) -> Result<u64> {
        Ok(u64::from_le_bytes(self.take(8, what)?.try_into().expect("8 bytes")))
    }
    fn i32(&mut self, what: &str) -> Result<i32> {
        Ok(i32::from_le_bytes(self.take(4, what)?.try_into().expect("4 bytes")))
    }
    fn f64(&mut self, what: &str) -> Result<f64> {
        let v = f64::from_le_bytes(self.take(8, what)?.try_into().expect("8 bytes"));
        if v.is_finite() { Ok(v) } else { Err(Error::invalid(self.path, format!("{what} is not finite at byte {}", self.at - 8))) }
    }
    /// A count of items of at least `item_bytes` each, checked against the bytes left.
    fn count(&mut self, item_bytes: usize, what: &str) -> Result<usize> {
        let n = self.u64(what)?;
        let left = (self.bytes.len() - self.at) as u64;
        if n > MAX_MODEL_ENTRIES || n.saturating_mul(item_bytes as u64) > left {
            return Err(Error::invalid(self.path, format!("{what} = {n} does not fit in the {left} bytes left (truncated or not a COLMAP file)")));
        }
        Ok(n as usize)
    }
    fn done(&self) -> Result<()> {
        if self.at != self.bytes.len() {
            return Err(Error::invalid(self.path, format!("{} unexpected bytes after the last entry", self.bytes.len() - self.at)));
        }
        Ok(())
    }
}

/// `cameras.bin`: u64 count, then per camera i32 id, i32 model, u64 width, u64 height, f64 params.
pub fn parse_cameras_bin(path: &Path, bytes: &[u8]) -> Result<Vec<ColmapCamera>> {
    let mut c = Cursor { path, bytes, at: 0 };
    let n = c.count(24, "the number of cameras")?;
    let mut cameras = Vec::with_capacity(n);
    for _ in 0..n {
        let id = c.i32("a camera id")? as i64;
        let model_id = c.i32("a camera model")?;
        let model = CameraModel::from_id(model_id).ok_or_else(|| Error::invalid(path, format!("camera {id}: unknown model id {model_id}")))?;
        let (width, height) = (c.u64("a width")?, c.u64("a height")?);
        let params = (0..model.num_params()).map(|_| c.f64("a camera parameter")).collect::<Result<Vec<_>>>()?;
        cameras.push(check_camera(path, ColmapCamera { id, model, width, height, params })?);
    }
    c.done()?;
    Ok(cameras)
}

/// `images.bin`: u64 count, then per image i32 id, f64 qvec[4], f64 tvec[3], i32 camera id,
/// a NUL-terminated name, u64 point count and that many (f64 x, f64 y, i64 point id).
pub fn parse_images_bin(path: &Path, bytes: &[u8]) -> Result<Vec<ColmapImage>> {
    let mut c = Cursor { path, bytes, at: 0 };
    let n = c.count(4 + 56 + 4 + 1 + 8, "the number of images")?;
    let mut images = Vec::with_capacity(n);
    for _ in 0..n {
        let id = c.i32("an image id")? as i64;
        let mut qvec = [0.0; 4];
        for v in &mut qvec {
            *v = c.f64("a quaternion")?;
        }
        let mut tvec = [0.0; 3];
        for v in &mut tvec {
            *v = c.f64("a translation")?;
        }
        let camera_id = c.i32("a camera id")? as i64;
        let rest = &bytes[c.at..];
        let len = rest.iter().position(|&b| b == 0).ok_or_else(|| Error::invalid(path, format!("image {id}: its name has no end (truncated)")))?;
        let name = std::str::from_utf8(&rest[..len]).map_err(|_| Error::invalid(path, format!("image {id}: its name is not UTF-8")))?.to_string();
        c.at += len + 1;
        let points = c.count(24, "the number of 2-D points")?;
        c.take(points * 24, "2-D points")?;
        images.push(check_image(path, ColmapImage { id, qvec, tvec, camera_id, name })?);
    }
    c.done()?;
    Ok(images)
}

/// `cameras.txt`: `# comments`, then `CAMERA_ID MODEL WIDTH HEIGHT PARAMS...` per line.
pub fn parse_cameras_txt(path: &Path, text: &str) -> Result<Vec<ColmapCamera>> {
    let mut cameras = Vec::new();
    for (k, line) in text.lines().enumerate().filter(|(_, l)| !l.trim().is_empty() && !l.trim_start().starts_with('#')) {
        let bad = |what: &str| Error::invalid(path, format!("line {}: {what}", k + 1));
        let fields: Vec<&str> = line.split_whitespace().collect();
        if fields.len() < 4 {
            return Err(bad("expected CAMERA_ID MODEL WIDTH HEIGHT PARAMS..."));
        }
        let model = CameraModel::from_name(fields[1]).ok_or_else(|| bad(&format!("unknown camera model {:?}", fields[1])))?;
        let int = |s: &str, what: &str| s.parse::<u64>().map_err(|_| bad(&format!("{what} {s:?} is not a whole number")));
        let params = fields[4..].iter().map(|s| s.parse::<f64>().ok().filter(|v| v.is_finite()).ok_or_else(|| bad(&format!("parameter {s:?} is not a finite number")))).collect::<Result<Vec<_>>>()?;
        if params.len() != model.num_params() {
            return Err(bad(&format!("{} takes {} parameters, the line has {}", fields[1], model.num_params(), params.len())));
        }
        let camera = ColmapCamera { id: int(fields[0], "the camera id")? as i64, model, width: int(fields[2], "the width")?, height: int(fields[3], "the height")?, params };
        cameras.push(check_camera(path, camera)?);
    }
    Ok(cameras)
}

/// `images.txt`: per image a line `IMAGE_ID QW QX QY QZ TX TY TZ CAMERA_ID NAME` and a line of
/// 2-D points (possibly empty).
pub fn parse_images_txt(path: &Path, text: &str) -> Result<Vec<ColmapImage>> {
    let mut images = Vec::new();
    let mut lines = text.lines().enumerate().filter(|(_, l)| !l.trim_start().starts_with('#'));
    while let Some((k, line)) = lines.next() {
        if line.trim().is_empty() {
            continue;
        }
        let bad = |what: &str| Error::invalid(path, format!("line {}: {what}", k + 1));
        let fields: Vec<&str> = line.split_whitespace().collect();
        if fields.len() < 10 {
            return Err(bad("expected IMAGE_ID QW QX QY QZ TX TY TZ CAMERA_ID NAME"));
        }
        let num = |s: &str| s.parse::<f64>().ok().filter(|v| v.is_finite()).ok_or_else(|| bad(&format!("{s:?} is not a finite number")));
        let id = fields[0].parse::<i64>().map_err(|_| bad("the image id is not a whole number"))?;
        let camera_id = fields[8].parse::<i64>().map_err(|_| bad("the camera id is not a whole number"))?;
        let qvec = [num(fields[1])?, num(fields[2])?, num(fields[3])?, num(fields[4])?];
        let tvec = [num(fields[5])?, num(fields[6])?, num(fields[7])?];
        // The name may hold spaces: the rest of the line.
        let name = line.split_whitespace().skip(9).collect::<Vec<_>>().join(" ");
        images.push(check_image(path, ColmapImage { id, qvec, tvec, camera_id, name })?);
        lines.next(); // its 2-D points
    }
    Ok(images)
}

fn check_camera(path: &Path, camera: ColmapCamera) -> Result<ColmapCamera> {
    limits::check_image_size(camera.width, camera.height, limits::Origin::Field(path, "camera width/height"))?;
    if camera.params[0] <= 0.0 {
        return Err(Error::invalid(path, format!("camera {}: focal length {} is not positive", camera.id, camera.params[0])));
    }
    Ok(camera)
}

fn check_image(path: &Path, image: ColmapImage) -> Result<ColmapImage> {
    let norm = image.qvec.iter().map(|v| v * v).sum::<f64>().sqrt();
    if !(norm > 1e-6) {
        return Err(Error::invalid(path, format!("image {:?}: its rotation quaternion is zero", image.name)));
    }
    if image.name.is_empty() || image.name.contains("..") || image.name.starts_with('/') {
        return Err(Error::invalid(path, format!("image {}: name {:?} is not a path inside the image folder", image.id, image.name)));
    }
    Ok(image)
}

/// The OpenGL camera-to-world matrix (3 × 4 rows) of an image (module doc).
pub fn camera_to_world(image: &ColmapImage) -> [[f64; 4]; 3] {
    let n = image.qvec.iter().map(|v| v * v).sum::<f64>().sqrt();
    let [w, x, y, z] = image.qvec.map(|v| v / n);
    // World-to-camera rotation (COLMAP's qvec2rotmat).
    let r = [
        [1.0 - 2.0 * y * y - 2.0 * z * z, 2.0 * x * y - 2.0 * w * z, 2.0 * x * z + 2.0 * w * y],
        [2.0 * x * y + 2.0 * w * z, 1.0 - 2.0 * x * x - 2.0 * z * z, 2.0 * y * z - 2.0 * w * x],
        [2.0 * x * z - 2.0 * w * y, 2.0 * y * z + 2.0 * w * x, 1.0 - 2.0 * x * x - 2.0 * y * y],
    ];
    let t = image.tvec;
    let mut c2w = [[0.0; 4]; 3];
    for i in 0..3 {
        for j in 0..3 {
            // Rᵀ, with the y and z camera axes flipped (OpenCV → OpenGL).
            c2w[i][j] = r[j][i] * if j == 0 { 1.0 } else { -1.0 };
        }
        c2w[i][3] = -(0..3).map(|k| r[k][i] * t[k]).sum::<f64>();
    }
    c2w
}

/// The camera fields of `transforms.json` for a camera, or why it cannot be converted.
pub fn camera_fields(path: &Path, camera: &ColmapCamera) -> Result<serde_json::Map<String, serde_json::Value>> {
    let p = &camera.params;
    let (fx, fy, cx, cy, k1, k2, p1, p2) = match camera.model {
        CameraModel::SimplePinhole => (p[0], p[0], p[1], p[2], 0.0, 0.0, 0.0, 0.0),
        CameraModel::Pinhole => (p[0], p[1], p[2], p[3], 0.0, 0.0, 0.0, 0.0),
        CameraModel::SimpleRadial => (p[0], p[0], p[1], p[2], p[3], 0.0, 0.0, 0.0),
        CameraModel::Radial => (p[0], p[0], p[1], p[2], p[3], p[4], 0.0, 0.0),
        CameraModel::OpenCv => (p[0], p[1], p[2], p[3], p[4], p[5], p[6], p[7]),
        other => {
            return Err(Error::invalid(path, format!("camera {}: model {other:?} cannot be converted yet (SIMPLE_PINHOLE, PINHOLE, SIMPLE_RADIAL, RADIAL or OPENCV)", camera.id)));
        }
    };
    let json = serde_json::json!({
        "camera_model": "OPENCV", "fl_x": fx, "fl_y": fy, "cx": cx, "cy": cy,
        "w": camera.width, "h": camera.height, "k1": k1, "k2": k2, "p1": p1, "p2": p2,
    });
    Ok(json.as_object().expect("an object").clone())
}

/// Where [`transforms_json`] puts the cameras.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Coordinates {
    /// COLMAP's own (arbitrary position, orientation and scale): the loader fits the cameras
    /// into the field as it fits any capture without `aabb_scale`.
    Colmap,
    /// instant-ngp's placement ([`normalise`]), recorded as `applied_transform`, with this
    /// `aabb_scale`.
    InstantNgp {
        /// The scene box's side in instant-ngp's units.
        aabb_scale: u32,
    },
}

/// `transforms.json` of `model` with image paths `<image_prefix>/<name>`: shared intrinsics
/// when the model has one camera, per frame otherwise; frames sorted by name.
pub fn transforms_json(dir: &Path, model: &ColmapModel, image_prefix: &str, coordinates: Coordinates) -> Result<serde_json::Value> {
    let mut out = serde_json::Map::new();
    let shared = model.cameras.len() == 1;
    if shared {
        out.extend(camera_fields(dir, &model.cameras[0])?);
    }
    let mut images: Vec<&ColmapImage> = model.images.iter().collect();
    images.sort_by(|a, b| a.name.cmp(&b.name));
    let mut c2ws: Vec<[[f64; 4]; 3]> = images.iter().map(|i| camera_to_world(i)).collect();
    if let Coordinates::InstantNgp { aabb_scale } = coordinates {
        let applied = normalise(&mut c2ws);
        out.insert("aabb_scale".into(), aabb_scale.into());
        out.insert("applied_transform".into(), serde_json::json!(applied.matrix()));
    }
    let mut frames = Vec::with_capacity(images.len());
    for (image, c2w) in images.into_iter().zip(c2ws) {
        let mut frame = serde_json::Map::new();
        frame.insert("file_path".into(), format!("{image_prefix}/{}", image.name).into());
        let rows: Vec<Vec<f64>> = c2w.iter().map(|r| r.to_vec()).chain([vec![0.0, 0.0, 0.0, 1.0]]).collect();
        frame.insert("transform_matrix".into(), serde_json::json!(rows));
        if !shared {
            let camera = model.cameras.iter().find(|c| c.id == image.camera_id).expect("read_model checks camera ids");
            frame.extend(camera_fields(dir, camera)?);
        }
        frame.insert("colmap_im_id".into(), image.id.into());
        frames.push(serde_json::Value::Object(frame));
    }
    out.insert("frames".into(), frames.into());
    Ok(serde_json::Value::Object(out))
}

/// The models at `dir`: `dir` itself when it is a model, else its subfolders that are (COLMAP's
/// `sparse/` folder holds `0`, `1`, …), else those of `dir/sparse` (a COLMAP project).
pub fn model_dirs(dir: &Path) -> Vec<PathBuf> {
    let is_model = |d: &Path| d.join("cameras.bin").is_file() || d.join("cameras.txt").is_file();
    if is_model(dir) {
        return vec![dir.to_path_buf()];
    }
    let models_in = |d: &Path| {
        let mut found: Vec<PathBuf> = std::fs::read_dir(d).into_iter().flatten().flatten().map(|e| e.path()).filter(|p| is_model(p)).collect();
        found.sort();
        found
    };
    let found = models_in(dir);
    if found.is_empty() { models_in(&dir.join("sparse")) } else { found }
}

mod normalise;
pub use normalise::{MEAN_CAMERA_DISTANCE, Normalisation, normalise};

#[cfg(test)]
mod tests;
