//! PNG plots in the manner of the thesis's Appendix A: x, y and θ over time (one line per
//! rover, dashed vertical markers at each rover's command times) and a top-down
//! trajectory (x against y, one line per rover, start and end marked).
//!
//! Rendering uses `plotters`' bitmap backend into an in-memory RGB buffer, which is then
//! encoded with the `png` crate; this avoids pulling in the `image` crate just to write one
//! format. Text is drawn with DejaVu Sans, embedded in the crate (`assets/`, Bitstream
//! Vera licence, see `assets/DejaVuSans-LICENSE.txt`) and registered with plotters'
//! `ab_glyph` font table, so plots look the same on every machine and no system font
//! lookup happens at run time.

use super::CommandRecord;
use crate::kinematics::angle_diff_deg;
use crate::world::PoseSample;
use plotters::coord::ranged1d::Ranged;
use plotters::coord::types::RangedCoordf64;
use plotters::prelude::*;
use plotters::style::text_anchor::{HPos, Pos, VPos};
use std::path::{Path, PathBuf};

mod band;
pub use band::{Band, BAND_FILL, BAND_TEXT};

/// DejaVu Sans 2.37, unmodified (see `assets/DejaVuSans-LICENSE.txt`).
static FONT: &[u8] = include_bytes!("../../assets/DejaVuSans.ttf");

/// Width in pixels of every plot.
pub const WIDTH: u32 = 1200;
/// Height in pixels of the trajectory plot: a header, an overview of all rovers and a
/// row of per-rover zoomed panels. (Time-series heights depend on the number of rovers,
/// see [`time_series_height`].)
pub const TRAJECTORY_HEIGHT: u32 = 1040;

/// Line colours, assigned to rovers in order of first appearance (then repeated).
const PALETTE: [RGBColor; 6] = [
    RGBColor(31, 119, 180),
    RGBColor(255, 127, 14),
    RGBColor(44, 160, 44),
    RGBColor(214, 39, 40),
    RGBColor(148, 103, 189),
    RGBColor(140, 86, 75),
];

/// Which pose component a time-series plot shows.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Quantity {
    /// The x coordinate.
    X,
    /// The y coordinate.
    Y,
    /// The heading θ in degrees. Samples hold it in `[0, 360)`; plots unwrap it (see
    /// [`plotted_series`]).
    Theta,
}

impl Quantity {
    /// All three quantities, in the order x, y, θ.
    pub const ALL: [Quantity; 3] = [Quantity::X, Quantity::Y, Quantity::Theta];

    /// The PNG file name used for this quantity: `x.png`, `y.png` or `theta.png`.
    pub fn file_name(self) -> &'static str {
        match self {
            Quantity::X => "x.png",
            Quantity::Y => "y.png",
            Quantity::Theta => "theta.png",
        }
    }

    fn value(self, s: &PoseSample) -> f64 {
        match self {
            Quantity::X => s.pose.x,
            Quantity::Y => s.pose.y,
            Quantity::Theta => s.pose.theta_deg,
        }
    }

    fn caption(self) -> &'static str {
        match self {
            Quantity::X => "X position over time",
            Quantity::Y => "Y position over time",
            Quantity::Theta => "Heading θ over time",
        }
    }

    fn axis(self) -> &'static str {
        match self {
            Quantity::X => "X (units)",
            Quantity::Y => "Y (units)",
            Quantity::Theta => "θ (°, unwrapped)",
        }
    }
}

/// Why a plot could not be produced.
#[derive(Debug)]
pub enum PlotError {
    /// There were no finite pose samples to plot.
    NoData,
    /// Creating the directory or writing the file failed.
    Io(std::io::Error),
    /// plotters reported a drawing error (e.g. the font could not be used).
    Draw(String),
    /// The PNG encoder failed.
    Encode(String),
}

impl std::fmt::Display for PlotError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            PlotError::NoData => write!(f, "no finite pose samples to plot"),
            PlotError::Io(e) => write!(f, "writing plot: {e}"),
            PlotError::Draw(e) => write!(f, "drawing plot: {e}"),
            PlotError::Encode(e) => write!(f, "encoding PNG: {e}"),
        }
    }
}

impl std::error::Error for PlotError {}

impl From<std::io::Error> for PlotError {
    fn from(e: std::io::Error) -> Self {
        PlotError::Io(e)
    }
}

fn draw_err<E: std::fmt::Display>(e: E) -> PlotError {
    PlotError::Draw(e.to_string())
}

/// An 8-bit RGB image held in memory, as rendered before PNG encoding.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct RgbImage {
    /// Width in pixels.
    pub width: u32,
    /// Height in pixels.
    pub height: u32,
    /// Row-major RGB bytes, `width · height · 3` of them.
    pub pixels: Vec<u8>,
}

impl RgbImage {
    fn blank(width: u32, height: u32) -> Self {
        RgbImage {
            width,
            height,
            pixels: vec![255; width as usize * height as usize * 3],
        }
    }

