//! How the `rtt` and `oneway` sections measure their paths: each path's run again in every
//! round, the paths interleaved within a round (so a machine whose speed drifts moves every
//! path alike), each path's median kept, and secured paths paired with their unsecured twins
//! round by round.

use crate::report::Row;
use crate::{hc, log, raw, stats, Options};

/// One measurement of one path, run again in each round.
pub type Run<T> = Box<dyn Fn() -> Result<T, String>>;

/// The raw and hetcomm paths the options ask for, each with its measurement.
pub fn bench_paths<T>(
    o: &Options,
    raws: &[raw::RawKind],
    hc_paths: &[(hc::Kind, bool)],
    raw_run: impl Fn(raw::RawKind) -> Run<T>,
    hc_run: impl Fn(hc::Kind, bool) -> Run<T>,
) -> Vec<(String, Run<T>)> {
    raws.iter()
        .map(|&k| (k.name().to_string(), raw_run(k)))
        .chain(
            hc_paths
                .iter()
                .map(|&(k, acked)| (hc::path_name(k, acked), hc_run(k, acked))),
        )
        .filter(|(name, _)| o.path_wanted(name))
        .collect()
}

/// Runs every path once per round, the paths interleaved within each round, and gives each
/// path's run with the median `key` (see [`median_by`]).
pub fn interleaved<T>(
    quick: bool,
    what: &str,
    paths: Vec<(String, Run<T>)>,
    rounds: usize,
    key: impl Fn(&T) -> f64 + Copy,
) -> Vec<(String, Result<T, String>)> {
    interleaved_rounds(quick, what, paths, rounds, key)
        .into_iter()
        .map(|(name, median, _)| (name, median))
        .collect()
}

/// A path's name, its run with the median key, and its key per round (`None`: that round
/// failed).
pub type Measured<T> = (String, Result<T, String>, Vec<Option<f64>>);

/// As [`interleaved`], with each path's `key` per round too (`None` where that round failed),
/// so that two paths run one after the other can be compared round by round.
pub fn interleaved_rounds<T>(
    quick: bool,
    what: &str,
    paths: Vec<(String, Run<T>)>,
    rounds: usize,
    key: impl Fn(&T) -> f64 + Copy,
) -> Vec<Measured<T>> {
    let mut results: Vec<Vec<Result<T, String>>> = paths.iter().map(|_| Vec::new()).collect();
    for round in 0..rounds {
        for ((name, run), out) in paths.iter().zip(results.iter_mut()) {
            log(quick, &format!("{what} {name} (round {})", round + 1));
            out.push(run());
        }
    }
    paths
        .into_iter()
        .zip(results)
        .map(|((name, _), runs)| {
            let per_round = runs.iter().map(|r| r.as_ref().ok().map(key)).collect();
            (name, median_by(runs, key), per_round)
        })
        .collect()
}

/// For every secured path among `measured` whose unsecured twin was measured too (run just
/// before it in every round), a `paired` row: the secured rate over the twin's, round by
/// round, and their median. On a machine whose speed drifts between rounds, comparing each
/// round's two runs, made seconds apart, is steadier than comparing the two medians.
pub fn paired_rows(section_size: usize, measured: &[(String, Vec<Option<f64>>)]) -> Vec<Row> {
    let mut rows = Vec::new();
    for (name, secured) in measured {
        let Some(twin) = name
            .strip_prefix("hetcomm-")
            .and_then(|rest| rest.split_once("-secured-"))
            .map(|(transport, mode)| format!("hetcomm-{transport}-{mode}"))
        else {
            continue;
        };
        let Some((_, plain)) = measured.iter().find(|(n, _)| *n == twin) else {
            continue;
        };
        let ratios: Vec<f64> = secured
            .iter()
            .zip(plain)
            .filter_map(|(s, p)| match (s, p) {
                (Some(s), Some(p)) if *p > 0.0 => Some(s / p),
                _ => None,
            })
            .collect();
        if let Some(row) = Row::paired(name, &twin, section_size, &ratios) {
            rows.push(row);
        }
    }
    rows
}

/// The run with the median p50 among those that succeeded (the first error if none did).
pub fn median_run(runs: Vec<Result<stats::Latency, String>>) -> Result<stats::Latency, String> {
    median_by(runs, |l| l.p50)
}

/// The run with the median `key` among those that succeeded (the first error if none did).
pub fn median_by<T>(
    mut runs: Vec<Result<T, String>>,
    key: impl Fn(&T) -> f64,
) -> Result<T, String> {
    let mut ok: Vec<T> = Vec::new();
    let mut first_err = None;
    for r in runs.drain(..) {
        match r {
            Ok(l) => ok.push(l),
            Err(e) => {
                first_err.get_or_insert(e);
            }
        }
    }
    if ok.is_empty() {
        return Err(first_err.unwrap_or_else(|| "no run".into()));
    }
    ok.sort_by(|a, b| key(a).total_cmp(&key(b)));
    let mid = ok.len() / 2;
    Ok(ok.swap_remove(mid))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Each secured path is paired with its unsecured twin round by round; a round where
    /// either failed is left out, and a path without a twin gets no row.
    #[test]
    fn secured_paths_are_paired_with_their_twins_round_by_round() {
        let measured = vec![
            (
                "hetcomm-udp-unack".to_string(),
                vec![Some(100.0), Some(100.0), None],
            ),
            (
                "hetcomm-udp-secured-unack".to_string(),
                vec![Some(90.0), Some(80.0), Some(70.0)],
            ),
            ("hetcomm-tcp-secured-ack".to_string(), vec![Some(1.0)]),
            ("raw-udp".to_string(), vec![Some(5.0)]),
        ];
        let rows = paired_rows(65536, &measured);
        assert_eq!(rows.len(), 1);
        let r = &rows[0];
        assert_eq!(
            (r.section, r.path.as_str(), r.size),
            ("paired", "hetcomm-udp-secured-unack", 65536)
        );
        assert_eq!(r.get("rounds"), Some(2.0));
        assert_eq!(r.get("ratio_median"), Some(0.9));
        assert_eq!(r.note, "over hetcomm-udp-unack, round by round: 90%, 80%");
    }
}
