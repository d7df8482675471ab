//! The one font of the plots, compiled in (`assets/fonts/`, DejaVu Sans under the Bitstream
//! Vera licence) and registered with plotters' ab_glyph text renderer: no system font is ever
//! looked up, so plots draw the same on a headless machine without fonts.

use crate::error::{Error, Result};
use plotters::style::FontStyle;
use std::sync::OnceLock;

/// DejaVu Sans 2.37 (`assets/fonts/README.md` says where it came from).
const DEJAVU_SANS: &[u8] = include_bytes!("../../assets/fonts/DejaVuSans.ttf");

/// The family names plotters asks for: all of them get the bundled font, so no text style
/// can miss it.
const FAMILIES: [&str; 3] = ["sans-serif", "serif", "monospace"];

/// The family the plots name.
pub const FAMILY: &str = FAMILIES[0];

/// Register the bundled font (once per process; later calls return the first outcome).
pub fn register() -> Result<()> {
    static REGISTERED: OnceLock<std::result::Result<(), String>> = OnceLock::new();
    let outcome = REGISTERED.get_or_init(|| {
        for family in FAMILIES {
            for style in [FontStyle::Normal, FontStyle::Bold] {
                plotters::style::register_font(family, style, DEJAVU_SANS).map_err(|_| "the bundled font does not parse".to_string())?;
            }
        }
        Ok(())
    });
    outcome.clone().map_err(Error::Plot)
}