    /// The number of distinct colours in the image (a blank image has 1).
    pub fn distinct_colors(&self) -> usize {
        let mut seen = std::collections::HashSet::new();
        for px in self.pixels.chunks_exact(3) {
            seen.insert((px[0], px[1], px[2]));
        }
        seen.len()
    }

    /// Encodes the image as an 8-bit RGB PNG.
    pub fn encode_png(&self) -> Result<Vec<u8>, PlotError> {
        let mut out = Vec::new();
        {
            let mut enc = png::Encoder::new(&mut out, self.width, self.height);
            enc.set_color(png::ColorType::Rgb);
            enc.set_depth(png::BitDepth::Eight);
            let mut writer = enc
                .write_header()
                .map_err(|e| PlotError::Encode(e.to_string()))?;
            writer
                .write_image_data(&self.pixels)
                .map_err(|e| PlotError::Encode(e.to_string()))?;
        }
        Ok(out)
    }

    /// Encodes the image as PNG and writes it to `path`.
    pub fn save_png(&self, path: &Path) -> Result<(), PlotError> {
        let bytes = self.encode_png()?;
        std::fs::write(path, bytes)?;
        Ok(())
    }
}

/// Registers the embedded font under the family plotters uses by default, once per process.
/// Other crates that draw with plotters' bitmap backend call this too, so one copy of the
/// font serves every plot.
pub fn ensure_font() {
    static ONCE: std::sync::Once = std::sync::Once::new();
    ONCE.call_once(|| {
        // The font is compiled in and checked by the tests, so this cannot fail in
        // practice; if it ever did, drawing text would return a PlotError instead.
        let _ = plotters::style::register_font("sans-serif", FontStyle::Normal, FONT);
    });
}

/// Rover names in order of first appearance in the samples.
fn rover_order(samples: &[PoseSample]) -> Vec<&str> {
    let mut out: Vec<&str> = Vec::new();
    for s in samples {
        if !out.contains(&s.rover.as_str()) {
            out.push(&s.rover);
        }
    }
    out
}

fn color_of(index: usize) -> RGBColor {
    PALETTE[index % PALETTE.len()]
}

/// A rover's finite samples in time order.
fn series_of<'a>(samples: &'a [PoseSample], rover: &str) -> Vec<&'a PoseSample> {
    let mut v: Vec<&PoseSample> = samples
        .iter()
        .filter(|s| s.rover == rover && s.t_s.is_finite() && s.pose.is_finite())
        .collect();
    v.sort_by(|a, b| a.t_s.total_cmp(&b.t_s));
    v
}

/// Unwraps headings in degrees: each value is moved by a multiple of 360 so that it lies
/// within 180° of the one before, so a heading that turns past 360 keeps counting
/// (350, 355, 361, …) instead of jumping back to 1. The first value is kept as it is.
///
/// ```
/// use hetcomm_sim::report::plot::unwrap_degrees;
/// assert_eq!(unwrap_degrees(&[350.0, 355.0, 1.0, 10.0]), [350.0, 355.0, 361.0, 370.0]);
/// assert_eq!(unwrap_degrees(&[10.0, 350.0]), [10.0, -10.0]);
/// ```
pub fn unwrap_degrees(degrees: &[f64]) -> Vec<f64> {
    let mut out: Vec<f64> = Vec::with_capacity(degrees.len());
    for &d in degrees {
        match out.last() {
            Some(&prev) => out.push(prev + angle_diff_deg(prev, d)),
            None => out.push(d),
        }
    }
    out
}

/// The points a time-series plot draws for one rover: (simulated time, value) for each of
/// its finite samples, in time order. θ is unwrapped ([`unwrap_degrees`]), so the line has no
/// jump where the heading passes 360°; the tables and CSV files keep θ in `[0, 360)`.
pub fn plotted_series(samples: &[PoseSample], rover: &str, quantity: Quantity) -> Vec<(f64, f64)> {
    let series = series_of(samples, rover);
    let values: Vec<f64> = series.iter().map(|s| quantity.value(s)).collect();
    let values = if quantity == Quantity::Theta {
        unwrap_degrees(&values)
    } else {
        values
    };
    series.iter().map(|s| s.t_s).zip(values).collect()
}

/// A padded `[lo, hi]` range around the values, at least `min_span` wide.
fn padded_range(lo: f64, hi: f64, frac: f64, min_span: f64) -> (f64, f64) {
    let span = (hi - lo).max(min_span);
    let mid = (lo + hi) / 2.0;
    (mid - span * (0.5 + frac), mid + span * (0.5 + frac))
}

/// Tick label text: integers without a trailing ".0", other values with up to 3 decimals.
fn tick(v: &f64) -> String {
    let s = format!("{:.3}", v);
    let s = s.trim_end_matches('0').trim_end_matches('.');
    if s == "-0" {
        "0".to_string()
    } else {
        s.to_string()
    }
}

