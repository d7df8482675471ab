//! A legend in its own strip under the chart, so it never hides a line: entries in two
//! columns, each a line sample (or a dot) and its text.

use crate::error::Result;
use crate::plot::figure::{TEXT, drawing_error};
use crate::plot::font;
use plotters::coord::Shift;
use plotters::element::DashedPathElement;
use plotters::prelude::*;
use plotters::style::text_anchor::{HPos, Pos, VPos};

/// How an entry's line is drawn.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Sample {
    /// A solid line (val PSNR).
    Solid(RGBColor),
    /// A dashed line (train PSNR, a mean).
    Dashed(RGBColor),
    /// A dot (one value per view).
    Dot(RGBColor),
    /// Nothing: an empty cell, to start the next entry on a new row.
    Blank,
}

/// Height of one legend row, in pixels.
const ROW: u32 = 20;
/// Entries per row.
pub const COLUMNS: usize = 2;
/// Left edge of the first column (lined up with the chart's plot area, after the y labels).
const LEFT: i32 = 70;
/// Width of a sample line.
const SAMPLE: i32 = 24;

/// Height of the strip that holds `entries` entries.
pub fn height(entries: usize) -> u32 {
    entries.div_ceil(COLUMNS) as u32 * ROW + 6
}

/// Draw `entries` (sample, text) into `area`, row by row, [`COLUMNS`] to a row.
pub fn draw(area: &DrawingArea<BitMapBackend<'_>, Shift>, entries: &[(Sample, String)]) -> Result<()> {
    let column_width = (area.dim_in_pixel().0 as i32 - LEFT) / COLUMNS as i32;
    for (k, (sample, text)) in entries.iter().enumerate() {
        let x = LEFT + (k % COLUMNS) as i32 * column_width;
        let y = (k / COLUMNS) as i32 * ROW as i32 + 2;
        let middle = y + ROW as i32 / 2;
        let line = vec![(x, middle), (x + SAMPLE, middle)];
        match *sample {
            Sample::Solid(c) => area.draw(&PathElement::new(line, c.stroke_width(2))),
            Sample::Dashed(c) => area.draw(&DashedPathElement::new(line, 6, 4, c.stroke_width(1))),
            Sample::Dot(c) => area.draw(&Circle::new((x + SAMPLE / 2, middle), 3, c.filled())),
            Sample::Blank => continue,
        }
        .map_err(drawing_error)?;
        let style = TextStyle::from((font::FAMILY, TEXT).into_font()).color(&BLACK).pos(Pos::new(HPos::Left, VPos::Center));
        area.draw(&Text::new(text.clone(), (x + SAMPLE + 8, middle), style)).map_err(drawing_error)?;
    }
    Ok(())
}
