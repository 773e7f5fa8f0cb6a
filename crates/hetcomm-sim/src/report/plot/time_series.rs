//! The time-series plots (x, y, θ over time): one panel per rover.

use super::*;

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