/// Font size in pixels of tick labels.
const TICK_FONT_PX: u32 = 15;
/// Room in pixels kept free between neighbouring tick labels on a horizontal axis.
const TICK_GAP_PX: f64 = 8.0;
/// Most tick labels ever asked for on one axis (plotters' default).
const MAX_TICKS: usize = 11;

/// Width in pixels of a tick label drawn in the embedded font at [`TICK_FONT_PX`].
fn tick_width_px(text: &str) -> f64 {
    ensure_font();
    match ("sans-serif", TICK_FONT_PX).into_font().box_size(text) {
        Ok((w, _)) => f64::from(w),
        // Cannot happen with the embedded font; a generous estimate keeps labels apart.
        Err(_) => text.chars().count() as f64 * f64::from(TICK_FONT_PX) * 0.7,
    }
}

/// The labels plotters draws on an axis spanning `lo..hi` when asked for at most `n`,
/// formatted as on the plots.
fn tick_labels(lo: f64, hi: f64, n: usize) -> Vec<(f64, String)> {
    RangedCoordf64::from(lo..hi)
        .key_points(n)
        .into_iter()
        .map(|v| (v, tick(&v)))
        .collect()
}

/// Whether the labels plotters draws for `n` requested ticks on a horizontal axis
/// `axis_px` pixels wide, spanning `lo..hi`, leave at least 8 pixels between
/// neighbours (each label is centred on its tick).
pub fn x_ticks_fit(lo: f64, hi: f64, axis_px: u32, n: usize) -> bool {
    if !(lo.is_finite() && hi.is_finite() && hi > lo) {
        return true;
    }
    let scale = f64::from(axis_px) / (hi - lo);
    let placed: Vec<(f64, f64)> = tick_labels(lo, hi, n)
        .iter()
        .map(|(v, text)| ((v - lo) * scale, tick_width_px(text)))
        .collect();
    placed
        .windows(2)
        .all(|w| w[1].0 - w[0].0 >= (w[0].1 + w[1].1) / 2.0 + TICK_GAP_PX)
}

/// How many x tick labels to ask plotters for on an axis `axis_px` pixels wide spanning
/// `lo..hi`: the most, up to plotters' default of 11, whose labels do not overlap ([`x_ticks_fit`]); at least 1.
///
/// A narrow panel (the trajectory plot's per-rover zooms, about 280 pixels for a
/// 60-unit range) gets fewer labels than a wide one instead of labels printed over each
/// other.
pub fn x_tick_count(lo: f64, hi: f64, axis_px: u32) -> usize {
    (2..=MAX_TICKS)
        .rev()
        .find(|&n| x_ticks_fit(lo, hi, axis_px, n))
        .unwrap_or(1)
}

type Area<'a> = DrawingArea<BitMapBackend<'a>, plotters::coord::Shift>;

/// Height in pixels of a time-series plot with `n_rovers` panels (one panel per rover).
pub fn time_series_height(n_rovers: usize) -> u32 {
    let n = n_rovers.clamp(1, 12) as u32;
    TS_HEADER + n * TS_PANEL
}

/// Header (title and two lines of key) height of a time-series plot.
const TS_HEADER: u32 = 104;
/// Height of one rover's panel in a time-series plot.
const TS_PANEL: u32 = 230;

