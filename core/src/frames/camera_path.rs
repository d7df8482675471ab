//! nerfstudio's camera paths (`camera_path.json`, as its viewer's render panel writes it and
//! `ns-render camera-path` reads it) as views to render.
//!
//! Read: `render_width` and `render_height` (pixels), `seconds` (the video's length:
//! ns-render spreads the cameras over it, so a frame lasts `seconds / cameras`), `camera_type`
//! (missing or `"perspective"`; fisheye, equirectangular and nerfstudio's other types are
//! refused), and per entry of `camera_path[]`: `camera_to_world` (16 numbers, the 4×4 matrix row
//! by row, OpenGL axes; a nested 4×4 list also reads) and `fov` (vertical, in degrees). The rest
//! (`keyframes`, `fps`, `aspect`, `smoothness_value`, …) is ignored as ns-render ignores it: the
//! image size is `render_width × render_height`.
//!
//! The camera is nerfstudio's: focal `(render_height / 2) / tan(fov / 2)` on both axes
//! (`three_js_perspective_camera_focal_length`), principal point at the image centre. Its
//! pixel-centre convention is not nerfstudio's fixed half pixel but the run's or bundle's
//! recorded one ([`PixelCenter`]): the field learnt the rays of that convention, so a path's
//! pose equal to a test pose renders that test view (the Blender scenes train with integer
//! centres, where half-pixel rays shift the image by half a pixel).
//!
//! Poses are in the coordinates of the original capture (the files the run trained on), like
//! the poses of `--split --data`; [`CameraPathFile::frames`] maps them through the run's or
//! bundle's recorded placement. (nerfstudio's own viewer writes paths in its normalised frame:
//! map them back through its `dataparser_transforms.json` first.)
//!
//! Python's `json` writes a NaN as the bare word `NaN`, which is not JSON: such words are read
//! so that the error names the key that holds one.

use super::spec::{FrameSpec, GifSpec};
use crate::camera::{PinholeCamera, PixelCenter, Pose, SceneTransform};
use crate::error::{Error, Result};
use crate::io::limits::{self, MAX_FRAMES, Origin};
use glam::DMat3;
use serde_json::{Map, Value};
use std::borrow::Cow;
use std::path::{Path, PathBuf};

/// File name of a camera path's animation.
pub const CAMERA_PATH_GIF: &str = "camera_path.gif";
/// Largest deviation of a pose's rotation from orthonormal, `max |RᵀR − I|`.
const ROTATION_TOLERANCE: f64 = 1e-3;
/// Shortest GIF frame time (GIF counts in hundredths of a second).
const MIN_DELAY_MS: f64 = 10.0;

/// One camera of the path.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PathCamera {
    /// Camera-to-world, in the capture's coordinates.
    pub pose: Pose,
    /// Vertical field of view in degrees, in (0, 180).
    pub fov_degrees: f64,
}

/// A checked `camera_path.json`.
#[derive(Debug, Clone, PartialEq)]
pub struct CameraPathFile {
    /// The file it came from.
    pub path: PathBuf,
    /// Image width in pixels.
    pub width: u32,
    /// Image height in pixels.
    pub height: u32,
    /// Length of the video in seconds.
    pub seconds: f64,
    /// The cameras, one per frame.
    pub cameras: Vec<PathCamera>,
}

impl CameraPathFile {
    /// Read and check `path`.
    pub fn read(path: &Path) -> Result<Self> {
        Self::parse(path, &limits::read_json_text(path)?)
    }

