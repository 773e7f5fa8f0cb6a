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