/// Renders one time-series plot into memory (see [`plot_time_series`]).
pub fn render_time_series(
    samples: &[PoseSample],
    commands: &[CommandRecord],
    quantity: Quantity,
    bands: &[Band],
) -> Result<RgbImage, PlotError> {
    ensure_font();
    let mut rovers = rover_order(samples);
    // Panels beyond a dozen would be unreadably thin; the height helper caps them too.
    rovers.truncate(12);
    let series: Vec<Vec<(f64, f64)>> = rovers
        .iter()
        .map(|r| plotted_series(samples, r, quantity))
        .collect();
    let all: Vec<(f64, f64)> = series.iter().flatten().copied().collect();
    if all.is_empty() {
        return Err(PlotError::NoData);
    }
    // One shared time axis, so the panels can be compared vertically (e.g. Tango's delay).
    let t_min = all
        .iter()
        .map(|p| p.0)
        .fold(f64::INFINITY, f64::min)
        .min(0.0);
    let t_max = all
        .iter()
        .map(|p| p.0)
        .fold(f64::NEG_INFINITY, f64::max)
        .max(t_min + 1.0);
    // Unwrapped headings share one axis too, in whole quarter turns: x and y get a range
    // per panel (the rovers are far apart), headings are comparable across rovers.
    let theta_range = {
        let lo = all.iter().map(|p| p.1).fold(f64::INFINITY, f64::min);
        let hi = all.iter().map(|p| p.1).fold(f64::NEG_INFINITY, f64::max);
        let lo = (lo / 90.0).floor() * 90.0;
        (lo, ((hi / 90.0).ceil() * 90.0).max(lo + 90.0))
    };
    let height = time_series_height(rovers.len());
    let mut img = RgbImage::blank(WIDTH, height);
    {
        let root = BitMapBackend::with_buffer(&mut img.pixels, (WIDTH, height)).into_drawing_area();
        root.fill(&WHITE).map_err(draw_err)?;
        let (header, body) = root.split_vertically(TS_HEADER);
        header
            .draw(&Text::new(
                quantity.caption(),
                (WIDTH as i32 / 2, 14),
                ("sans-serif", 30)
                    .into_font()
                    .color(&BLACK)
                    .pos(Pos::new(HPos::Center, VPos::Top)),
            ))
            .map_err(draw_err)?;
        let mut notes = vec![
            "one panel per rover · dashed lines: commands, code above (1 = turn left, 0 = straight, 2 = stop)",
        ];
        if quantity == Quantity::Theta {
            notes.push("θ unwrapped: it keeps counting past 360° instead of jumping back to 0 (the tables give θ modulo 360)");
        }
        for (k, note) in notes.iter().enumerate() {
            header
                .draw(&Text::new(
                    *note,
                    (WIDTH as i32 / 2, 52 + 24 * k as i32),
                    ("sans-serif", 17)
                        .into_font()
                        .color(&RGBColor(90, 90, 90))
                        .pos(Pos::new(HPos::Center, VPos::Top)),
                ))
                .map_err(draw_err)?;
        }
        let panels = body.split_evenly((rovers.len(), 1));
        for (i, ((rover, s), panel)) in rovers.iter().zip(&series).zip(&panels).enumerate() {
            let last = i + 1 == rovers.len();
            let y_range = match quantity {
                Quantity::Theta => theta_range,
                _ => {
                    let lo = s.iter().map(|p| p.1).fold(f64::INFINITY, f64::min);
                    let hi = s.iter().map(|p| p.1).fold(f64::NEG_INFINITY, f64::max);
                    if lo.is_finite() && hi.is_finite() {
                        padded_range(lo, hi, 0.08, 10.0)
                    } else {
                        (-1.0, 1.0)
                    }
                }
            };
            draw_time_panel(
                panel,
                rover,
                color_of(i),
                s,
                commands,
                quantity,
                (t_min, t_max),
                y_range,
                bands,
                last,
            )?;
        }
        root.present().map_err(draw_err)?;
    }
    Ok(img)
}

/// Draws one rover's panel of a time-series plot: `points` as plotted (see
/// [`plotted_series`]) over `t_min..t_max` and `y_lo..y_hi`.
#[allow(clippy::too_many_arguments)]
fn draw_time_panel(
    panel: &Area<'_>,
    rover: &str,
    color: RGBColor,
    points: &[(f64, f64)],
    commands: &[CommandRecord],
    quantity: Quantity,
    (t_min, t_max): (f64, f64),
    (y_lo, y_hi): (f64, f64),
    bands: &[Band],
    last: bool,
) -> Result<(), PlotError> {
    let mut chart = ChartBuilder::on(panel)
        .margin_left(15)
        .margin_right(30)
        .margin_top(34)
        .margin_bottom(6)
        .x_label_area_size(if last { 55 } else { 28 })
        .y_label_area_size(85)
        .build_cartesian_2d(t_min..t_max, y_lo..y_hi)
        .map_err(draw_err)?;
    let axis_px = chart.plotting_area().dim_in_pixel().0;
    // Under the grid, so the grid still reads across a band.
    band::draw_bands(&mut chart, bands, (t_min, t_max), (y_lo, y_hi))?;
    let mut mesh = chart.configure_mesh();
    mesh.y_desc(quantity.axis())
        .x_labels(x_tick_count(t_min, t_max, axis_px))
        .x_label_formatter(&tick)
        .y_label_formatter(&tick)
        .axis_desc_style(("sans-serif", 18))
        .label_style(("sans-serif", TICK_FONT_PX))
        .light_line_style(RGBColor(238, 238, 238))
        .bold_line_style(RGBColor(205, 205, 205))
        .y_labels(6);
    if last {
        mesh.x_desc("Simulated time (s)");
    }
    mesh.draw().map_err(draw_err)?;

    // The rover's name above the plot's top-left corner.
    let (x_px, y_px) = chart.plotting_area().get_pixel_range();
    let base = panel.get_base_pixel();
    panel
        .draw(&Text::new(
            rover.to_string(),
            (x_px.start - base.0, y_px.start - base.1 - 6),
            ("sans-serif", 21)
                .into_font()
                .color(&color)
                .pos(Pos::new(HPos::Left, VPos::Bottom)),
        ))
        .map_err(draw_err)?;

    for c in commands
        .iter()
        .filter(|c| c.rover == rover && c.t_s.is_finite())
    {
        if c.t_s < t_min || c.t_s > t_max {
            continue;
        }
        chart
            .draw_series(DashedLineSeries::new(
                vec![(c.t_s, y_lo), (c.t_s, y_hi)],
                7,
                5,
                BLACK.mix(0.55).stroke_width(2),
            ))
            .map_err(draw_err)?;
        // The code sits just above the plotting area, so it never hides the data.
        let (px, _) = chart.backend_coord(&(c.t_s, y_hi));
        panel
            .draw(&Text::new(
                c.code.to_string(),
                (px - base.0, y_px.start - base.1 - 4),
                ("sans-serif", 18)
                    .into_font()
                    .color(&BLACK.mix(0.75))
                    .pos(Pos::new(HPos::Center, VPos::Bottom)),
            ))
            .map_err(draw_err)?;
    }

    draw_thick_line(&chart, &simplify(points.iter().copied()), color, LINE_WIDTH)?;
    band::label_bands(&chart, panel, bands, (t_min, t_max), y_hi)?;
    Ok(())
}

