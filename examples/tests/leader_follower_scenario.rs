//! The demonstration's example scenario (`scenario-tango-cut.toml`): Tango is cut off from
//! Charlie from 4.5 s to 7.5 s, and the run shows it exactly there, repeatably for a seed.

use hetcomm_examples::leader_follower::{self, scenario, DemoOptions, DemoReport};
use hetcomm_sim::report::CommandKind;

fn run(seed: u64, with_cut: bool) -> DemoReport {
    let fleet = hetcomm::config::parse_str(
        leader_follower::EMBEDDED_FLEET,
        "<embedded leader-follower fleet>",
        None,
    )
    .unwrap();
    let sc = with_cut.then(|| {
        hetcomm::config::scenario::parse_scenario(
            scenario::TANGO_CUT,
            "scenario-tango-cut.toml",
            &fleet,
        )
        .unwrap()
    });
    leader_follower::run(&DemoOptions {
        seed,
        scenario: sc,
        ..DemoOptions::default()
    })
    .unwrap_or_else(|e| panic!("seed {seed}: demo failed: {e}"))
}

fn received(r: &DemoReport, rover: &str) -> Vec<(f64, i64)> {
    r.commands
        .iter()
        .filter(|c| c.rover == rover && c.kind == CommandKind::Received)
        .map(|c| (c.t_s, c.code))
        .collect()
}

#[test]
fn cutting_tango_off_delays_exactly_the_command_sent_during_the_cut() {
    for seed in [1, 2, 3] {
        let (cut, clear) = (run(seed, true), run(seed, false));
        // Charlie's link is untouched.
        assert_eq!(
            received(&cut, "Charlie"),
            received(&clear, "Charlie"),
            "seed {seed}"
        );
        let (t_cut, t_clear) = (received(&cut, "Tango"), received(&clear, "Tango"));
        let before = |v: &[(f64, i64)]| v.iter().filter(|c| c.0 < 4.5).copied().collect::<Vec<_>>();
        assert_eq!(
            before(&t_cut),
            before(&t_clear),
            "seed {seed}: before the cut"
        );
        // What arrived in the cut without it arrives after the cut, or never (the radio's
        // attempts ran out); everything after comes as before.
        let codes = |v: &[(f64, i64)], from: f64| {
            v.iter()
                .filter(|c| c.0 >= from)
                .map(|c| c.1)
                .collect::<Vec<_>>()
        };
        let in_cut: Vec<i64> = t_clear
            .iter()
            .filter(|c| (4.5..7.5).contains(&c.0))
            .map(|c| c.1)
            .collect();
        assert!(
            !in_cut.is_empty(),
            "seed {seed}: the cut should catch a command"
        );
        let after = codes(&t_cut, 7.5);
        let late = [in_cut.clone(), codes(&t_clear, 7.5)].concat();
        assert!(
            after == late || after == codes(&t_clear, 7.5),
            "seed {seed}: after the cut {after:?}, expected {late:?} or without {in_cut:?}"
        );
        // Nothing reaches Tango during the cut.
        assert!(
            t_cut.iter().all(|(t, _)| !(4.5..7.5).contains(t)),
            "seed {seed}: {t_cut:?}"
        );
        // The scenario's report names the cut and counts the frames it dropped.
        assert!(
            cut.scenario
                .iter()
                .any(|l| l.contains("partition (cut): Charlie→Tango")),
            "{:?}",
            cut.scenario
        );
        assert!(
            cut.scenario
                .iter()
                .any(|l| l.starts_with("  Charlie: frames cut")),
            "{:?}",
            cut.scenario
        );
        // Tango pivoted longer, so it ends elsewhere; repeatable for the seed.
        let text = scenario::compare(&cut, &clear);
        assert!(text.contains("Tango ends at"), "{text}");
        assert_eq!(received(&run(seed, true), "Tango"), t_cut, "seed {seed}");
    }
}

/// An RGB image read back from a PNG file.
struct Image {
    width: usize,
    rgb: Vec<u8>,
}

impl Image {
    fn read(path: &std::path::Path) -> Image {
        let file = std::io::BufReader::new(std::fs::File::open(path).unwrap());
        let mut reader = png::Decoder::new(file).read_info().unwrap();
        let mut buf = vec![0; reader.output_buffer_size().unwrap()];
        let info = reader.next_frame(&mut buf).unwrap();
        assert_eq!(info.color_type, png::ColorType::Rgb);
        buf.truncate(info.buffer_size());
        Image {
            width: info.width as usize,
            rgb: buf,
        }
    }

    fn at(&self, x: usize, y: usize) -> [u8; 3] {
        let i = 3 * (y * self.width + x);
        [self.rgb[i], self.rgb[i + 1], self.rgb[i + 2]]
    }

