//! PSNR and LPIPS per evaluated view (`nerf eval`'s `psnr_per_view.png` and
//! `lpips_per_view.png`): a dot per view in the order of `metrics.json`, the mean as a dashed
//! line, view names on the ticks.

use crate::error::{Error, Result};
use crate::plot::figure::{CAPTION, Figure, PALETTE, SIZE, drawing_error, style_axes};
use crate::plot::font;
use crate::plot::legend::{self, Sample};
use nerf_core::render::metrics::ImageMetrics;
use plotters::prelude::*;

/// What a per-view plot shows.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ViewMetric {
    /// PSNR in dB (higher is better); views with an infinite PSNR are counted, not placed.
    Psnr,
    /// LPIPS (lower is better); views without one are counted, not placed.
    Lpips,
}

impl ViewMetric {
    fn name(self) -> &'static str {
        match self {
            ViewMetric::Psnr => "PSNR",
            ViewMetric::Lpips => "LPIPS",
        }
    }

    /// The view's value, when it can be placed.
    fn value(self, m: &ImageMetrics) -> Option<f64> {
        match self {
            ViewMetric::Psnr => Some(m.psnr as f64).filter(|p| p.is_finite()),
            ViewMetric::Lpips => m.lpips.map(|l| l as f64).filter(|l| l.is_finite()),
        }
    }

    fn mean_label(self, mean: f64) -> String {
        match self {
            ViewMetric::Psnr => format!("mean {mean:.2} dB"),
            ViewMetric::Lpips => format!("mean {mean:.4}"),
        }
    }

    /// Why views were not placed, for the caption.
    fn unplaced(self) -> &'static str {
        match self {
            ViewMetric::Psnr => "exact",
            ViewMetric::Lpips => "without LPIPS",
        }
    }

    /// The y range around values from `lo` to `hi`: whole dB for PSNR, a margin of a tenth of
    /// the spread for LPIPS.
    fn y_range(self, lo: f64, hi: f64) -> std::ops::Range<f64> {
        match self {
            ViewMetric::Psnr => (lo - 0.5).floor()..(hi + 0.5).ceil(),
            ViewMetric::Lpips => {
                let margin = ((hi - lo) * 0.1).max(0.005);
                (lo - margin).max(0.0)..hi + margin
            }
        }
    }
}

/// Draw the PSNR of `views`, titled `title` (the run and split) ([`draw_view_metric`]).
pub fn draw_view_psnr(title: &str, views: &[ImageMetrics]) -> Result<Figure> {
    draw_view_metric(title, views, ViewMetric::Psnr)
}

