//! `hetcomm topology`: the communication table as a picture. Systems sit on a circle; each
//! ordered pair with a transport is an arrow from source to destination labelled with the
//! transport's name (one two-headed arrow when both directions use the same transport), in
//! one colour per transport; `--show-x` adds a dotted line for pairs that cannot talk.
//! SVG is written directly; PNG is drawn with plotters and the embedded font of the plots.

use std::f64::consts::PI;
use std::fmt::Write as _;
use std::path::Path;

use anyhow::Context;
use hetcomm::config::Fleet;

const NODE_R: f64 = 50.0;
/// Text sizes, in pixels: readable at the picture's own size.
const TITLE_PX: u32 = 20;
const TEXT_PX: u32 = 16;
const PALETTE: [(u8, u8, u8); 8] = [
    (31, 119, 180),
    (214, 39, 40),
    (44, 160, 44),
    (148, 103, 189),
    (255, 127, 14),
    (140, 86, 75),
    (227, 119, 194),
    (23, 190, 207),
];
const GREY: (u8, u8, u8) = (170, 170, 170);

struct Node {
    name: String,
    x: f64,
    y: f64,
}

struct Edge {
    from: (f64, f64),
    to: (f64, f64),
    colour: (u8, u8, u8),
    dotted: bool,
    head_at_end: bool,
    head_at_start: bool,
    label: String,
    label_at: (f64, f64),
}

struct Picture {
    /// Width and height of the square picture without the title band: small fleets get a
    /// small picture, so that a pair of systems is not a dot in a white page.
    size: f64,
    title: String,
    nodes: Vec<Node>,
    edges: Vec<Edge>,
    legend: Vec<(String, (u8, u8, u8))>,
}

fn picture(fleet: &Fleet, show_x: bool) -> Picture {
    let n = fleet.systems.len().max(1);
    let size = match n {
        0..=2 => 560.0,
        3..=4 => 700.0,
        _ => 900.0,
    };
    let (cx, cy, r) = (size / 2.0, size / 2.0 + 20.0, size / 2.0 - 130.0);
    // Two systems side by side (the page is wider than it is tall once the legend is on
    // top); more on a circle from the top.
    let start = if n == 2 { -PI } else { -PI / 2.0 };
    let nodes: Vec<Node> = fleet
        .systems
        .iter()
        .enumerate()
        .map(|(i, s)| {
            let a = start + 2.0 * PI * i as f64 / n as f64;
            Node {
                name: s.name.clone(),
                x: cx + r * a.cos(),
                y: cy + r * a.sin(),
            }
        })
        .collect();
    let colour = |t: usize| PALETTE[t % PALETTE.len()];
    let mut edges = Vec::new();
    for i in 0..fleet.systems.len() {
        for j in i + 1..fleet.systems.len() {
            let (a, b) = (&fleet.systems[i], &fleet.systems[j]);
            let ab = fleet.table.get(&(a.id, b.id)).copied();
            let ba = fleet.table.get(&(b.id, a.id)).copied();
            let (p, q) = (&nodes[i], &nodes[j]);
            // Shorten to the circles' rims; `off` moves a line sideways.
            let line = |from: &Node, to: &Node, off: f64| {
                let (dx, dy) = (to.x - from.x, to.y - from.y);
                let len = (dx * dx + dy * dy).sqrt().max(1.0);
                let (ux, uy) = (dx / len, dy / len);
                let (nx, ny) = (-uy * off, ux * off);
                (
                    (from.x + ux * NODE_R + nx, from.y + uy * NODE_R + ny),
                    (to.x - ux * NODE_R + nx, to.y - uy * NODE_R + ny),
                )
            };
            // Where the label of a line goes: `f` of the way along, moved off the line to its
            // left by enough that the label's box (about 9 px a character at TEXT_PX, 22 px
            // high) does not touch it, so the arrow never runs through its own label.
            let along = |(s, e): ((f64, f64), (f64, f64)), f: f64, label: &str| {
                let (dx, dy) = (e.0 - s.0, e.1 - s.1);
                let len = (dx * dx + dy * dy).sqrt().max(1.0);
                let (nx, ny) = (dy / len, -dx / len);
                let (hw, hh) = (4.5 * label.chars().count() as f64 + 3.0, 11.0);
                let side = hw * nx.abs() + hh * ny.abs() + 3.0;
                (s.0 + dx * f + nx * side, s.1 + dy * f + ny * side)
            };
            let name = |t: usize| fleet.transports[t].name.clone();
            match (ab, ba) {
                (Some(x), Some(y)) if x == y => {
                    let l = line(p, q, 0.0);
                    edges.push(Edge {
                        from: l.0,
                        to: l.1,
                        colour: colour(x),
                        dotted: false,
                        head_at_end: true,
                        head_at_start: true,
                        // Off the middle, where diagonals of a circle cross.
                        label_at: along(l, 0.3, &name(x)),
                        label: name(x),
                    });
                }
                (None, None) => {
                    if show_x {
                        let l = line(p, q, 0.0);
                        edges.push(Edge {
                            from: l.0,
                            to: l.1,
                            colour: GREY,
                            dotted: true,
                            head_at_end: false,
                            head_at_start: false,
                            label: "X".into(),
                            label_at: along(l, 0.4, "X"),
                        });
                    }
                }
                _ => {
                    for (t, from, to) in [(ab, p, q), (ba, q, p)] {
                        let Some(t) = t else { continue };
                        let l = line(from, to, 7.0);
                        edges.push(Edge {
                            from: l.0,
                            to: l.1,
                            colour: colour(t),
                            dotted: false,
                            head_at_end: true,
                            head_at_start: false,
                            label_at: along(l, 0.3, &name(t)),
                            label: name(t),
                        });
                    }
                }
            }
        }
    }
    let mut legend: Vec<(String, (u8, u8, u8))> = fleet
        .transports
        .iter()
        .enumerate()
        .filter(|(i, _)| fleet.table.values().any(|t| t == i))
        .map(|(i, t)| (format!("{} ({})", t.name, t.kind), colour(i)))
        .collect();
    if show_x {
        legend.push(("X: no traffic".into(), GREY));
    }
    Picture {
        size,
        title: format!(
            "fleet {}: {} systems, {} ordered pairs with a transport",
            fleet.name.as_deref().unwrap_or("(unnamed)"),
            fleet.systems.len(),
            fleet.table.len()
        ),
        nodes,
        edges,
        legend,
    }
}