/// Width in pixels of the data lines.
const LINE_WIDTH: f64 = 3.5;

type Chart<'a, 'b> =
    ChartContext<'a, BitMapBackend<'b>, Cartesian2d<RangedCoordf64, RangedCoordf64>>;

/// Draws a polyline of uniform pixel width: one filled quad per segment plus a round
/// joint at every vertex, clipped to the plotting area.
///
/// plotters' own wide strokes come out thinner on steep segments than on flat ones, which
/// makes a trajectory look as if the rover changed; quads keep the width exact.
fn draw_thick_line(
    chart: &Chart<'_, '_>,
    points: &[(f64, f64)],
    color: RGBColor,
    width: f64,
) -> Result<(), PlotError> {
    let screen = chart.plotting_area().use_screen_coord();
    let px: Vec<(f64, f64)> = points
        .iter()
        .map(|p| {
            let (x, y) = chart.backend_coord(p);
            (f64::from(x), f64::from(y))
        })
        .collect();
    let half = width / 2.0;
    for w in px.windows(2) {
        let ((x0, y0), (x1, y1)) = (w[0], w[1]);
        let len = (x1 - x0).hypot(y1 - y0);
        if len < 1e-9 {
            continue;
        }
        let (nx, ny) = (-(y1 - y0) / len * half, (x1 - x0) / len * half);
        let quad: Vec<(i32, i32)> = [
            (x0 + nx, y0 + ny),
            (x1 + nx, y1 + ny),
            (x1 - nx, y1 - ny),
            (x0 - nx, y0 - ny),
        ]
        .iter()
        .map(|&(x, y)| (x.round() as i32, y.round() as i32))
        .collect();
        screen
            .draw(&Polygon::new(quad, color.filled()))
            .map_err(draw_err)?;
    }
    let radius = (half.round() as i32).max(1);
    for &(x, y) in &px {
        let c = (x.round() as i32, y.round() as i32);
        screen
            .draw(&Circle::new(c, radius, color.filled()))
            .map_err(draw_err)?;
    }
    Ok(())
}

/// Drops points that add nothing to a polyline: repeats of the previous point, and
/// middle points of straight runs.
///
/// plotters draws a thick polyline segment by segment, so a straight leg logged at 10 Hz
/// comes out as a row of slightly misaligned stubs, and a zero-length segment (a rover
/// pivoting in place logs the same x, y) draws a spur. Straight legs and pivots are exactly
/// what this simulation produces, so merging them makes the lines clean without changing
/// their shape (the tolerance is a relative 1e−7 on the turn between segments).
fn simplify(points: impl IntoIterator<Item = (f64, f64)>) -> Vec<(f64, f64)> {
    let mut out: Vec<(f64, f64)> = Vec::new();
    for p in points {
        if let Some(&q) = out.last() {
            if (q.0 - p.0).abs() <= 1e-9 && (q.1 - p.1).abs() <= 1e-9 {
                continue;
            }
        }
        if out.len() >= 2 {
            let (a, b) = (out[out.len() - 2], out[out.len() - 1]);
            let (ux, uy) = (b.0 - a.0, b.1 - a.1);
            let (vx, vy) = (p.0 - b.0, p.1 - b.1);
            let cross = ux * vy - uy * vx;
            let dot = ux * vx + uy * vy;
            let norms = (ux.hypot(uy)) * (vx.hypot(vy));
            if dot > 0.0 && cross.abs() <= 1e-7 * norms {
                // b lies on the straight run from a to p: extend the run instead.
                let n = out.len();
                out[n - 1] = p;
                continue;
            }
        }
        out.push(p);
    }
    out
}

/// Bounds `(x_lo, x_hi, y_lo, y_hi)` of some samples' positions.
fn bounds(samples: &[&PoseSample]) -> (f64, f64, f64, f64) {
    samples.iter().fold(
        (
            f64::INFINITY,
            f64::NEG_INFINITY,
            f64::INFINITY,
            f64::NEG_INFINITY,
        ),
        |(a, b, c, d), s| {
            (
                a.min(s.pose.x),
                b.max(s.pose.x),
                c.min(s.pose.y),
                d.max(s.pose.y),
            )
        },
    )
}

