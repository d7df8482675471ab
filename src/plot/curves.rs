//! PSNR against minutes of training for one run (`curve.png`, with its steps on a second axis
//! along the top) or several (`nerf plot`): val PSNR solid with a dot per evaluation, train PSNR
//! dashed, one colour per run.
//!
//! Several runs make different numbers of steps per minute, so one step axis cannot serve
//! them: the overlay has none, and each run's legend entry gives its last step and minute.

use crate::error::{Error, Result};
use crate::plot::curve::{CurvePoint, step_at};
use crate::plot::figure::{CAPTION, Figure, PALETTE, SIZE, TEXT, TICK, drawing_error, style_axes, tick_label};
use crate::plot::font;
use crate::plot::legend::{self, Sample};
use plotters::prelude::*;

/// One run's curve and its label.
#[derive(Debug, Clone, PartialEq)]
pub struct RunCurve {
    /// The run's name (its directory's).
    pub label: String,
    /// Its `curve.csv` rows (at least one).
    pub points: Vec<CurvePoint>,
}

/// Most runs on one plot: one colour each.
pub const MAX_RUNS: usize = PALETTE.len();

/// A drawn curve plot and where its val points landed.
#[derive(Debug, Clone, PartialEq)]
pub struct CurvesFigure {
    /// The image.
    pub figure: Figure,
    /// Per run, the pixel (column, row) of each val point, in row order.
    pub val_pixels: Vec<Vec<(i32, i32)>>,
}

/// Dash and gap of the train lines, in pixels.
const DASH: (u32, u32) = (7, 5);

/// Draw `runs` (1 to [`MAX_RUNS`], each with at least one row) at [`SIZE`].
pub fn draw_curves(runs: &[RunCurve]) -> Result<CurvesFigure> {
    if runs.is_empty() || runs.len() > MAX_RUNS {
        return Err(Error::Config(format!("{} runs: a plot takes 1 to {MAX_RUNS} (one colour each)", runs.len())));
    }
    if let Some(empty) = runs.iter().find(|r| r.points.is_empty()) {
        return Err(Error::Config(format!("{}: the curve has no rows to draw", empty.label)));
    }
    font::register()?;
    let (x_range, y_range) = ranges(runs);
    let single = runs.len() == 1;
    let mut entries = Vec::new();
    for (run, colour) in runs.iter().zip(PALETTE) {
        if single {
            entries.push((Sample::Solid(colour), "val PSNR (first val view)".to_string()));
            entries.push((Sample::Dashed(colour), "train PSNR (last 50 batches)".to_string()));
        } else {
            let last = run.points.iter().max_by(|a, b| a.minutes.total_cmp(&b.minutes)).expect("checked non-empty");
            entries.push((Sample::Solid(colour), format!("{}: {} steps in {:.1} min", run.label, last.step, last.minutes)));
        }
    }
    if !single {
        // What the two line styles mean, once for all runs, on a row of their own.
        while entries.len() % legend::COLUMNS != 0 {
            entries.push((Sample::Blank, String::new()));
        }
        entries.push((Sample::Solid(BLACK), "val PSNR (first val view)".to_string()));
        entries.push((Sample::Dashed(BLACK), "train PSNR (last 50 batches)".to_string()));
    }
    let mut figure = Figure::new(SIZE);
    let mut val_pixels = Vec::with_capacity(runs.len());
    {
        let root = BitMapBackend::with_buffer(&mut figure.rgb, SIZE).into_drawing_area();
        root.fill(&WHITE).map_err(drawing_error)?;
        let (plot_area, legend_area) = root.split_vertically(SIZE.1 - legend::height(entries.len()));
        let title = if single { format!("{}: PSNR while training", runs[0].label) } else { "PSNR while training".to_string() };
        let mut builder = ChartBuilder::on(&plot_area);
        builder.caption(title, (font::FAMILY, CAPTION)).margin(14).x_label_area_size(42).y_label_area_size(56);
        if single {
            builder.top_x_label_area_size(42);
        }
        let mut chart = builder
            .build_cartesian_2d(x_range.clone(), y_range.clone())
            .map_err(drawing_error)?
            .set_secondary_coord(x_range, y_range);
        style_axes(&mut chart.configure_mesh()).x_desc("minutes of training").x_label_formatter(&tick_label).draw().map_err(drawing_error)?;
        if single {
            // Steps at the minute ticks, read off the curve (their spacing follows the run's pace).
            let points = &runs[0].points;
            let steps = |m: &f64| step_at(points, *m).map(|s| format!("{s:.0}")).unwrap_or_default();
            chart
                .configure_secondary_axes()
                .x_desc("steps")
                .x_label_formatter(&steps)
                .label_style((font::FAMILY, TICK))
                .axis_desc_style((font::FAMILY, TEXT))
                .draw()
                .map_err(drawing_error)?;
        }
        for (run, colour) in runs.iter().zip(PALETTE) {
            let train: Vec<(f64, f64)> = run.points.iter().map(|p| (p.minutes, p.train_psnr as f64)).collect();
            let val: Vec<(f64, f64)> = run.points.iter().filter_map(|p| p.val_psnr.map(|v| (p.minutes, v as f64))).collect();
            chart.draw_series(DashedLineSeries::new(train, DASH.0, DASH.1, colour.stroke_width(1))).map_err(drawing_error)?;
            chart.draw_series(LineSeries::new(val.clone(), colour.stroke_width(2))).map_err(drawing_error)?;
            chart.draw_series(val.iter().map(|&p| Circle::new(p, 3, colour.filled()))).map_err(drawing_error)?;
            val_pixels.push(val.iter().map(|p| chart.backend_coord(p)).collect());
        }
        legend::draw(&legend_area, &entries)?;
        root.present().map_err(drawing_error)?;
    }
    Ok(CurvesFigure { figure, val_pixels })
}