fn escape(s: &str) -> String {
    s.replace('&', "&amp;")
        .replace('<', "&lt;")
        .replace('>', "&gt;")
        .replace('"', "&quot;")
}

fn rgb((r, g, b): (u8, u8, u8)) -> String {
    format!("rgb({r},{g},{b})")
}

fn svg(p: &Picture) -> String {
    let mut s = String::new();
    let _ = writeln!(
        s,
        r#"<svg xmlns="http://www.w3.org/2000/svg" width="{w}" height="{h}" viewBox="0 0 {w} {h}" font-family="DejaVu Sans, sans-serif">"#,
        w = p.size,
        h = p.size + 40.0
    );
    let _ = writeln!(s, r#"<rect width="100%" height="100%" fill="white"/>"#);
    let _ = writeln!(
        s,
        r#"<text x="20" y="30" font-size="{TITLE_PX}">{}</text>"#,
        escape(&p.title)
    );
    for (i, (label, c)) in p.legend.iter().enumerate() {
        let y = 58.0 + 22.0 * i as f64;
        let _ = writeln!(
            s,
            r#"<line x1="20" y1="{y}" x2="50" y2="{y}" stroke="{}" stroke-width="3"/><text x="58" y="{}" font-size="{TEXT_PX}">{}</text>"#,
            rgb(*c),
            y + 4.0,
            escape(label)
        );
    }
    for (i, e) in p.edges.iter().enumerate() {
        let c = rgb(e.colour);
        let _ = writeln!(
            s,
            r#"<defs><marker id="h{i}" viewBox="0 0 10 10" refX="10" refY="5" markerWidth="8" markerHeight="8" orient="auto-start-reverse"><path d="M0,0 L10,5 L0,10 z" fill="{c}"/></marker></defs>"#
        );
        let _ = writeln!(
            s,
            r#"<line class="pair" x1="{:.1}" y1="{:.1}" x2="{:.1}" y2="{:.1}" stroke="{c}" stroke-width="2"{}{}{}/>"#,
            e.from.0,
            e.from.1,
            e.to.0,
            e.to.1,
            if e.dotted {
                r#" stroke-dasharray="4 4""#
            } else {
                ""
            },
            if e.head_at_end {
                format!(r#" marker-end="url(#h{i})""#)
            } else {
                String::new()
            },
            if e.head_at_start {
                format!(r#" marker-start="url(#h{i})""#)
            } else {
                String::new()
            },
        );
        let _ = writeln!(
            s,
            r#"<text x="{:.1}" y="{:.1}" font-size="{TEXT_PX}" text-anchor="middle" fill="{c}" stroke="white" stroke-width="4" paint-order="stroke">{}</text>"#,
            e.label_at.0,
            e.label_at.1 + 4.0,
            escape(&e.label)
        );
    }
    for n in &p.nodes {
        let _ = writeln!(
            s,
            r#"<circle class="system" cx="{:.1}" cy="{:.1}" r="{NODE_R}" fill="rgb(245,245,245)" stroke="black" stroke-width="2"/><text x="{:.1}" y="{:.1}" font-size="{TEXT_PX}" text-anchor="middle">{}</text>"#,
            n.x,
            n.y,
            n.x,
            n.y + 5.0,
            escape(&n.name)
        );
    }
    s.push_str("</svg>\n");
    s
}

fn png(p: &Picture, out: &Path) -> anyhow::Result<()> {
    hetcomm_sim::report::plot::ensure_font();
    let (w, h) = (p.size as u32, (p.size + 40.0) as u32);
    let mut img = hetcomm_sim::report::plot::RgbImage {
        width: w,
        height: h,
        pixels: vec![255; w as usize * h as usize * 3],
    };
    draw_png(p, &mut img, out)?;
    img.save_png(out)
        .map_err(|e| anyhow::anyhow!("writing {}: {e}", out.display()))
}

fn draw_png(
    p: &Picture,
    img: &mut hetcomm_sim::report::plot::RgbImage,
    out: &Path,
) -> anyhow::Result<()> {
    use plotters::prelude::*;
    use plotters::style::text_anchor::{HPos, Pos, VPos};
    let root =
        BitMapBackend::with_buffer(&mut img.pixels, (img.width, img.height)).into_drawing_area();
    let err = |e: &dyn std::fmt::Display| anyhow::anyhow!("drawing {}: {e}", out.display());
    root.fill(&WHITE).map_err(|e| err(&e))?;
    let at = |(x, y): (f64, f64)| (x.round() as i32, y.round() as i32);
    let col = |(r, g, b): (u8, u8, u8)| RGBColor(r, g, b);
    fn centred(size: u32, c: &RGBColor) -> TextStyle<'_> {
        TextStyle::from(("sans-serif", size).into_font())
            .color(c)
            .pos(Pos::new(HPos::Center, VPos::Center))
    }
    root.draw(&Text::new(
        p.title.clone(),
        (20, 15),
        ("sans-serif", TITLE_PX).into_font(),
    ))
    .map_err(|e| err(&e))?;
    for (i, (label, c)) in p.legend.iter().enumerate() {
        let y = 58 + 22 * i as i32;
        root.draw(&PathElement::new(
            vec![(20, y), (50, y)],
            col(*c).stroke_width(3),
        ))
        .map_err(|e| err(&e))?;
        root.draw(&Text::new(
            label.clone(),
            (58, y - 9),
            ("sans-serif", TEXT_PX).into_font(),
        ))
        .map_err(|e| err(&e))?;
    }
    for e in &p.edges {
        let c = col(e.colour);
        if e.dotted {
            let n = 40;
            for k in (0..n).step_by(2) {
                let f = |k: i32| {
                    let t = k as f64 / n as f64;
                    at((
                        e.from.0 + (e.to.0 - e.from.0) * t,
                        e.from.1 + (e.to.1 - e.from.1) * t,
                    ))
                };
                root.draw(&PathElement::new(vec![f(k), f(k + 1)], c.stroke_width(2)))
                    .map_err(|x| err(&x))?;
            }
        } else {
            root.draw(&PathElement::new(
                vec![at(e.from), at(e.to)],
                c.stroke_width(2),
            ))
            .map_err(|x| err(&x))?;
        }
        let mut heads = Vec::new();
        if e.head_at_end {
            heads.push((e.from, e.to));
        }
        if e.head_at_start {
            heads.push((e.to, e.from));
        }
        for (s, t) in heads {
            let (dx, dy) = (t.0 - s.0, t.1 - s.1);
            let len = (dx * dx + dy * dy).sqrt().max(1.0);
            let (ux, uy) = (dx / len, dy / len);
            let back = (t.0 - ux * 12.0, t.1 - uy * 12.0);
            let tri = vec![
                at(t),
                at((back.0 - uy * 5.0, back.1 + ux * 5.0)),
                at((back.0 + uy * 5.0, back.1 - ux * 5.0)),
            ];
            root.draw(&Polygon::new(tri, c.filled()))
                .map_err(|x| err(&x))?;
        }
    }
    // Labels after every line, each on a white box: no other pair's line runs through one.
    for e in &p.edges {
        let c = col(e.colour);
        let style = centred(TEXT_PX, &c);
        let (tw, th) = root
            .estimate_text_size(&e.label, &style)
            .map_err(|x| err(&x))?;
        let (lx, ly) = at(e.label_at);
        let (hw, hh) = (tw as i32 / 2 + 3, th as i32 / 2 + 2);
        root.draw(&Rectangle::new(
            [(lx - hw, ly - hh), (lx + hw, ly + hh)],
            WHITE.filled(),
        ))
        .map_err(|x| err(&x))?;
        root.draw(&Text::new(e.label.clone(), (lx, ly), style))
            .map_err(|x| err(&x))?;
    }
    for n in &p.nodes {
        root.draw(&Circle::new(
            at((n.x, n.y)),
            NODE_R as i32,
            RGBColor(245, 245, 245).filled(),
        ))
        .map_err(|e| err(&e))?;
        root.draw(&Circle::new(
            at((n.x, n.y)),
            NODE_R as i32,
            BLACK.stroke_width(2),
        ))
        .map_err(|e| err(&e))?;
        root.draw(&Text::new(
            n.name.clone(),
            at((n.x, n.y)),
            centred(TEXT_PX, &BLACK),
        ))
        .map_err(|e| err(&e))?;
    }
    root.present().map_err(|e| err(&e))?;
    Ok(())
}

/// Draws `fleet_path`'s topology into `out` (.svg or .png).
pub fn run(fleet_path: &Path, out: &Path, show_x: bool) -> anyhow::Result<()> {
    let fleet = hetcomm::load_fleet(fleet_path)?;
    let p = picture(&fleet, show_x);
    match out
        .extension()
        .and_then(|e| e.to_str())
        .map(str::to_ascii_lowercase)
    {
        Some(e) if e == "svg" => {
            std::fs::write(out, svg(&p)).with_context(|| format!("writing {}", out.display()))?
        }
        Some(e) if e == "png" => png(&p, out)?,
        _ => anyhow::bail!("-o {}: the picture must end in .svg or .png", out.display()),
    }
    let plural =
        |n: usize, one: &str, many: &str| format!("{n} {}", if n == 1 { one } else { many });
    eprintln!(
        "wrote {}: {}, {}",
        out.display(),
        plural(p.nodes.len(), "system", "systems"),
        plural(p.edges.len(), "arrow", "arrows")
    );
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    const FLEET: &str = r#"
        name = "t"
        [systems]
        Alpha = 0
        Charlie = 1
        Tango = 2
        [modules]
        Plan = 0
        [transports.wired]
        kind = "inproc"
        [transports.radio]
        kind = "inproc"
        [table]
        columns = ["Alpha", "Charlie", "Tango"]
        Alpha   = ["X", "wired", "X"]
        Charlie = ["wired", "X", "radio"]
        Tango   = ["X", "wired", "X"]
    "#;

    #[test]
    fn the_picture_has_one_arrow_per_direction_and_names_every_system() {
        let fleet = hetcomm::config::parse_str(FLEET, "t.toml", None).unwrap();
        let p = picture(&fleet, true);
        // Alpha⇄Charlie share "wired": one two-headed arrow; Charlie→Tango radio and
        // Tango→Charlie wired: two arrows; Alpha–Tango: X.
        assert_eq!(p.edges.len(), 4);
        let s = svg(&p);
        for label in ["Alpha", "Charlie", "Tango", "wired", "radio", ">X<"] {
            assert!(s.contains(label), "{label} missing from {s}");
        }
        assert_eq!(s.matches("class=\"pair\"").count(), 4);
        assert_eq!(s.matches("class=\"system\"").count(), 3);
        assert_eq!(picture(&fleet, false).edges.len(), 3);
    }

    #[test]
    fn kinds_are_spelt_as_in_fleet_files_and_small_fleets_get_a_small_picture() {
        let fleet = hetcomm::config::parse_str(FLEET, "t.toml", None).unwrap();
        let p = picture(&fleet, false);
        assert_eq!(p.legend[0].0, "wired (inproc)");
        assert_eq!(p.size, 700.0);
        // A label sits off its own line, by more than half its box.
        for e in &p.edges {
            let (dx, dy) = (e.to.0 - e.from.0, e.to.1 - e.from.1);
            let len = (dx * dx + dy * dy).sqrt();
            let (px, py) = (e.label_at.0 - e.from.0, e.label_at.1 - e.from.1);
            let distance = (px * dy - py * dx).abs() / len;
            assert!(
                distance > 11.0,
                "{} is {distance:.1} px from its line",
                e.label
            );
        }
    }

    #[test]
    fn names_are_escaped() {
        assert_eq!(escape("a<b&\"c\""), "a&lt;b&amp;&quot;c&quot;");
    }
}