/// Draws rover paths in `area` at equal x/y scale; returns nothing but errors.
///
/// `series` pairs each rover's name and colour with its samples; `with_legend` adds a
/// legend of rover names (for the overview, where several rovers share a panel).
fn draw_xy_panel(
    area: &Area<'_>,
    series: &[(&str, RGBColor, Vec<&PoseSample>)],
    with_legend: bool,
) -> Result<(), PlotError> {
    let all: Vec<&PoseSample> = series
        .iter()
        .flat_map(|(_, _, s)| s.iter().copied())
        .collect();
    let (bx0, bx1, by0, by1) = bounds(&all);
    let (x_lo, x_hi) = padded_range(bx0, bx1, 0.1, 20.0);
    let (y_lo, y_hi) = padded_range(by0, by1, 0.1, 20.0);
    let mut builder = ChartBuilder::on(area);
    builder
        .margin(12)
        .margin_right(25)
        .x_label_area_size(50)
        .y_label_area_size(75);
    // Equal scale on both axes, so turns look like turns: measure the plotting area
    // (building a chart without a caption draws nothing), then widen the narrower range.
    let (w, h) = builder
        .build_cartesian_2d(0.0..1.0, 0.0..1.0)
        .map_err(draw_err)?
        .plotting_area()
        .dim_in_pixel();
    let (w, h) = (f64::from(w.max(1)), f64::from(h.max(1)));
    let per_px = ((x_hi - x_lo) / w).max((y_hi - y_lo) / h);
    let (xm, ym) = ((x_lo + x_hi) / 2.0, (y_lo + y_hi) / 2.0);
    let (x_lo, x_hi) = (xm - per_px * w / 2.0, xm + per_px * w / 2.0);
    let (y_lo, y_hi) = (ym - per_px * h / 2.0, ym + per_px * h / 2.0);
    let mut chart = builder
        .build_cartesian_2d(x_lo..x_hi, y_lo..y_hi)
        .map_err(draw_err)?;
    // Narrow panels get fewer x labels, so that labels such as "-205" never overlap.
    let axis_px = chart.plotting_area().dim_in_pixel().0;
    chart
        .configure_mesh()
        .x_desc("X (units)")
        .y_desc("Y (units)")
        .x_labels(x_tick_count(x_lo, x_hi, axis_px))
        .x_label_formatter(&tick)
        .y_label_formatter(&tick)
        .axis_desc_style(("sans-serif", 18))
        .label_style(("sans-serif", TICK_FONT_PX))
        .light_line_style(RGBColor(238, 238, 238))
        .bold_line_style(RGBColor(205, 205, 205))
        .draw()
        .map_err(draw_err)?;
    for (rover, color, s) in series {
        let color = *color;
        let points = simplify(s.iter().map(|s| (s.pose.x, s.pose.y)));
        draw_thick_line(&chart, &points, color, LINE_WIDTH)?;
        if with_legend {
            // The line itself is drawn by hand, so an empty series carries the legend entry.
            chart
                .draw_series(std::iter::empty::<Circle<(f64, f64), i32>>())
                .map_err(draw_err)?
                .label(*rover)
                .legend(move |(x, y)| {
                    PathElement::new(vec![(x, y), (x + 24, y)], color.stroke_width(3))
                });
        }
        let (Some(first), Some(last)) = (s.first(), s.last()) else {
            continue;
        };
        let start = EmptyElement::at((first.pose.x, first.pose.y))
            + Circle::new((0, 0), 7, color.filled())
            + Circle::new((0, 0), 7, BLACK.stroke_width(1));
        chart
            .draw_series(std::iter::once(start))
            .map_err(draw_err)?;
        // The end is an arrowhead along the final heading, sized in pixels; screen y
        // grows downwards, hence the minus sign on the sine.
        let th = last.pose.theta_rad();
        let (c, s) = (th.cos(), -th.sin());
        let at = |len: f64, ang: f64| {
            let (ca, sa) = (ang.cos(), ang.sin());
            let (dx, dy) = (c * ca - s * sa, s * ca + c * sa);
            ((len * dx).round() as i32, (len * dy).round() as i32)
        };
        let tri = vec![at(16.0, 0.0), at(10.0, 2.5), at(10.0, -2.5)];
        let mut outline = tri.clone();
        outline.push(tri[0]);
        let end = EmptyElement::at((last.pose.x, last.pose.y))
            + Polygon::new(tri, color.filled())
            + PathElement::new(outline, BLACK.stroke_width(1));
        chart.draw_series(std::iter::once(end)).map_err(draw_err)?;
    }
    if with_legend {
        chart
            .configure_series_labels()
            .position(SeriesLabelPosition::UpperLeft)
            .label_font(("sans-serif", 18))
            .background_style(WHITE.mix(0.85))
            .border_style(RGBColor(160, 160, 160))
            .draw()
            .map_err(draw_err)?;
    }
    Ok(())
}

