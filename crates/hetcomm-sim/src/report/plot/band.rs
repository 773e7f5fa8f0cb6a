//! Shaded intervals of a time-series plot: when something happened to the run (a radio cut,
//! a silent system), drawn behind the data and labelled, so a reader sees when it was.

use super::{draw_err, Area, Chart, PlotError};
use plotters::prelude::*;
use plotters::style::text_anchor::{HPos, Pos, VPos};

/// Fill of a shaded interval (drawn under the grid and the data).
pub const BAND_FILL: RGBColor = RGBColor(255, 232, 166);
/// Colour of a shaded interval's label.
pub const BAND_TEXT: RGBColor = RGBColor(140, 80, 0);

/// An interval of simulated time to shade in every panel of a time-series plot, with a label
/// written at its top.
#[derive(Clone, Debug, PartialEq)]
pub struct Band {
    /// Start, seconds.
    pub start_s: f64,
    /// End, seconds.
    pub end_s: f64,
    /// What happened then, e.g. "partition Charlie–Tango".
    pub label: String,
}

/// Shades `bands` (clipped to the panel's time range) from `y_lo` to `y_hi`.
pub(super) fn draw_bands(
    chart: &mut Chart<'_, '_>,
    bands: &[Band],
    (t_min, t_max): (f64, f64),
    (y_lo, y_hi): (f64, f64),
) -> Result<(), PlotError> {
    for b in bands {
        let (a, z) = (b.start_s.max(t_min), b.end_s.min(t_max));
        if a < z {
            chart
                .draw_series(std::iter::once(Rectangle::new(
                    [(a, y_lo), (z, y_hi)],
                    BAND_FILL.filled(),
                )))
                .map_err(draw_err)?;
        }
    }
    Ok(())
}

/// Writes each band's label inside its top-left corner (after the data, so it stays
/// readable), a line lower for each band that starts before the previous one ends.
pub(super) fn label_bands(
    chart: &Chart<'_, '_>,
    panel: &Area<'_>,
    bands: &[Band],
    (t_min, t_max): (f64, f64),
    y_hi: f64,
) -> Result<(), PlotError> {
    let base = panel.get_base_pixel();
    let mut row = 0;
    for (i, b) in bands.iter().enumerate() {
        let a = b.start_s.max(t_min);
        if a >= b.end_s.min(t_max) {
            continue;
        }
        row = match i.checked_sub(1).map(|j| &bands[j]) {
            Some(prev) if prev.end_s > b.start_s => row + 1,
            _ => 0,
        };
        let (px, py) = chart.backend_coord(&(a, y_hi));
        panel
            .draw(&Text::new(
                b.label.clone(),
                (px - base.0 + 5, py - base.1 + 4 + 18 * row),
                ("sans-serif", 15)
                    .into_font()
                    .color(&BAND_TEXT)
                    .pos(Pos::new(HPos::Left, VPos::Top)),
            ))
            .map_err(draw_err)?;
    }
    Ok(())
}
