//! The sweep plot: delivery ratio against loss (top panel) and mean delay against loss (bottom
//! panel), one line per mode × loss model (solid: i.i.d., dashed: bursty).
//!
//! As in `hetcomm-sim`: `plotters`' bitmap backend renders into an in-memory RGB buffer that
//! the `png` crate encodes, and text uses the DejaVu Sans font embedded in `hetcomm-sim`
//! (registered with plotters' `ab_glyph` font table), so the plot looks the same on every
//! machine.

use std::path::Path;

use plotters::prelude::*;

use crate::reliability::{ExperimentError, Mode};
use crate::sweep::SweepReport;

/// Width of the plot, pixels.
pub const WIDTH: u32 = 1100;
/// Height of the plot (both panels), pixels.
pub const HEIGHT: u32 = 1100;

fn ensure_font() {
    hetcomm_sim::report::plot::ensure_font();
}

pub(crate) fn draw_err<E: std::fmt::Display>(e: E) -> ExperimentError {
    ExperimentError::Plot(e.to_string())
}

fn color(mode: Mode) -> RGBColor {
    match mode {
        Mode::Thesis => RGBColor(214, 39, 40),
        Mode::Acknowledged => RGBColor(31, 119, 180),
    }
}

type Series = (Mode, String, Vec<(f64, f64, f64)>);

/// (mode, loss model, [(loss %, ratio %, mean delay ms)]) in the order first seen.
fn series(report: &SweepReport) -> Vec<Series> {
    let mut out: Vec<Series> = Vec::new();
    for p in &report.points {
        let pt = (p.loss_percent, p.delivery_ratio_percent, p.delay_mean_ms);
        match out
            .iter_mut()
            .find(|(m, l, _)| *m == p.mode && *l == p.loss_model)
        {
            Some(s) => s.2.push(pt),
            None => out.push((p.mode, p.loss_model.clone(), vec![pt])),
        }
    }
    for s in &mut out {
        s.2.sort_by(|a, b| a.0.total_cmp(&b.0));
    }
    out
}

/// Renders the sweep into RGB pixels (`WIDTH × HEIGHT × 3` bytes).
pub fn render_sweep(report: &SweepReport) -> Result<Vec<u8>, ExperimentError> {
    ensure_font();
    let all = series(report);
    if all.is_empty() {
        return Err(ExperimentError::Plot("the sweep has no points".into()));
    }
    let pts = || all.iter().flat_map(|s| s.2.iter());
    let x_max = pts().map(|p| p.0).fold(0.0, f64::max).max(1.0);
    let r_min = pts().map(|p| p.1).fold(100.0, f64::min);
    let r_lo = ((r_min - 2.0) / 5.0).floor() * 5.0;
    let r_lo = r_lo.clamp(0.0, 95.0);
    let d_max = pts().map(|p| p.2).fold(0.0, f64::max).max(0.1) * 1.1;

    let mut pixels = vec![255u8; WIDTH as usize * HEIGHT as usize * 3];
    {
        let root = BitMapBackend::with_buffer(&mut pixels, (WIDTH, HEIGHT)).into_drawing_area();
        root.fill(&WHITE).map_err(draw_err)?;
        let (top, bottom) = root.split_vertically(HEIGHT / 2);
        let panels: [(&DrawingArea<_, _>, &str, &str, f64, f64, usize); 2] = [
            (
                &top,
                "Delivery ratio vs loss on B",
                "messages received (%)",
                r_lo,
                100.5,
                1,
            ),
            (
                &bottom,
                "Mean delay (send → receipt, virtual time) vs loss on B",
                "mean delay (ms)",
                0.0,
                d_max,
                2,
            ),
        ];
        for (area, caption, y_desc, y_lo, y_hi, field) in panels {
            let mut chart = ChartBuilder::on(area)
                .caption(caption, ("sans-serif", 26))
                .margin(18)
                .x_label_area_size(50)
                .y_label_area_size(75)
                .build_cartesian_2d(0.0..x_max * 1.02, y_lo..y_hi)
                .map_err(draw_err)?;
            chart
                .configure_mesh()
                .x_desc("loss on B (%, long-run mean)")
                .y_desc(y_desc)
                .axis_desc_style(("sans-serif", 18))
                .label_style(("sans-serif", 15))
                .light_line_style(RGBColor(235, 235, 235))
                .bold_line_style(RGBColor(200, 200, 200))
                .draw()
                .map_err(draw_err)?;
            for (mode, model, points) in &all {
                let c = color(*mode);
                let xy: Vec<(f64, f64)> = points
                    .iter()
                    .map(|p| (p.0, if field == 1 { p.1 } else { p.2 }))
                    .collect();
                let label = format!("{mode}, {model}");
                let style = c.stroke_width(3);
                let drawn = if model == "bursty" {
                    chart
                        .draw_series(DashedLineSeries::new(xy.clone(), 10, 6, style))
                        .map_err(draw_err)?
                } else {
                    chart
                        .draw_series(LineSeries::new(xy.clone(), style))
                        .map_err(draw_err)?
                };
                let dashed = model == "bursty";
                drawn.label(label).legend(move |(x, y)| {
                    // Two strokes with a gap read as "dashed"; without the gap, a solid line.
                    let (a, b) = if dashed { (9, 15) } else { (12, 12) };
                    EmptyElement::at((x, y))
                        + PathElement::new(vec![(0, 0), (a, 0)], c.stroke_width(3))
                        + PathElement::new(vec![(b, 0), (24, 0)], c.stroke_width(3))
                });
                // Where two series are equal (every message delivered) their lines lie on top
                // of each other: a filled dot and an open triangle keep both visible.
                if dashed {
                    chart
                        .draw_series(
                            xy.iter()
                                .map(|&p| TriangleMarker::new(p, 9, c.stroke_width(2))),
                        )
                        .map_err(draw_err)?;
                } else {
                    chart
                        .draw_series(xy.iter().map(|&p| Circle::new(p, 4, c.filled())))
                        .map_err(draw_err)?;
                }
            }
            chart
                .configure_series_labels()
                .position(if field == 1 {
                    SeriesLabelPosition::LowerLeft
                } else {
                    SeriesLabelPosition::UpperLeft
                })
                .label_font(("sans-serif", 16))
                .background_style(WHITE.mix(0.9))
                .border_style(RGBColor(160, 160, 160))
                .draw()
                .map_err(draw_err)?;
        }
        root.present().map_err(draw_err)?;
    }
    Ok(pixels)
}

/// Renders the sweep and writes it as an 8-bit RGB PNG.
pub fn sweep_png(report: &SweepReport, path: &Path) -> Result<(), ExperimentError> {
    let pixels = render_sweep(report)?;
    write_png(&pixels, WIDTH, HEIGHT, path)
}

/// Encodes `width × height` RGB pixels as an 8-bit PNG and writes it to `path`.
pub fn write_png(
    pixels: &[u8],
    width: u32,
    height: u32,
    path: &Path,
) -> Result<(), ExperimentError> {
    let mut out = Vec::new();
    {
        let mut enc = png::Encoder::new(&mut out, width, height);
        enc.set_color(png::ColorType::Rgb);
        enc.set_depth(png::BitDepth::Eight);
        let mut writer = enc.write_header().map_err(draw_err)?;
        writer.write_image_data(pixels).map_err(draw_err)?;
    }
    std::fs::write(path, out).map_err(ExperimentError::io(format!("writing {}", path.display())))
}
