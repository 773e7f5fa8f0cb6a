//! One plot per pair: the histogram of its delays (top) and their CDF (bottom), one-way in
//! blue, round trip in orange. Rendered like the sweep plot (`crate::plot`): plotters' bitmap
//! backend into memory, encoded by `png`, text in the font embedded in `hetcomm-sim`.

use std::path::Path;

use plotters::prelude::*;

use super::{Direction, ExperimentError, LatencyReport, PairReport};
use crate::plot::draw_err;

/// Width of a pair's plot, pixels.
pub const WIDTH: u32 = 1000;
/// Height of a pair's plot (both panels), pixels.
pub const HEIGHT: u32 = 900;
/// Bins of the histogram.
pub const BINS: usize = 60;

fn color(d: Direction) -> RGBColor {
    match d {
        Direction::OneWay => RGBColor(31, 119, 180),
        Direction::RoundTrip => RGBColor(255, 127, 14),
    }
}

/// The plot's file name: `<from>-<to>.png`, with anything but letters, digits, `-` and `_`
/// replaced by `_`.
pub fn file_name(pair: &PairReport) -> String {
    let clean = |s: &str| -> String {
        s.chars()
            .map(|c| {
                if c.is_ascii_alphanumeric() || c == '-' || c == '_' {
                    c
                } else {
                    '_'
                }
            })
            .collect()
    };
    format!("{}-{}.png", clean(&pair.from), clean(&pair.to))
}

/// The pair's delays, µs, sorted, per direction (one-way first).
fn delays(report: &LatencyReport, pair: &PairReport) -> Vec<(Direction, Vec<f64>)> {
    [Direction::OneWay, Direction::RoundTrip]
        .into_iter()
        .map(|d| {
            let mut v: Vec<f64> = report
                .samples
                .iter()
                .filter(|s| s.from == pair.from && s.to == pair.to && s.direction == d)
                .map(|s| s.delay_us)
                .collect();
            v.sort_by(f64::total_cmp);
            (d, v)
        })
        .filter(|(_, v)| !v.is_empty())
        .collect()
}

