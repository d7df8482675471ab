//! A plot drawn in memory (8-bit RGB), written to disk whole or not at all, and what the plots
//! share: size, colours and the mapping of plotters' errors.

use crate::error::{Error, Result};
use crate::plot::font;
use plotters::chart::MeshStyle;
use plotters::coord::ranged1d::{Ranged, ValueFormatter};
use plotters::prelude::DrawingBackend;
use plotters::style::{RGBColor, TRANSPARENT};
use std::path::Path;

/// Width × height of every plot, in pixels.
pub const SIZE: (u32, u32) = (800, 480);

/// Line colours, one per run (Tableau 10 without its grey, which reads as an axis).
pub const PALETTE: [RGBColor; 9] = [
    RGBColor(31, 119, 180),
    RGBColor(255, 127, 14),
    RGBColor(44, 160, 44),
    RGBColor(214, 39, 40),
    RGBColor(148, 103, 189),
    RGBColor(140, 86, 75),
    RGBColor(227, 119, 194),
    RGBColor(188, 189, 34),
    RGBColor(23, 190, 207),
];

/// Font sizes in pixels: the title, axis descriptions and legend, tick labels. Even sizes:
/// plotters' ab_glyph text puts the baseline at half the size, truncated, so at odd sizes a
/// full stop sits a pixel higher than the digits.
pub const CAPTION: u32 = 20;
/// See [`CAPTION`].
pub const TEXT: u32 = 14;
/// See [`CAPTION`].
pub const TICK: u32 = 12;

/// Grid lines at the labelled ticks (no finer grid).
pub const GRID: RGBColor = RGBColor(225, 225, 225);

/// The axes every plot shares: the bundled font at the tick and description sizes, grid lines
/// at the labelled ticks only, PSNR on the y axis with [`tick_label`]s. The caller adds the x axis.
pub fn style_axes<'m, 'a, 'b, X, Y, DB>(mesh: &'m mut MeshStyle<'a, 'b, X, Y, DB>) -> &'m mut MeshStyle<'a, 'b, X, Y, DB>
where
    X: Ranged<ValueType = f64> + ValueFormatter<f64>,
    Y: Ranged<ValueType = f64> + ValueFormatter<f64>,
    DB: DrawingBackend,
{
    mesh.y_desc("PSNR (dB)")
        .y_label_formatter(&tick_label)
        .label_style((font::FAMILY, TICK))
        .axis_desc_style((font::FAMILY, TEXT))
        .bold_line_style(GRID)
        .light_line_style(TRANSPARENT)
}

/// A tick's value with at most two decimals and no trailing zeros: 10.0 → "10", 2.50 → "2.5".
pub fn tick_label(value: &f64) -> String {
    let text = format!("{value:.2}");
    let text = text.trim_end_matches('0').trim_end_matches('.');
    if text == "-0" { "0".to_string() } else { text.to_string() }
}

/// An RGB image, row-major, 3 bytes per pixel.
#[derive(Debug, Clone, PartialEq)]
pub struct Figure {
    /// Width in pixels.
    pub width: u32,
    /// Height in pixels.
    pub height: u32,
    /// `3·width·height` bytes, RGBRGB…, row by row from the top.
    pub rgb: Vec<u8>,
}

impl Figure {
    /// A black `width × height` image (the plots fill their background first).
    pub fn new((width, height): (u32, u32)) -> Self {
        Figure { width, height, rgb: vec![0; 3 * width as usize * height as usize] }
    }

    /// The colour at column `x`, row `y` (`None` outside the image).
    pub fn pixel(&self, x: i32, y: i32) -> Option<[u8; 3]> {
        if x < 0 || y < 0 || x as u32 >= self.width || y as u32 >= self.height {
            return None;
        }
        let k = 3 * (y as usize * self.width as usize + x as usize);
        Some([self.rgb[k], self.rgb[k + 1], self.rgb[k + 2]])
    }

    /// Write it as a PNG at `path` (through a temporary file and a rename).
    pub fn save(&self, path: &Path) -> Result<()> {
        Ok(nerf_core::io::image::save_png_rgb8(path, self.width, self.height, &self.rgb)?)
    }
}

/// A plotters failure (the data's own problems are reported before drawing).
pub fn drawing_error(e: impl std::fmt::Display) -> Error {
    Error::Plot(e.to_string())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn tick_labels_drop_trailing_zeros() {
        let labels: Vec<String> = [10.0, 2.5, 0.25, 0.125, -0.001, 31.0].iter().map(tick_label).collect();
        // 0.125 rounds to even at two decimals (0.12); −0.001 rounds to −0.00, shown as 0.
        assert_eq!(labels, ["10", "2.5", "0.25", "0.12", "0", "31"]);
    }
}
