//! Drawing helpers the plots share: thick polylines and their simplification.

use super::*;

/// The drawing area of one plot or panel.
pub(super) type Area<'a> = DrawingArea<BitMapBackend<'a>, plotters::coord::Shift>;

/// Width in pixels of the data lines.
pub(super) const LINE_WIDTH: f64 = 3.5;

pub(super) type Chart<'a, 'b> =
    ChartContext<'a, BitMapBackend<'b>, Cartesian2d<RangedCoordf64, RangedCoordf64>>;

/// Draws a polyline of uniform pixel width: one filled quad per segment plus a round
/// joint at every vertex, clipped to the plotting area.
///
/// plotters' own wide strokes come out thinner on steep segments than on flat ones, which
/// makes a trajectory look as if the rover changed; quads keep the width exact.
pub(super) fn draw_thick_line(
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
pub(super) fn simplify(points: impl IntoIterator<Item = (f64, f64)>) -> Vec<(f64, f64)> {
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
