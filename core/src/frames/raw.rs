//! A frame's exact values (`--npy`): `<name>.npy`, a little-endian float32 `[H, W, 5]` array
//! of r, g, b, depth, acc per pixel (the PNGs are 8-bit), written by the frame writer and read
//! back by comparisons between renderers.

use crate::error::{Error, Result};
use crate::io::atomic::write_atomic;
use crate::io::npy::read_npy;
use crate::render::RenderedImage;
use std::path::Path;

/// `[H, W, 5]` little-endian float32 `.npy` (format 1.0) of r, g, b, depth, acc per pixel.
pub fn npy_bytes(image: &RenderedImage) -> Vec<u8> {
    let r = &image.rays;
    let mut header = format!("{{'descr': '<f4', 'fortran_order': False, 'shape': ({}, {}, 5), }}", image.height, image.width);
    // Magic (6) + version (2) + length (2) + header + '\n' is a multiple of 64.
    while (10 + header.len() + 1) % 64 != 0 {
        header.push(' ');
    }
    header.push('\n');
    let mut bytes = Vec::with_capacity(10 + header.len() + r.rgb.len() * 20);
    bytes.extend_from_slice(b"\x93NUMPY\x01\x00");
    bytes.extend_from_slice(&(header.len() as u16).to_le_bytes());
    bytes.extend_from_slice(header.as_bytes());
    for ((c, d), a) in r.rgb.iter().zip(&r.depth).zip(&r.acc) {
        for v in [c[0], c[1], c[2], *d, *a] {
            bytes.extend_from_slice(&v.to_le_bytes());
        }
    }
    bytes
}

/// Write [`npy_bytes`] atomically.
pub fn save_npy(path: &Path, image: &RenderedImage) -> Result<()> {
    write_atomic(path, &npy_bytes(image))
}

/// Read back the `[H, W, 5]` float32 arrays [`save_npy`] writes: (height, width, values).
pub fn load_npy(path: &Path) -> Result<(usize, usize, Vec<f32>)> {
    let array = read_npy(path)?;
    let [h, w, 5] = array.shape[..] else {
        return Err(Error::invalid(path, format!("shape {:?}: not the [H, W, 5] of a rendered frame", array.shape)));
    };
    // float32 files widen to f64 exactly and narrow back exactly.
    Ok((h, w, array.data.iter().map(|&v| v as f32).collect()))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::frames::write::tests::image;

    #[test]
    fn npy_round_trip_keeps_layout_and_values() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("x.npy");
        let image = image();
        save_npy(&path, &image).unwrap();
        let bytes = std::fs::read(&path).unwrap();
        assert_eq!((10 + u16::from_le_bytes([bytes[8], bytes[9]]) as usize) % 64, 0, "data is 64-byte aligned");
        let (h, w, v) = load_npy(&path).unwrap();
        assert_eq!((h, w, v.len()), (2, 3, 30));
        // Pixel (row 1, column 2) = index 5: r = 0.5, depth = 7, acc = 0.25.
        assert_eq!(&v[25..30], &[0.5, 0.5, 1.0, 7.0, 0.25]);
        std::fs::write(&path, &bytes[..bytes.len() - 4]).unwrap();
        let err = load_npy(&path).unwrap_err().to_string();
        assert!(err.contains("x.npy") && err.contains("truncated"), "{err}");
    }
}
