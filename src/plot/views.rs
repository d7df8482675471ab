//! PSNR per evaluated view (`nerf eval`'s `psnr_per_view.png`): a dot per view in the order of
//! `metrics.json`, the mean as a dashed line, view names on the ticks.

use crate::error::{Error, Result};
use crate::plot::figure::{CAPTION, Figure, PALETTE, SIZE, drawing_error, style_axes};
use crate::plot::font;
use crate::plot::legend::{self, Sample};
use nerf_core::render::metrics::ImageMetrics;
use plotters::prelude::*;

/// Draw the PSNR of `views`, titled `title` (the run and split). Views with an infinite PSNR (a render equal to its
/// target) cannot be placed and are counted in the title instead; at least one must be finite.
pub fn draw_view_psnr(title: &str, views: &[ImageMetrics]) -> Result<Figure> {
    let finite: Vec<(usize, f64)> = views.iter().enumerate().filter(|(_, m)| m.psnr.is_finite()).map(|(k, m)| (k, m.psnr as f64)).collect();
    if finite.is_empty() {
        return Err(Error::Config(format!("{title}: no view has a finite PSNR to plot")));
    }
    font::register()?;
    let mean = finite.iter().map(|(_, p)| p).sum::<f64>() / finite.len() as f64;
    let (lo, hi) = finite.iter().fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), &(_, p)| (lo.min(p), hi.max(p)));
    let y_range = (lo - 0.5).floor()..(hi + 0.5).ceil();
    let x_range = -0.5..views.len() as f64 - 0.5;
    let skipped = views.len() - finite.len();
    let caption = match skipped {
        0 => format!("{title}: PSNR of {} views", views.len()),
        k => format!("{title}: PSNR of {} views ({k} exact, not shown)", views.len()),
    };
    let colour = PALETTE[0];
    let mean_colour = PALETTE[3];
    let entries = [(Sample::Dot(colour), "PSNR of the view".to_string()), (Sample::Dashed(mean_colour), format!("mean {mean:.2} dB"))];
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
        let points: Vec<(f64, f64)> = finite.iter().map(|&(k, p)| (k as f64, p)).collect();
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
}