/// Minutes from 0 to a little past the last row; PSNR over every value, padded to whole dB.
fn ranges(runs: &[RunCurve]) -> (std::ops::Range<f64>, std::ops::Range<f64>) {
    let points = runs.iter().flat_map(|r| &r.points);
    let last_minute = points.clone().map(|p| p.minutes).fold(0.0, f64::max);
    let psnrs = points.flat_map(|p| std::iter::once(p.train_psnr).chain(p.val_psnr)).map(f64::from);
    let (lo, hi) = psnrs.fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), v| (lo.min(v), hi.max(v)));
    // A run stopped within its first minute can have rows at 0.00 minutes only.
    let x_end = if last_minute > 0.0 { last_minute * 1.03 } else { 1.0 };
    (0.0..x_end, (lo - 0.5).floor()..(hi + 0.5).ceil())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn point(step: usize, minutes: f64, train_psnr: f32, val_psnr: Option<f32>) -> CurvePoint {
        CurvePoint { step, minutes, train_psnr, val_psnr }
    }

    /// Val 20, 25, 30 dB at minutes 1, 2, 3; train 35 dB throughout (well away from val).
    fn run(label: &str) -> RunCurve {
        let points = (1..=3).map(|k| point(100 * k, k as f64, 35.0, Some(15.0 + 5.0 * k as f32))).collect();
        RunCurve { label: label.into(), points }
    }

    #[test]
    fn ranges_pad_to_whole_decibels() {
        let (x, y) = ranges(&[run("a")]);
        // Minutes 0 to 3·1.03; PSNR 20..35 padded by 0.5 and rounded out: 19..36.
        assert!((x.end - 3.09).abs() < 1e-12 && x.start == 0.0, "{x:?}");
        assert_eq!(y, 19.0..36.0);
        let at_zero = RunCurve { label: "z".into(), points: vec![point(20, 0.0, 10.2, None)] };
        assert_eq!(ranges(&[at_zero]), (0.0..1.0, 9.0..11.0));
    }

    #[test]
    fn val_points_land_where_their_values_say() {
        let drawn = draw_curves(&[run("a")]).unwrap();
        let f = &drawn.figure;
        assert_eq!((f.width, f.height, f.rgb.len()), (SIZE.0, SIZE.1, 3 * (SIZE.0 * SIZE.1) as usize));
        let px = &drawn.val_pixels[0];
        assert_eq!(px.len(), 3);
        // Equal steps in minutes and in dB are equal steps in pixels: right and up.
        let (dx1, dx2) = (px[1].0 - px[0].0, px[2].0 - px[1].0);
        let (dy1, dy2) = (px[1].1 - px[0].1, px[2].1 - px[1].1);
        assert!(dx1 > 50 && (dx1 - dx2).abs() <= 1, "{px:?}");
        assert!(dy1 < -50 && (dy1 - dy2).abs() <= 1, "{px:?}");
        // Each val point is a dot of the run's colour, inside the image.
        for &(x, y) in px {
            assert_eq!(f.pixel(x, y), Some([31, 119, 180]), "at ({x}, {y})");
        }
        // The background is white and the plot is not blank elsewhere (axes, labels, lines).
        assert_eq!(f.pixel(1, 1), Some([255, 255, 255]));
        let dark = f.rgb.chunks_exact(3).filter(|p| p.iter().all(|&c| c < 100)).count();
        assert!(dark > 2000, "{dark} dark pixels: where are the axes and the text?");
    }

    #[test]
    fn runs_get_their_own_colours_and_limits_hold() {
        let mut b = run("b");
        for p in &mut b.points {
            p.val_psnr = p.val_psnr.map(|v| v - 2.0);
        }
        let drawn = draw_curves(&[run("a"), b]).unwrap();
        let (a0, b0) = (drawn.val_pixels[0][0], drawn.val_pixels[1][0]);
        assert_eq!(a0.0, b0.0, "same minute, same column");
        assert!(b0.1 > a0.1, "2 dB lower is further down");
        assert_eq!(drawn.figure.pixel(b0.0, b0.1), Some([255, 127, 14]));
        assert!(draw_curves(&[]).is_err());
        let many: Vec<RunCurve> = (0..MAX_RUNS + 1).map(|k| run(&k.to_string())).collect();
        assert!(draw_curves(&many).unwrap_err().to_string().contains("1 to 9"));
        let empty = RunCurve { label: "fresh".into(), points: vec![] };
        assert_eq!(draw_curves(&[empty]).unwrap_err().to_string(), "fresh: the curve has no rows to draw");
    }
}