    /// Columns in which at least `min` pixels of `rows` satisfy `is`.
    fn columns(
        &self,
        rows: std::ops::Range<usize>,
        min: usize,
        is: impl Fn([u8; 3]) -> bool,
    ) -> Vec<usize> {
        (0..self.width)
            .filter(|&x| rows.clone().filter(|&y| is(self.at(x, y))).count() >= min)
            .collect()
    }
}

/// Runs of nearby columns (a 2-pixel line may be drawn as its two edges), as their centres.
fn centres(columns: &[usize]) -> Vec<f64> {
    let mut runs: Vec<Vec<usize>> = Vec::new();
    for &c in columns {
        match runs.last_mut() {
            Some(run) if run.last().is_some_and(|&l| c - l <= 3) => run.push(c),
            _ => runs.push(vec![c]),
        }
    }
    runs.iter()
        .map(|r| r.iter().sum::<usize>() as f64 / r.len() as f64)
        .collect()
}

#[test]
fn the_plots_shade_the_cut_where_it_happened_with_its_label() {
    use hetcomm_sim::report::plot::{time_series_height, BAND_FILL, BAND_TEXT};

    let report = run(1, true);
    assert_eq!(report.bands.len(), 1, "{:?}", report.bands);
    let band = &report.bands[0];
    assert_eq!(band.label, "partition Charlie–Tango");
    assert!(
        (band.start_s - 4.5).abs() < 1e-3 && (band.end_s - 7.5).abs() < 1e-3,
        "{band:?}"
    );
    assert!(run(1, false).bands.is_empty());

    let dir = std::env::temp_dir().join(format!("hetcomm-cut-plots-{}", std::process::id()));
    let files = leader_follower::write_outputs(&report, &dir).unwrap();
    for name in ["x.png", "y.png", "theta.png"] {
        assert!(files.contains(&dir.join(name)), "{files:?}");
        let img = Image::read(&dir.join(name));
        // The first panel (Alpha's) lies below the header; three panels share the rest.
        let header = time_series_height(3) as usize - 3 * 230;
        let panel = header..header + 230;
        // Alpha's command times are dashed grey lines (black at 55 % on white): rulers for
        // the time axis, independent of how the band is drawn.
        let sent: Vec<f64> = report
            .commands
            .iter()
            .filter(|c| c.rover == "Alpha" && c.kind == CommandKind::Sent)
            .map(|c| c.t_s)
            .collect();
        let grey = |p: [u8; 3]| p[0] == p[1] && p[1] == p[2] && (105..=125).contains(&p[0]);
        let rulers = centres(&img.columns(panel.clone(), 40, grey));
        assert_eq!(
            rulers.len(),
            sent.len(),
            "{name}: rulers {rulers:?} for {sent:?}"
        );
        let (t0, t1) = (sent[0], sent[sent.len() - 1]);
        let (x0, x1) = (rulers[0], rulers[rulers.len() - 1]);
        let px = |t: f64| x0 + (t - t0) * (x1 - x0) / (t1 - t0);
        // The band fills exactly 4.5 s to 7.5 s (to a pixel or two of rounding).
        let shaded = img.columns(panel.clone(), 40, |p| {
            p == [BAND_FILL.0, BAND_FILL.1, BAND_FILL.2]
        });
        let (first, last) = (shaded[0] as f64, shaded[shaded.len() - 1] as f64);
        assert!(
            (first - px(4.5)).abs() <= 2.0 && (last - px(7.5)).abs() <= 2.0,
            "{name}: shaded columns {first}–{last}, expected {:.1}–{:.1}",
            px(4.5),
            px(7.5)
        );
        // One band: between its edges, only grid lines, the command at 5 s and the label
        // leave columns with fewer shaded pixels.
        assert!(
            shaded.len() as f64 >= 0.9 * (last - first + 1.0),
            "{name}: {} shaded columns in {first}–{last}",
            shaded.len()
        );
        // Its label is written inside it, in every panel.
        for k in 0..3 {
            // The top of the plotting area (34 px below the panel's top).
            let top = header + 230 * k + 34;
            let rows = top..top + 24;
            // The label's colour, or its smoothed edges over the band or the white.
            let brownish = |[r, g, b]: [u8; 3]| {
                (BAND_TEXT.0..200).contains(&r)
                    && r > g.saturating_add(30)
                    && g > b.saturating_add(20)
            };
            let text = img.columns(rows, 1, brownish);
            // (A data line crossing a dashed one makes a few such columns elsewhere.)
            let inside = text
                .iter()
                .filter(|&&c| (c as f64) >= first && (c as f64) <= last)
                .count();
            assert!(inside > 100, "{name}, panel {k}: label columns {inside}");
        }
    }
    if std::env::var_os("KEEP_PLOTS").is_none() {
        let _ = std::fs::remove_dir_all(&dir);
    }
}
