//! The experiment on real transports in real time: the same counting, with the wall clock and
//! real links (here UDP on 127.0.0.1 for R and an in-process link for B).

use hetcomm_experiments::reliability::{self, Mode, ReliabilityConfig};

#[test]
fn the_experiment_runs_on_real_links_in_real_time() {
    let free = || {
        std::net::UdpSocket::bind("127.0.0.1:0")
            .unwrap()
            .local_addr()
            .unwrap()
            .port()
    };
    let text = format!(
        r#"
[systems]
Bravo = 0
Charlie = 1
Delta = 2
[modules]
Plan = 0
[transports.ros]
kind = "udp"
letter = "R"
endpoints = {{ Bravo = "127.0.0.1:{}", Charlie = "127.0.0.1:{}", Delta = "127.0.0.1:{}" }}
[transports.bt]
kind = "inproc"
letter = "B"
[table]
columns = ["Bravo", "Charlie", "Delta"]
Bravo   = ["X", "R", "B"]
Charlie = ["B", "X", "R"]
Delta   = ["R", "B", "X"]
"#,
        free(),
        free(),
        free()
    );
    let fleet = hetcomm::config::parse_str(&text, "realtime.toml", None).unwrap();
    let config = ReliabilityConfig {
        trials: 2,
        realtime: true,
        modes: Mode::ALL.to_vec(),
        ..ReliabilityConfig::default()
    };
    let report = reliability::run(&fleet, &config).expect("real-time run");
    for mode in Mode::ALL {
        let m = report.mode(mode).expect("mode ran");
        assert_eq!(m.messages, 42, "{mode}");
        assert_eq!(m.received, 42, "{mode}: {m:#?}");
        assert_eq!(m.duplicates_delivered, 0, "{mode}");
        assert_eq!(m.accounting.in_flight, 0, "{mode}");
    }
}