/// Renders the plot of `pair` into RGB pixels (`WIDTH × HEIGHT × 3` bytes).
pub fn render_pair(report: &LatencyReport, pair: &PairReport) -> Result<Vec<u8>, ExperimentError> {
    hetcomm_sim::report::plot::ensure_font();
    let series = delays(report, pair);
    let all = || series.iter().flat_map(|(_, v)| v.iter().copied());
    let lo = all().fold(f64::INFINITY, f64::min);
    let max = all().fold(0.0, f64::max);
    // The histogram spans the smallest sample to the largest p99 (a real-time tail of a few
    // slow samples would squash the rest into one bin); what lies above is counted in the
    // last bin. The CDF shows every sample, on a logarithmic axis.
    let p99 = series
        .iter()
        .map(|(_, v)| v[((0.99 * v.len() as f64).ceil() as usize).clamp(1, v.len()) - 1])
        .fold(0.0, f64::max);
    let (lo, hi) = if series.is_empty() {
        (0.0, 1.0)
    } else if p99 - lo < 1e-9 {
        (lo - 0.5, p99 + 0.5)
    } else {
        let pad = (p99 - lo) * 0.03;
        (lo - pad, p99 + pad)
    };
    let clipped = max > hi;
    let (cdf_lo, cdf_hi) = if series.is_empty() {
        (1.0, 10.0)
    } else {
        let a = (all().fold(f64::INFINITY, f64::min) * 0.9).max(0.1);
        (a, (max * 1.1).max(a * 10.0))
    };
    let width = (hi - lo) / BINS as f64;
    let histograms: Vec<(Direction, Vec<u64>)> = series
        .iter()
        .map(|(d, v)| {
            let mut bins = vec![0u64; BINS];
            for &x in v {
                let b = (((x - lo) / width) as usize).min(BINS - 1);
                bins[b] += 1;
            }
            (*d, bins)
        })
        .collect();
    let peak = histograms
        .iter()
        .flat_map(|(_, b)| b.iter().copied())
        .max()
        .unwrap_or(1)
        .max(1);

    let mut pixels = vec![255u8; WIDTH as usize * HEIGHT as usize * 3];
    {
        let root = BitMapBackend::with_buffer(&mut pixels, (WIDTH, HEIGHT)).into_drawing_area();
        root.fill(&WHITE).map_err(draw_err)?;
        let (top, bottom) = root.split_vertically(HEIGHT / 2);
        let title = format!(
            "{} → {} over {} ({} time), {} B, {} msg/s",
            pair.from,
            pair.to,
            pair.transport,
            pair.clock.name(),
            report.size_bytes,
            report.rate_hz
        );
        let caption = if clipped {
            format!("Delay histogram (to p99; above it in the last bin): {title}")
        } else {
            format!("Delay histogram: {title}")
        };
        let mut hist = ChartBuilder::on(&top)
            .caption(caption, ("sans-serif", 18))
            .margin(15)
            .x_label_area_size(45)
            .y_label_area_size(70)
            .build_cartesian_2d(lo..hi, 0.0..peak as f64 * 1.08)
            .map_err(draw_err)?;
        hist.configure_mesh()
            .x_desc("delay (µs)")
            .y_desc("samples per bin")
            .x_label_formatter(&|x| format!("{x:.0}"))
            .y_label_formatter(&|y| format!("{y:.0}"))
            .axis_desc_style(("sans-serif", 16))
            .label_style(("sans-serif", 13))
            .light_line_style(RGBColor(235, 235, 235))
            .draw()
            .map_err(draw_err)?;
        for (d, bins) in &histograms {
            let c = color(*d);
            hist.draw_series(
                bins.iter()
                    .enumerate()
                    .filter(|(_, &n)| n > 0)
                    .map(|(i, &n)| {
                        let x0 = lo + i as f64 * width;
                        Rectangle::new([(x0, 0.0), (x0 + width, n as f64)], c.mix(0.55).filled())
                    }),
            )
            .map_err(draw_err)?
            .label(d.name())
            .legend(move |(x, y)| Rectangle::new([(x, y - 6), (x + 14, y + 6)], c.filled()));
        }
        hist.configure_series_labels()
            .position(SeriesLabelPosition::UpperRight)
            .label_font(("sans-serif", 15))
            .background_style(WHITE.mix(0.9))
            .border_style(RGBColor(160, 160, 160))
            .draw()
            .map_err(draw_err)?;

        let mut cdf = ChartBuilder::on(&bottom)
            .caption(
                "Cumulative distribution (every sample, log scale)",
                ("sans-serif", 20),
            )
            .margin(15)
            .x_label_area_size(45)
            .y_label_area_size(70)
            .build_cartesian_2d((cdf_lo..cdf_hi).log_scale(), 0.0..1.0)
            .map_err(draw_err)?;
        cdf.configure_mesh()
            .x_desc("delay (µs)")
            .y_desc("fraction of samples ≤ delay")
            .x_label_formatter(&|x| format!("{x}"))
            .axis_desc_style(("sans-serif", 16))
            .label_style(("sans-serif", 13))
            .light_line_style(RGBColor(235, 235, 235))
            .draw()
            .map_err(draw_err)?;
        for (d, v) in &series {
            let c = color(*d);
            let n = v.len() as f64;
            // A step function: at each sample the fraction rises by 1/n.
            let mut points = vec![(cdf_lo, 0.0)];
            for (i, &x) in v.iter().enumerate() {
                points.push((x, i as f64 / n));
                points.push((x, (i + 1) as f64 / n));
            }
            points.push((cdf_hi, 1.0));
            cdf.draw_series(LineSeries::new(points, c.stroke_width(2)))
                .map_err(draw_err)?
                .label(d.name())
                .legend(move |(x, y)| {
                    PathElement::new(vec![(x, y), (x + 18, y)], c.stroke_width(3))
                });
        }
        cdf.configure_series_labels()
            .position(SeriesLabelPosition::LowerRight)
            .label_font(("sans-serif", 15))
            .background_style(WHITE.mix(0.9))
            .border_style(RGBColor(160, 160, 160))
            .draw()
            .map_err(draw_err)?;
        root.present().map_err(draw_err)?;
    }
    Ok(pixels)
}

/// Renders the plot of `pair` and writes it as an 8-bit RGB PNG.
pub fn pair_png(
    report: &LatencyReport,
    pair: &PairReport,
    path: &Path,
) -> Result<(), ExperimentError> {
    let pixels = render_pair(report, pair)?;
    crate::plot::write_png(&pixels, WIDTH, HEIGHT, path)
}