    /// Check `text`, the content of `path` (which errors name).
    pub fn parse(path: &Path, text: &str) -> Result<Self> {
        let file = Keys { path };
        let value: Value = serde_json::from_str(&quote_non_finite(text)).map_err(|source| Error::Json { path: path.to_path_buf(), source })?;
        let Value::Object(top) = value else {
            return Err(Error::invalid(path, "not a camera path: the top level is not a JSON object"));
        };
        match top.get("camera_type") {
            None => {}
            Some(Value::String(t)) if t.eq_ignore_ascii_case("perspective") => {}
            Some(Value::String(t)) => {
                return Err(file.error(
                    &format!("camera_type {t:?}"),
                    "only perspective cameras are supported (not nerfstudio's fisheye, equirectangular, omnidirectional or vr180)",
                ));
            }
            Some(other) => return Err(file.error("camera_type", format!("{other} is not a camera type"))),
        }
        let width = file.pixels(&top, "render_width")?;
        let height = file.pixels(&top, "render_height")?;
        limits::check_image_size(width, height, Origin::Field(path, "render_width × render_height"))?;
        let seconds = file.number(file.get(&top, "seconds", "seconds")?, "seconds")?;
        if seconds <= 0.0 {
            return Err(file.error("seconds", format!("{seconds} is not a positive duration")));
        }
        let Value::Array(entries) = file.get(&top, "camera_path", "camera_path")? else {
            return Err(file.error("camera_path", "not a list of cameras"));
        };
        if entries.is_empty() {
            return Err(file.error("camera_path", "no cameras"));
        }
        limits::check_count(entries.len(), MAX_FRAMES, "cameras", Origin::Field(path, "camera_path"))?;
        let cameras = entries.iter().enumerate().map(|(k, entry)| file.camera(&format!("camera_path[{k}]"), entry)).collect::<Result<_>>()?;
        Ok(CameraPathFile { path: path.to_path_buf(), width: width as u32, height: height as u32, seconds, cameras })
    }

    /// The views, `frame_00000`, `frame_00001`, …, poses mapped into the field by `placement`,
    /// rays through `pixel_center` (the run's or bundle's training camera's).
    pub fn frames(&self, placement: &SceneTransform, pixel_center: PixelCenter) -> Vec<FrameSpec> {
        self.cameras
            .iter()
            .enumerate()
            .map(|(k, c)| FrameSpec {
                name: format!("frame_{k:05}"),
                camera: perspective_camera(self.width, self.height, c.fov_degrees, pixel_center),
                pose: placement.apply_pose(&c.pose),
                target: None,
            })
            .collect()
    }

    /// `camera_path.gif`, each frame shown `seconds / cameras` (at least 10 ms, GIF's step).
    pub fn gif(&self) -> GifSpec {
        let ms = (1000.0 * self.seconds / self.cameras.len() as f64).round().clamp(MIN_DELAY_MS, u16::MAX as f64);
        GifSpec { file: CAMERA_PATH_GIF.into(), delay_ms: ms as u16 }
    }
}

/// nerfstudio's perspective camera: `width × height`, vertical field of view `fov_degrees`,
/// focal `(height / 2) / tan(fov / 2)` on both axes, principal point at the centre, rays through
/// `pixel_center`. Example: 200 × 100 at 90° → focal 50, principal point (100, 50).
pub fn perspective_camera(width: u32, height: u32, fov_degrees: f64, pixel_center: PixelCenter) -> PinholeCamera {
    let focal = (0.5 * height as f64 / (0.5 * fov_degrees.to_radians()).tan()) as f32;
    PinholeCamera {
        width,
        height,
        fx: focal,
        fy: focal,
        cx: 0.5 * width as f32,
        cy: 0.5 * height as f32,
        pixel_center,
        distortion: None,
    }
}

/// Errors naming `key` of the file.
struct Keys<'a> {
    path: &'a Path,
}