/// Height in pixels of the overview part of the trajectory plot.
const TRAJ_OVERVIEW: u32 = 560;
/// Height of the header (title and key) of the trajectory plot.
const TRAJ_HEADER: u32 = 80;

/// Renders the top-down trajectory plot into memory (see [`plot_trajectory`]).
pub fn render_trajectory(samples: &[PoseSample]) -> Result<RgbImage, PlotError> {
    ensure_font();
    let rovers = rover_order(samples);
    let series: Vec<(&str, RGBColor, Vec<&PoseSample>)> = rovers
        .iter()
        .enumerate()
        .map(|(i, r)| (*r, color_of(i), series_of(samples, r)))
        .filter(|(_, _, s)| !s.is_empty())
        .collect();
    if series.is_empty() {
        return Err(PlotError::NoData);
    }
    let mut img = RgbImage::blank(WIDTH, TRAJECTORY_HEIGHT);
    {
        let root = BitMapBackend::with_buffer(&mut img.pixels, (WIDTH, TRAJECTORY_HEIGHT))
            .into_drawing_area();
        root.fill(&WHITE).map_err(draw_err)?;
        let (header, body) = root.split_vertically(TRAJ_HEADER);
        header
            .draw(&Text::new(
                "Rover trajectories (top-down)",
                (WIDTH as i32 / 2, 14),
                ("sans-serif", 30)
                    .into_font()
                    .color(&BLACK)
                    .pos(Pos::new(HPos::Center, VPos::Top)),
            ))
            .map_err(draw_err)?;
        header
            .draw(&Text::new(
                "all rovers at equal scale (top) and each rover zoomed in (bottom) · dot: start · arrow: end, pointing along the final heading",
                (WIDTH as i32 / 2, 52),
                ("sans-serif", 17)
                    .into_font()
                    .color(&RGBColor(90, 90, 90))
                    .pos(Pos::new(HPos::Center, VPos::Top)),
            ))
            .map_err(draw_err)?;
        let (overview, zoom_row) = body.split_vertically(TRAJ_OVERVIEW);
        draw_xy_panel(&overview, &series, true)?;
        // The zoom row gets unreadable beyond a handful of panels; the overview shows all.
        let shown = &series[..series.len().min(6)];
        let cells = zoom_row.split_evenly((1, shown.len()));
        for (one, cell) in shown.iter().zip(&cells) {
            let titled = cell
                .titled(one.0, ("sans-serif", 20).into_font().color(&one.1))
                .map_err(draw_err)?;
            draw_xy_panel(&titled, std::slice::from_ref(one), false)?;
        }
        root.present().map_err(draw_err)?;
    }
    Ok(img)
}

fn save(dir: &Path, name: &str, img: &RgbImage) -> Result<PathBuf, PlotError> {
    std::fs::create_dir_all(dir)?;
    let path = dir.join(name);
    img.save_png(&path)?;
    Ok(path)
}

/// Plots one pose component over time for every rover and writes it to
/// `dir/<quantity.file_name()>`, returning that path.
///
/// Each rover is a solid line in its own colour; each of its command records is a dashed
/// vertical line of the same colour with the command code at the top. θ is unwrapped (see
/// [`plotted_series`]), so a heading that turns past 360° keeps rising instead of jumping
/// back to 0; the axis label says so.
pub fn plot_time_series(
    dir: &Path,
    samples: &[PoseSample],
    commands: &[CommandRecord],
    quantity: Quantity,
    bands: &[Band],
) -> Result<PathBuf, PlotError> {
    let img = render_time_series(samples, commands, quantity, bands)?;
    save(dir, quantity.file_name(), &img)
}

/// Plots every rover's path in the x–y plane at equal scale and writes it to
/// `dir/trajectory.png`, returning that path. Starts are dots labelled with the rover's
/// name; ends are arrowheads along the final heading.
pub fn plot_trajectory(dir: &Path, samples: &[PoseSample]) -> Result<PathBuf, PlotError> {
    let img = render_trajectory(samples)?;
    save(dir, "trajectory.png", &img)
}

