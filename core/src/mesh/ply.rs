//! Binary PLY meshes: positions, normals and colours per vertex, triangles as index lists.
//!
//! # Layout (`binary_little_endian 1.0`)
//! ```text
//! element vertex V: float x, y, z; float nx, ny, nz; uchar red, green, blue   (27 bytes each)
//! element face F:   list uchar int vertex_indices (always 3)                  (13 bytes each)
//! ```
//! Meshes are streamed: [`PlyWriter`] appends vertices and faces to two temporary siblings of
//! the output as they come, and [`PlyWriter::finish`] writes the header (now that the counts
//! are known) and both parts into the output through a temporary name and a rename. A mesh is
//! on disk whole or not at all; the temporaries go with the writer, whatever happens.

use crate::error::{Error, Result};
use crate::io::atomic::{temp_sibling, write_atomic_with};
use std::fs::File;
use std::io::{BufWriter, Read, Write};
use std::path::{Path, PathBuf};

/// One vertex as written.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PlyVertex {
    /// Position.
    pub position: [f32; 3],
    /// Unit normal.
    pub normal: [f32; 3],
    /// Colour, 0–255.
    pub color: [u8; 3],
}

const VERTEX_BYTES: usize = 27;
const FACE_BYTES: usize = 13;

/// The header for `vertices` and `faces`, with `comments` (one line each).
fn header(vertices: usize, faces: usize, comments: &[String]) -> String {
    let mut h = String::from("ply\nformat binary_little_endian 1.0\n");
    for c in comments {
        h.push_str(&format!("comment {}\n", c.replace('\n', " ")));
    }
    h.push_str(&format!("element vertex {vertices}\n"));
    for p in ["x", "y", "z", "nx", "ny", "nz"] {
        h.push_str(&format!("property float {p}\n"));
    }
    for p in ["red", "green", "blue"] {
        h.push_str(&format!("property uchar {p}\n"));
    }
    h.push_str(&format!("element face {faces}\nproperty list uchar int vertex_indices\nend_header\n"));
    h
}

/// A temporary part of the output, removed when dropped.
struct Part {
    path: PathBuf,
    file: Option<BufWriter<File>>,
}

impl Part {
    fn create(path: PathBuf) -> Result<Self> {
        let file = File::create(&path).map_err(|e| Error::io(&path, e))?;
        Ok(Part { path, file: Some(BufWriter::new(file)) })
    }

    fn write(&mut self, bytes: &[u8]) -> Result<()> {
        let file = self.file.as_mut().expect("open until finished");
        file.write_all(bytes).map_err(|e| Error::io(&self.path, e))
    }

    /// Flush and reopen for reading from the start.
    fn reader(&mut self) -> Result<File> {
        if let Some(mut file) = self.file.take() {
            file.flush().map_err(|e| Error::io(&self.path, e))?;
        }
        File::open(&self.path).map_err(|e| Error::io(&self.path, e))
    }
}

impl Drop for Part {
    fn drop(&mut self) {
        let _ = std::fs::remove_file(&self.path);
    }
}

/// Streams a mesh into a PLY file (see the module docs).
pub struct PlyWriter {
    path: PathBuf,
    vertices: Part,
    faces: Part,
    vertex_count: usize,
    face_count: usize,
}

impl PlyWriter {
    /// Start writing `path`: its directory must exist (the parts are written beside it, so
    /// that a directory that cannot be written fails now, not after the work).
    pub fn create(path: &Path) -> Result<Self> {
        if path.is_dir() {
            return Err(Error::invalid(path, "is a directory; give the mesh file to write (mesh.ply)"));
        }
        let vertices = Part::create(temp_sibling(path, "vertices.tmp"))?;
        let faces = Part::create(temp_sibling(path, "faces.tmp"))?;
        Ok(PlyWriter { path: path.to_path_buf(), vertices, faces, vertex_count: 0, face_count: 0 })
    }

    /// Vertices written so far (the next one's index).
    pub fn vertex_count(&self) -> usize {
        self.vertex_count
    }

    /// Append vertices.
    pub fn push_vertices(&mut self, vertices: &[PlyVertex]) -> Result<()> {
        let mut bytes = Vec::with_capacity(vertices.len() * VERTEX_BYTES);
        for v in vertices {
            for x in v.position.iter().chain(&v.normal) {
                bytes.extend_from_slice(&x.to_le_bytes());
            }
            bytes.extend_from_slice(&v.color);
        }
        self.vertex_count += vertices.len();
        self.vertices.write(&bytes)
    }

