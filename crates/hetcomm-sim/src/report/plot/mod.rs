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

mod axes;
mod band;
mod draw;
mod time_series;
mod trajectory;
use axes::TICK_FONT_PX;
pub use axes::{x_tick_count, x_ticks_fit};
pub use band::{Band, BAND_FILL, BAND_TEXT};
use draw::{draw_thick_line, simplify, Area, Chart, LINE_WIDTH};
pub use time_series::{render_time_series, time_series_height};
pub use trajectory::render_trajectory;

/// DejaVu Sans 2.37, unmodified (see `assets/DejaVuSans-LICENSE.txt`).
static FONT: &[u8] = include_bytes!("../../../assets/DejaVuSans.ttf");

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
    use super::axes::{tick_labels, MAX_TICKS};
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