/// Writes all four plots (`x.png`, `y.png`, `theta.png`, `trajectory.png`) into `dir`,
/// creating it if needed, and returns their paths in that order; the time series shade
/// `bands`.
pub fn write_all(
    dir: &Path,
    samples: &[PoseSample],
    commands: &[CommandRecord],
    bands: &[Band],
) -> Result<Vec<PathBuf>, PlotError> {
    let mut paths = Vec::new();
    for q in Quantity::ALL {
        paths.push(plot_time_series(dir, samples, commands, q, bands)?);
    }
    paths.push(plot_trajectory(dir, samples)?);
    Ok(paths)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sample(t_s: f64, rover: &str, theta_deg: f64) -> PoseSample {
        PoseSample {
            t_s,
            rover: rover.into(),
            pose: crate::Pose::new(0.0, 0.0, theta_deg),
        }
    }

    #[test]
    fn plotted_theta_is_unwrapped() {
        // Out of time order on purpose: the series is sorted first.
        let samples = [
            sample(2.0, "A", 2.0),
            sample(0.0, "A", 340.0),
            sample(1.0, "A", 350.0),
            sample(3.0, "A", 10.0),
            sample(0.0, "B", 10.0),
            sample(1.0, "B", 350.0),
        ];
        assert_eq!(
            plotted_series(&samples, "A", Quantity::Theta),
            [(0.0, 340.0), (1.0, 350.0), (2.0, 362.0), (3.0, 370.0)]
        );
        assert_eq!(
            plotted_series(&samples, "B", Quantity::Theta),
            [(0.0, 10.0), (1.0, -10.0)]
        );
        // Other quantities are drawn as they are.
        assert_eq!(
            plotted_series(&samples, "B", Quantity::X),
            [(0.0, 0.0), (1.0, 0.0)]
        );
    }

    #[test]
    fn plotted_theta_of_the_demo_has_no_jumps() {
        // Charlie and Tango turn past 360° in the open-loop demonstration.
        let run = crate::Scenario::thesis()
            .run_open_loop(&[("Charlie", 0.0), ("Tango", 0.5)])
            .unwrap();
        let mut wrapped = 0;
        for rover in ["Alpha", "Charlie", "Tango"] {
            let raw: Vec<f64> = series_of(&run.samples, rover)
                .iter()
                .map(|s| s.pose.theta_deg)
                .collect();
            wrapped += raw
                .windows(2)
                .filter(|w| (w[1] - w[0]).abs() > 180.0)
                .count();
            let plotted = plotted_series(&run.samples, rover, Quantity::Theta);
            assert_eq!(plotted.len(), raw.len());
            for w in plotted.windows(2) {
                assert!((w[1].1 - w[0].1).abs() <= 180.0, "{rover}: {w:?}");
            }
            // Same heading, modulo whole turns.
            for (p, r) in plotted.iter().zip(&raw) {
                assert!(
                    angle_diff_deg(*r, p.1).abs() < 1e-9,
                    "{rover}: {p:?} vs {r}"
                );
            }
        }
        assert!(wrapped > 0, "the run should cross 0/360 somewhere");
    }

    #[test]
    fn x_tick_labels_do_not_overlap() {
        // A per-rover zoom of the trajectory plot: about 280 px for Alpha's -212..-158.
        // plotters' default of 11 labels prints "-210-205-200…" as one smear.
        assert!(!x_ticks_fit(-212.0, -158.0, 280, MAX_TICKS));
        let n = x_tick_count(-212.0, -158.0, 280);
        assert!((2..MAX_TICKS).contains(&n), "{n}");
        assert!(x_ticks_fit(-212.0, -158.0, 280, n));
        assert!(tick_labels(-212.0, -158.0, n).len() >= 2);
        // Wide axes keep the full count; every width and range gets labels that fit.
        assert_eq!(x_tick_count(0.0, 15.0, 1070), MAX_TICKS);
        for (lo, hi) in [
            (-212.0, -158.0),
            (0.0, 15.0),
            (-440.0, 480.0),
            (160.0, 210.0),
            (-0.5, 0.5),
        ] {
            for px in [60, 120, 200, 280, 400, 800, 1100] {
                let n = x_tick_count(lo, hi, px);
                assert!(n >= 1);
                if n > 1 {
                    assert!(x_ticks_fit(lo, hi, px, n), "{lo}..{hi} at {px} px: {n}");
                }
            }
        }
    }

    #[test]
    fn simplify_merges_straight_runs_and_repeats() {
        let pts = vec![
            (0.0, 0.0),
            (1.0, 1.0),
            (1.0, 1.0),
            (2.0, 2.0),
            (3.0, 2.0),
            (4.0, 2.0),
        ];
        assert_eq!(simplify(pts), vec![(0.0, 0.0), (2.0, 2.0), (4.0, 2.0)]);
        // Doubling back is kept.
        assert_eq!(simplify(vec![(0.0, 0.0), (1.0, 0.0), (0.5, 0.0)]).len(), 3);
    }

    #[test]
    fn tick_labels_and_font() {
        assert_eq!(tick(&2.0), "2");
        assert_eq!(tick(&-0.0), "0");
        assert_eq!(tick(&2.5), "2.5");
        assert_eq!(tick(&-200.0), "-200");
        // The embedded font parses and a rendered plot has text-like detail.
        let img = render_trajectory(&[PoseSample {
            t_s: 0.0,
            rover: "A".into(),
            pose: crate::Pose::new(0.0, 0.0, 0.0),
        }])
        .unwrap();
        assert!(img.distinct_colors() > 20);
        assert!(RgbImage::blank(4, 4).distinct_colors() == 1);
    }
}