    /// Append triangles (indices of vertices pushed before or after; [`finish`](Self::finish)
    /// checks them against the final count).
    pub fn push_faces(&mut self, faces: &[[u32; 3]]) -> Result<()> {
        let mut bytes = Vec::with_capacity(faces.len() * FACE_BYTES);
        for f in faces {
            if f.iter().any(|&v| v > i32::MAX as u32) {
                return Err(Error::invalid(&self.path, format!("vertex index {} does not fit PLY's int", f.iter().max().unwrap())));
            }
            bytes.push(3);
            for v in f {
                bytes.extend_from_slice(&v.to_le_bytes());
            }
        }
        self.face_count += faces.len();
        self.faces.write(&bytes)
    }

    /// Write the file whole (header with `comments`, vertices, faces) and remove the parts:
    /// (vertices, faces).
    pub fn finish(mut self, comments: &[String]) -> Result<(usize, usize)> {
        let head = header(self.vertex_count, self.face_count, comments);
        let mut vertices = self.vertices.reader()?;
        let mut faces = self.faces.reader()?;
        let (vpath, fpath) = (self.vertices.path.clone(), self.faces.path.clone());
        write_atomic_with(&self.path, |out| {
            out.write_all(head.as_bytes())?;
            std::io::copy(&mut vertices, out).map_err(|e| std::io::Error::new(e.kind(), format!("copying {}: {e}", vpath.display())))?;
            std::io::copy(&mut faces, out).map_err(|e| std::io::Error::new(e.kind(), format!("copying {}: {e}", fpath.display())))?;
            Ok(())
        })?;
        Ok((self.vertex_count, self.face_count))
    }
}

/// A mesh read back from a PLY file of the layout above.
#[derive(Debug, Clone, PartialEq)]
pub struct PlyMesh {
    /// The vertices.
    pub vertices: Vec<PlyVertex>,
    /// The triangles.
    pub faces: Vec<[u32; 3]>,
    /// The header's comment lines.
    pub comments: Vec<String>,
}