impl Keys<'_> {
    fn error(&self, key: &str, problem: impl std::fmt::Display) -> Error {
        Error::invalid(self.path, format!("{key}: {problem}"))
    }

    fn get<'v>(&self, object: &'v Map<String, Value>, name: &str, key: &str) -> Result<&'v Value> {
        object.get(name).ok_or_else(|| self.error(key, "missing"))
    }

    /// A finite number (a quoted NaN or ±Infinity is named as such).
    fn number(&self, v: &Value, key: &str) -> Result<f64> {
        match v {
            Value::Number(n) => n.as_f64().filter(|x| x.is_finite()).ok_or_else(|| self.error(key, format!("{n} is not a finite number"))),
            Value::String(s) if NON_FINITE.contains(&s.as_str()) => Err(self.error(key, format!("{s} is not a finite number"))),
            other => Err(self.error(key, format!("{other} is not a number"))),
        }
    }

    /// A whole, positive number of pixels.
    fn pixels(&self, object: &Map<String, Value>, key: &str) -> Result<u64> {
        let v = self.number(self.get(object, key, key)?, key)?;
        if v.fract() != 0.0 || v < 1.0 || v > u32::MAX as f64 {
            return Err(self.error(key, format!("{v} is not a positive whole number of pixels")));
        }
        Ok(v as u64)
    }

    fn camera(&self, at: &str, entry: &Value) -> Result<PathCamera> {
        let Value::Object(entry) = entry else {
            return Err(self.error(at, "not an object with camera_to_world and fov"));
        };
        let key = format!("{at}.camera_to_world");
        let m = self.get(entry, "camera_to_world", &key)?;
        let numbers: Vec<&Value> = match m {
            Value::Array(rows) if !rows.is_empty() && rows.iter().all(Value::is_array) => rows.iter().flat_map(|r| r.as_array().into_iter().flatten()).collect(),
            Value::Array(values) => values.iter().collect(),
            other => return Err(self.error(&key, format!("{other} is not a list of 16 numbers"))),
        };
        if numbers.len() != 16 {
            return Err(self.error(&key, format!("{} numbers, expected 16 (the 4×4 matrix, row by row)", numbers.len())));
        }
        let values = numbers.iter().enumerate().map(|(k, v)| self.number(v, &format!("{key}[{k}]"))).collect::<Result<Vec<f64>>>()?;
        let last = &values[12..16];
        if last.iter().zip([0.0, 0.0, 0.0, 1.0]).any(|(a, b)| (a - b).abs() > 1e-6) {
            return Err(self.error(&key, format!("the last row is {last:?}, not [0, 0, 0, 1]")));
        }
        let r = DMat3::from_cols_array(&[values[0], values[4], values[8], values[1], values[5], values[9], values[2], values[6], values[10]]);
        let off = (r.transpose() * r - DMat3::IDENTITY).to_cols_array().iter().fold(0.0f64, |m, v| m.max(v.abs()));
        if off > ROTATION_TOLERANCE {
            return Err(self.error(&key, format!("the rotation is not orthonormal (max |RᵀR − I| = {off:.3}): a camera's axes must have unit length")));
        }
        if r.determinant() < 0.0 {
            return Err(self.error(&key, "the rotation is a reflection (determinant −1)"));
        }
        let rows: [[f32; 4]; 4] = std::array::from_fn(|i| std::array::from_fn(|j| values[4 * i + j] as f32));
        let fov_key = format!("{at}.fov");
        let fov = self.number(self.get(entry, "fov", &fov_key)?, &fov_key)?;
        if !(fov > 0.0 && fov < 180.0) {
            return Err(self.error(&fov_key, format!("{fov} is outside (0, 180) degrees")));
        }
        Ok(PathCamera { pose: Pose::from_rows(rows), fov_degrees: fov })
    }
}

/// The words Python's `json` writes for non-finite floats.
const NON_FINITE: [&str; 3] = ["-Infinity", "Infinity", "NaN"];