/// Draw `metric` of `views`, titled `title` (the run and split). Views whose value cannot be
/// placed (an infinite PSNR: a render equal to its target; no LPIPS) are counted in the title
/// instead; at least one must have a value.
pub fn draw_view_metric(title: &str, views: &[ImageMetrics], metric: ViewMetric) -> Result<Figure> {
    let placed: Vec<(usize, f64)> = views.iter().enumerate().filter_map(|(k, m)| metric.value(m).map(|v| (k, v))).collect();
    let name = metric.name();
    if placed.is_empty() {
        let what = if metric == ViewMetric::Psnr { "a finite PSNR".to_string() } else { format!("an {name}") };
        return Err(Error::Config(format!("{title}: no view has {what} to plot")));
    }
    font::register()?;
    let mean = placed.iter().map(|(_, p)| p).sum::<f64>() / placed.len() as f64;
    let (lo, hi) = placed.iter().fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), &(_, p)| (lo.min(p), hi.max(p)));
    let y_range = metric.y_range(lo, hi);
    let x_range = -0.5..views.len() as f64 - 0.5;
    let caption = match views.len() - placed.len() {
        0 => format!("{title}: {name} of {} views", views.len()),
        k => format!("{title}: {name} of {} views ({k} {}, not shown)", views.len(), metric.unplaced()),
    };
    let colour = PALETTE[0];
    let mean_colour = PALETTE[3];
    let entries = [(Sample::Dot(colour), format!("{name} of the view")), (Sample::Dashed(mean_colour), metric.mean_label(mean))];
    let mut figure = Figure::new(SIZE);
    {
        let root = BitMapBackend::with_buffer(&mut figure.rgb, SIZE).into_drawing_area();
        root.fill(&WHITE).map_err(drawing_error)?;
        let (plot_area, legend_area) = root.split_vertically(SIZE.1 - legend::height(entries.len()));
        let mut chart = ChartBuilder::on(&plot_area)
            .caption(caption, (font::FAMILY, CAPTION))
            .margin(14)
            .x_label_area_size(42)
            .y_label_area_size(56)
            .build_cartesian_2d(x_range.clone(), y_range)
            .map_err(drawing_error)?;
        // A tick names its view when it falls on one.
        let name = |x: &f64| {
            let k = x.round();
            if (x - k).abs() > 1e-6 || k < 0.0 { String::new() } else { views.get(k as usize).map(|m| m.name.clone()).unwrap_or_default() }
        };
        style_axes(&mut chart.configure_mesh()).x_desc("view (in metrics.json order)").x_label_formatter(&name).draw().map_err(drawing_error)?;
        let points: Vec<(f64, f64)> = placed.iter().map(|&(k, p)| (k as f64, p)).collect();
        chart.draw_series(LineSeries::new(points.clone(), colour.mix(0.35).stroke_width(1))).map_err(drawing_error)?;
        chart.draw_series(points.iter().map(|&p| Circle::new(p, 3, colour.filled()))).map_err(drawing_error)?;
        let mean_line = [(x_range.start, mean), (x_range.end, mean)];
        chart.draw_series(DashedLineSeries::new(mean_line, 7, 5, mean_colour.stroke_width(2))).map_err(drawing_error)?;
        legend::draw(&legend_area, &entries)?;
        root.present().map_err(drawing_error)?;
    }
    Ok(figure)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn view(name: &str, psnr: f32) -> ImageMetrics {
        ImageMetrics { name: name.into(), psnr, ssim: 0.9, lpips: None }
    }

    /// The first column whose pixel has `colour`, scanning row `y`.
    fn first_in_row(f: &Figure, y: i32, colour: [u8; 3]) -> Option<i32> {
        (0..f.width as i32).find(|&x| f.pixel(x, y) == Some(colour))
    }

    #[test]
    fn views_are_dots_and_the_mean_a_line() {
        let views = [view("r_0", 20.0), view("r_1", 30.0), view("r_2", f32::INFINITY), view("r_3", 25.0)];
        let f = draw_view_psnr("run", &views).unwrap();
        assert_eq!((f.width, f.height), SIZE);
        let blue = [31, 119, 180];
        let red = [214, 39, 40];
        // The mean of the finite views (25 dB) is a red row: find it, then r_3 (25 dB) sits on
        // it to the right of r_1, whose dot lies higher.
        let mean_row = (0..f.height as i32).find(|&y| (0..f.width as i32).filter(|&x| f.pixel(x, y) == Some(red)).count() > 200);
        let mean_row = mean_row.expect("a dashed mean line across the plot");
        let top_blue_row = (0..f.height as i32).find(|&y| first_in_row(&f, y, blue).is_some()).unwrap();
        assert!(top_blue_row < mean_row - 50, "the 30 dB view ({top_blue_row}) lies well above the mean ({mean_row})");
        let dot_rows: Vec<i32> = (mean_row - 3..=mean_row + 3).filter(|&y| first_in_row(&f, y, blue).is_some()).collect();
        assert!(!dot_rows.is_empty(), "a 25 dB view on the mean line");
        assert!(draw_view_psnr("run", &[view("r_0", f32::INFINITY)]).unwrap_err().to_string().contains("no view has a finite PSNR"));
    }

    /// LPIPS: lower values lower on the plot; views without one are not placed.
    #[test]
    fn lpips_views_are_placed_by_their_value() {
        let with = |name: &str, lpips: Option<f32>| ImageMetrics { lpips, ..view(name, 25.0) };
        let views = [with("r_0", Some(0.30)), with("r_1", Some(0.10)), with("r_2", None)];
        let f = draw_view_metric("run", &views, ViewMetric::Lpips).unwrap();
        let blue = [31, 119, 180];
        // The dots above the legend: r_0 (0.30) left and high, r_1 (0.10) to its right and low.
        let plot_rows = (f.height - legend::height(2)) as i32;
        let dots: Vec<(i32, i32)> = (0..plot_rows).filter_map(|y| first_in_row(&f, y, blue).map(|x| (x, y))).collect();
        let (top, bottom) = (dots.first().unwrap(), dots.last().unwrap());
        assert!(top.0 < bottom.0 && bottom.1 - top.1 > 100, "r_0 at {top:?}, r_1 at {bottom:?}");
        let e = draw_view_metric("run", &[with("r_0", None)], ViewMetric::Lpips).unwrap_err().to_string();
        assert!(e.contains("no view has an LPIPS to plot"), "{e}");
    }
}