/// Read a PLY file written in the layout above (the header is parsed, not assumed: another
/// layout is an error naming what differs). Every face must be a triangle of valid indices.
pub fn read_ply(path: &Path) -> Result<PlyMesh> {
    let bad = |problem: String| Error::invalid(path, problem);
    let mut file = File::open(path).map_err(|e| Error::io(path, e))?;
    let mut bytes = Vec::new();
    file.read_to_end(&mut bytes).map_err(|e| Error::io(path, e))?;
    let end = bytes.windows(11).position(|w| w == b"end_header\n").ok_or_else(|| bad("no end_header line: not a PLY file".into()))? + 11;
    let text = std::str::from_utf8(&bytes[..end]).map_err(|_| bad("the header is not text".into()))?;
    let mut lines = text.lines();
    if lines.next() != Some("ply") {
        return Err(bad("does not start with `ply`".into()));
    }
    let (mut vertices, mut faces, mut comments) = (None, None, Vec::new());
    let mut properties: Vec<String> = Vec::new();
    for line in lines {
        let words: Vec<&str> = line.split_whitespace().collect();
        match words.as_slice() {
            ["format", "binary_little_endian", "1.0"] | ["end_header"] => {}
            ["format", other @ ..] => return Err(bad(format!("format {}: only binary_little_endian 1.0 is read", other.join(" ")))),
            ["comment", ..] => comments.push(line.trim_start_matches("comment").trim().to_string()),
            ["element", "vertex", n] => vertices = Some(n.parse::<usize>().map_err(|_| bad(format!("vertex count {n:?}")))?),
            ["element", "face", n] => faces = Some(n.parse::<usize>().map_err(|_| bad(format!("face count {n:?}")))?),
            ["element", other, ..] => return Err(bad(format!("unexpected element {other}"))),
            ["property", rest @ ..] => properties.push(rest.join(" ")),
            _ => return Err(bad(format!("unexpected header line {line:?}"))),
        }
    }
    let want: Vec<String> = header(0, 0, &[]).lines().filter_map(|l| l.strip_prefix("property ")).map(String::from).collect();
    if properties != want {
        return Err(bad(format!("properties {properties:?}, expected {want:?}")));
    }
    let (nv, nf) = (vertices.ok_or_else(|| bad("no vertex element".into()))?, faces.ok_or_else(|| bad("no face element".into()))?);
    let body = &bytes[end..];
    let need = nv.checked_mul(VERTEX_BYTES).and_then(|v| nf.checked_mul(FACE_BYTES).and_then(|f| v.checked_add(f)));
    if need != Some(body.len()) {
        return Err(bad(format!("{} bytes after the header, {nv} vertices and {nf} triangles need {need:?} (truncated?)", body.len())));
    }
    let f32_at = |b: &[u8], at: usize| f32::from_le_bytes([b[at], b[at + 1], b[at + 2], b[at + 3]]);
    let vertices = body[..nv * VERTEX_BYTES]
        .chunks_exact(VERTEX_BYTES)
        .map(|v| PlyVertex { position: [0, 1, 2].map(|k| f32_at(v, 4 * k)), normal: [0, 1, 2].map(|k| f32_at(v, 12 + 4 * k)), color: [v[24], v[25], v[26]] })
        .collect();
    let mut out = Vec::with_capacity(nf);
    for (n, f) in body[nv * VERTEX_BYTES..].chunks_exact(FACE_BYTES).enumerate() {
        if f[0] != 3 {
            return Err(bad(format!("face {n} has {} vertices, not 3", f[0])));
        }
        let tri = [0, 1, 2].map(|k| i32::from_le_bytes([f[1 + 4 * k], f[2 + 4 * k], f[3 + 4 * k], f[4 + 4 * k]]));
        if tri.iter().any(|&v| v < 0 || v as usize >= nv) {
            return Err(bad(format!("face {n} {tri:?} indexes past the {nv} vertices")));
        }
        out.push(tri.map(|v| v as u32));
    }
    Ok(PlyMesh { vertices, faces: out, comments })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn vertex(x: f32) -> PlyVertex {
        PlyVertex { position: [x, 2.0 * x, -x], normal: [0.0, 0.0, 1.0], color: [10, 20, (x * 10.0) as u8] }
    }

    #[test]
    fn a_mesh_streams_out_and_reads_back() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("mesh.ply");
        let mut w = PlyWriter::create(&path).unwrap();
        w.push_vertices(&[vertex(0.0), vertex(1.0)]).unwrap();
        w.push_faces(&[[0, 1, 2]]).unwrap();
        assert!(!path.exists(), "nothing at the final name before finish");
        w.push_vertices(&[vertex(2.0)]).unwrap();
        w.push_faces(&[[2, 1, 0]]).unwrap();
        assert_eq!(w.finish(&["made by a test".into()]).unwrap(), (3, 2));
        let bytes = std::fs::read(&path).unwrap();
        let head = header(3, 2, &["made by a test".into()]);
        assert!(bytes.starts_with(head.as_bytes()));
        assert_eq!(bytes.len(), head.len() + 3 * 27 + 2 * 13);
        // The first vertex's x is 0.0f32, then y 0, z −0: bytes 00 00 00 00, 00 00 00 00, 00 00 00 80.
        assert_eq!(&bytes[head.len()..head.len() + 12], &[0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0x80]);
        let mesh = read_ply(&path).unwrap();
        assert_eq!(mesh.vertices, vec![vertex(0.0), vertex(1.0), vertex(2.0)]);
        assert_eq!(mesh.faces, vec![[0, 1, 2], [2, 1, 0]]);
        assert_eq!(mesh.comments, vec!["made by a test".to_string()]);
        let left: Vec<_> = std::fs::read_dir(dir.path()).unwrap().map(|e| e.unwrap().file_name()).collect();
        assert_eq!(left.len(), 1, "the parts are gone: {left:?}");
    }

    #[test]
    fn an_abandoned_writer_leaves_nothing() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("mesh.ply");
        let mut w = PlyWriter::create(&path).unwrap();
        w.push_vertices(&[vertex(0.0)]).unwrap();
        drop(w);
        assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 0);
        let err = PlyWriter::create(dir.path()).err().unwrap().to_string();
        assert!(err.contains("is a directory"), "{err}");
        let err = PlyWriter::create(&dir.path().join("missing/mesh.ply")).err().unwrap().to_string();
        assert!(err.contains("missing"), "{err}");
    }

    #[test]
    fn bad_files_are_refused_with_the_reason() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("mesh.ply");
        let mut w = PlyWriter::create(&path).unwrap();
        w.push_vertices(&[vertex(0.0), vertex(1.0), vertex(2.0)]).unwrap();
        w.push_faces(&[[0, 1, 2]]).unwrap();
        w.finish(&[]).unwrap();
        let good = std::fs::read(&path).unwrap();
        let err = |bytes: &[u8]| {
            std::fs::write(&path, bytes).unwrap();
            read_ply(&path).unwrap_err().to_string()
        };
        assert!(err(&good[..good.len() - 1]).contains("truncated"));
        let mut out_of_range = good.clone();
        let n = out_of_range.len();
        out_of_range[n - 4..].copy_from_slice(&7i32.to_le_bytes());
        assert!(err(&out_of_range).contains("face 0 [0, 1, 7] indexes past the 3 vertices"));
        assert!(err(b"solid cube\nendsolid\n").contains("no end_header"));
        let ascii = String::from_utf8_lossy(&good).replacen("binary_little_endian", "ascii", 1).into_bytes();
        assert!(err(&ascii).contains("format ascii 1.0"));
    }
}
