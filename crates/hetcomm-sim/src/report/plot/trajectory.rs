//! The trajectory plot: x against y, an overview of all rovers and a zoomed panel each.

use super::*;

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
