//! Axis ticks: where they go and whether their labels fit the axis.

use super::*;

/// Font size in pixels of tick labels.
pub(super) const TICK_FONT_PX: u32 = 15;
/// Room in pixels kept free between neighbouring tick labels on a horizontal axis.
const TICK_GAP_PX: f64 = 8.0;
/// Most tick labels ever asked for on one axis (plotters' default).
pub(super) const MAX_TICKS: usize = 11;

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
pub(super) fn tick_labels(lo: f64, hi: f64, n: usize) -> Vec<(f64, String)> {
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