/// `text` with the bare words `NaN`, `Infinity` and `-Infinity` outside strings quoted, so that
/// it parses and the key holding one can be named.
fn quote_non_finite(text: &str) -> Cow<'_, str> {
    if !NON_FINITE.iter().any(|w| text.contains(w)) {
        return Cow::Borrowed(text);
    }
    let mut out = String::with_capacity(text.len() + 16);
    let (mut in_string, mut escaped) = (false, false);
    let mut rest = text;
    while let Some(c) = rest.chars().next() {
        if !in_string
            && let Some(word) = NON_FINITE.iter().find(|w| rest.starts_with(**w))
        {
            out.push('"');
            out.push_str(word);
            out.push('"');
            rest = &rest[word.len()..];
            continue;
        }
        if in_string {
            if escaped {
                escaped = false;
            } else if c == '\\' {
                escaped = true;
            } else if c == '"' {
                in_string = false;
            }
        } else if c == '"' {
            in_string = true;
        }
        out.push(c);
        rest = &rest[c.len_utf8()..];
    }
    Cow::Owned(out)
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::{Mat3, Vec3};

    /// A path as nerfstudio's viewer writes it (trimmed): two cameras 4 units from the origin.
    const PATH: &str = r#"{
        "keyframes": [],
        "camera_type": "perspective",
        "render_height": 100,
        "render_width": 200,
        "camera_path": [
            {"camera_to_world": [1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 4, 0, 0, 0, 1], "fov": 90, "aspect": 2},
            {"camera_to_world": [[0, 0, 1, 4], [0, 1, 0, 0], [-1, 0, 0, 0], [0, 0, 0, 1]], "fov": 60, "aspect": 2}
        ],
        "fps": 24,
        "seconds": 0.5,
        "smoothness_value": 0.5,
        "is_cycle": false,
        "crop": null
    }"#;

    fn parse(text: &str) -> Result<CameraPathFile> {
        CameraPathFile::parse(Path::new("path.json"), text)
    }

    /// The error for `PATH` with `edit` applied to its JSON.
    fn error_with(edit: impl FnOnce(&mut Value)) -> String {
        let mut v: Value = serde_json::from_str(PATH).unwrap();
        edit(&mut v);
        parse(&v.to_string()).unwrap_err().to_string()
    }

    #[test]
    fn reads_nerfstudio_cameras() {
        let p = parse(PATH).unwrap();
        assert_eq!((p.width, p.height, p.seconds, p.cameras.len()), (200, 100, 0.5, 2));
        let frames = p.frames(&SceneTransform::identity(), PixelCenter::HalfPixel);
        assert_eq!((frames[0].name.as_str(), frames[1].name.as_str()), ("frame_00000", "frame_00001"));
        // 90°: focal = 50 / tan 45° = 50; 60°: 50 / tan 30° = 86.6025.
        let k = frames[0].camera;
        assert_eq!((k.fx, k.fy, k.cx, k.cy, k.pixel_center), (50.0, 50.0, 100.0, 50.0, PixelCenter::HalfPixel));
        assert!((frames[1].camera.fx - 86.602_54).abs() < 1e-3, "{}", frames[1].camera.fx);
        // The centre ray looks down −z (the second camera's −z is +x): with half-pixel centres
        // it is pixel (99.5, 49.5)'s, with integer centres pixel (100, 50)'s.
        let d = frames[1].pose.ray_direction(&frames[1].camera, 99.5, 49.5);
        assert!((d - Vec3::new(-1.0, 0.0, 0.0)).length() < 1e-6, "{d}");
        let integer = p.frames(&SceneTransform::identity(), PixelCenter::Integer);
        assert_eq!(integer[1].camera, PinholeCamera { pixel_center: PixelCenter::Integer, ..frames[1].camera });
        let d = integer[1].pose.ray_direction(&integer[1].camera, 100.0, 50.0);
        assert!((d - Vec3::new(-1.0, 0.0, 0.0)).length() < 1e-6, "{d}");
        assert_eq!(frames[1].pose.origin(), Vec3::new(4.0, 0.0, 0.0));
        // Two cameras over 0.5 s: 250 ms a frame.
        assert_eq!(p.gif(), GifSpec { file: "camera_path.gif".into(), delay_ms: 250 });
        // Poses go through the placement: scale 0.5 about a shifted origin.
        let t = SceneTransform::new(0.5, Mat3::IDENTITY, Vec3::new(0.0, 0.0, -2.0));
        assert_eq!(p.frames(&t, PixelCenter::Integer)[0].pose.origin(), Vec3::new(0.0, 0.0, 1.0));
        // No camera_type is perspective, as in nerfstudio.
        let mut v: Value = serde_json::from_str(PATH).unwrap();
        v.as_object_mut().unwrap().remove("camera_type");
        assert_eq!(parse(&v.to_string()).unwrap().cameras.len(), 2);
    }

    #[test]
    fn bad_files_name_the_key() {
        let cases: Vec<(Box<dyn FnOnce(&mut Value)>, &str)> = vec![
            (Box::new(|v: &mut Value| drop(v.as_object_mut().unwrap().remove("render_width"))), "path.json: render_width: missing"),
            (Box::new(|v: &mut Value| drop(v.as_object_mut().unwrap().remove("seconds"))), "seconds: missing"),
            (Box::new(|v: &mut Value| drop(v.as_object_mut().unwrap().remove("camera_path"))), "camera_path: missing"),
            (Box::new(|v: &mut Value| drop(v["camera_path"][1].as_object_mut().unwrap().remove("fov"))), "camera_path[1].fov: missing"),
            (Box::new(|v: &mut Value| drop(v["camera_path"][0].as_object_mut().unwrap().remove("camera_to_world"))), "camera_path[0].camera_to_world: missing"),
            (
                Box::new(|v| drop(v["camera_path"][0]["camera_to_world"].as_array_mut().unwrap().pop())),
                "camera_path[0].camera_to_world: 15 numbers, expected 16",
            ),
            (Box::new(|v: &mut Value| v["camera_path"][0]["fov"] = 0.into()), "camera_path[0].fov: 0 is outside (0, 180) degrees"),
            (Box::new(|v: &mut Value| v["camera_path"][1]["fov"] = 180.into()), "camera_path[1].fov: 180 is outside (0, 180) degrees"),
            (Box::new(|v: &mut Value| v["camera_path"][0]["fov"] = "wide".into()), "camera_path[0].fov: \"wide\" is not a number"),
            (Box::new(|v: &mut Value| v["camera_type"] = "fisheye".into()), "camera_type \"fisheye\": only perspective cameras are supported"),
            (Box::new(|v: &mut Value| v["camera_type"] = "equirectangular".into()), "camera_type \"equirectangular\": only perspective"),
            (Box::new(|v: &mut Value| v["render_height"] = 0.into()), "render_height: 0 is not a positive whole number of pixels"),
            (Box::new(|v: &mut Value| v["render_width"] = 12.5.into()), "render_width: 12.5 is not a positive whole number"),
            (Box::new(|v: &mut Value| v["render_width"] = 20_000.into()), "render_width × render_height: 20000×100 pixels: a side is more than the limit"),
            (Box::new(|v: &mut Value| v["seconds"] = (-1).into()), "seconds: -1 is not a positive duration"),
            (Box::new(|v: &mut Value| v["camera_path"] = Value::Array(vec![])), "camera_path: no cameras"),
            (Box::new(|v: &mut Value| v["camera_path"] = 3.into()), "camera_path: not a list of cameras"),
            (Box::new(|v: &mut Value| v["camera_path"][1] = 3.into()), "camera_path[1]: not an object"),
            (Box::new(|v: &mut Value| v["camera_path"][0]["camera_to_world"][15] = 2.into()), "camera_path[0].camera_to_world: the last row is [0.0, 0.0, 0.0, 2.0]"),
            (Box::new(|v: &mut Value| v["camera_path"][0]["camera_to_world"][0] = 2.into()), "camera_path[0].camera_to_world: the rotation is not orthonormal"),
            (Box::new(|v: &mut Value| v["camera_path"][0]["camera_to_world"][0] = (-1).into()), "camera_path[0].camera_to_world: the rotation is a reflection"),
        ];
        for (edit, expected) in cases {
            let err = error_with(edit);
            assert!(err.contains(expected), "expected {expected:?} in {err:?}");
        }
        let too_many = error_with(|v| v["camera_path"] = Value::Array(vec![v["camera_path"][0].clone(); MAX_FRAMES + 1]));
        assert!(too_many.contains("camera_path: 10001 cameras is more than the limit of 10000"), "{too_many}");
        assert!(parse("[1, 2]").unwrap_err().to_string().contains("top level is not a JSON object"));
        assert!(parse("{").unwrap_err().to_string().starts_with("path.json: invalid JSON"));
    }

    #[test]
    fn python_nan_and_infinity_are_named_where_they_are() {
        // As Python's json.dump writes them.
        let nan = PATH.replacen("0, 0, 1, 4, 0, 0, 0, 1]", "0, 0, 1, NaN, 0, 0, 0, 1]", 1);
        let err = parse(&nan).unwrap_err().to_string();
        assert!(err.contains("camera_path[0].camera_to_world[11]: NaN is not a finite number"), "{err}");
        let inf = PATH.replacen("\"fov\": 60", "\"fov\": -Infinity", 1);
        let err = parse(&inf).unwrap_err().to_string();
        assert!(err.contains("camera_path[1].fov: -Infinity is not a finite number"), "{err}");
        // Inside strings the words stay as they are.
        assert_eq!(quote_non_finite(r#"{"a": "NaN \" Infinity", "b": NaN}"#), r#"{"a": "NaN \" Infinity", "b": "NaN"}"#);
        assert!(matches!(quote_non_finite("[1, 2]"), Cow::Borrowed(_)));
    }
}
