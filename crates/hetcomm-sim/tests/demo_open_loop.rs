//! End-to-end run of the demonstration with no communication: the schedule's commands go
//! straight into the rovers' wheels (Charlie at once, Tango 0.5 s later), the virtual
//! environment integrates the scenario, and the report is written to a temp directory.

use hetcomm_sim::kinematics::angle_diff_deg;
use hetcomm_sim::report::{self, plot, CommandKind};
use hetcomm_sim::scenario::{ALPHA, CHARLIE, TANGO};
use hetcomm_sim::{Command, PoseSample, Scenario};
use std::path::{Path, PathBuf};

const DELAYS: [(&str, f64); 2] = [(CHARLIE, 0.0), (TANGO, 0.5)];

fn run() -> hetcomm_sim::OpenLoopRun {
    Scenario::thesis().run_open_loop(&DELAYS).unwrap()
}

fn series<'a>(samples: &'a [PoseSample], rover: &str) -> Vec<&'a PoseSample> {
    samples.iter().filter(|s| s.rover == rover).collect()
}

/// The manoeuvre windows a rover went through, from its command records: (start, end, command).
fn windows(run: &hetcomm_sim::OpenLoopRun, rover: &str, end_s: f64) -> Vec<(f64, f64, Command)> {
    let cmds: Vec<(f64, Command)> = run
        .commands
        .iter()
        .filter(|c| c.rover == rover)
        .map(|c| (c.t_s, Command::from_code(c.code).unwrap()))
        .collect();
    let mut out = vec![(0.0, cmds[0].0, Command::Straight)];
    for (i, &(t, c)) in cmds.iter().enumerate() {
        let next = cmds.get(i + 1).map_or(end_s, |n| n.0);
        out.push((t, next, c));
    }
    out
}

#[test]
fn rovers_follow_the_same_manoeuvres() {
    let run = run();
    let end_s = Scenario::thesis().schedule.end_s();
    let mut turns_by_rover = Vec::new();
    for rover in [ALPHA, CHARLIE, TANGO] {
        let s = series(&run.samples, rover);
        assert_eq!(s.len(), 131, "{rover}: one sample per 0.1 s from 0 to 13 s");
        let mut turns = Vec::new();
        for (start, end, cmd) in windows(&run, rover, end_s) {
            let inside: Vec<&&PoseSample> = s
                .iter()
                .filter(|p| p.t_s >= start - 1e-9 && p.t_s <= end + 1e-9)
                .collect();
            let (a, b) = (inside.first().unwrap().pose, inside.last().unwrap().pose);
            match cmd {
                Command::TurnLeft => {
                    for p in &inside {
                        assert!(
                            (p.pose.x - a.x).abs() < 1e-9,
                            "{rover} x moved while pivoting at {}",
                            p.t_s
                        );
                        assert!(
                            (p.pose.y - a.y).abs() < 1e-9,
                            "{rover} y moved while pivoting at {}",
                            p.t_s
                        );
                    }
                    let turned = (b.theta_deg - a.theta_deg).rem_euclid(360.0);
                    assert!(
                        turned > 90.0,
                        "{rover} turned only {turned}° in {start}..{end}"
                    );
                    turns.push(turned);
                }
                Command::Straight => {
                    for p in &inside {
                        assert_eq!(
                            p.pose.theta_deg, a.theta_deg,
                            "{rover} θ changed while straight at {}",
                            p.t_s
                        );
                    }
                    let dist = ((b.x - a.x).powi(2) + (b.y - a.y).powi(2)).sqrt();
                    assert!(
                        (dist - 10.0 * (end - start)).abs() < 1e-6,
                        "{rover} went {dist} in {start}..{end}"
                    );
                }
                Command::Stop => unreachable!("the thesis schedule has no stop"),
            }
        }
        turns_by_rover.push(turns);
    }
    // Same sequence of manoeuvres: two left turns of 3 s and 2 s at 1 rad/s each.
    for turns in &turns_by_rover {
        assert_eq!(turns.len(), 2);
        assert!((turns[0] - 3f64.to_degrees()).abs() < 1e-6, "{turns:?}");
        assert!((turns[1] - 2f64.to_degrees()).abs() < 1e-6, "{turns:?}");
    }
    // Every rover ends up turned by the same total amount relative to its start.
    for rover in [ALPHA, CHARLIE, TANGO] {
        let s = series(&run.samples, rover);
        let total = angle_diff_deg(s[0].pose.theta_deg, s.last().unwrap().pose.theta_deg);
        assert!(
            (total - (5f64.to_degrees() - 360.0)).abs() < 1e-6,
            "{rover}: {total}"
        );
    }
    for p in &run.samples {
        assert!(p.pose.x.abs() <= 250.0 && p.pose.y.abs() <= 250.0, "{p:?}");
        assert!((0.0..360.0).contains(&p.pose.theta_deg));
    }
}

#[test]
fn run_is_deterministic() {
    assert_eq!(run(), run());
}

#[test]
fn command_tables_of_the_run() {
    let run = run();
    let expected = "\
Table 12: Command timing (s)
         Left Turn Command  Straight Command  Left Turn Command  Straight Command
Alpha                2.000             5.000              8.000            10.000
Charlie              2.000             5.000              8.000            10.000
Tango                2.500             5.500              8.500            10.500
";
    assert_eq!(report::command_timing_matrix(&run.commands), expected);
    let tables = report::command_tables(&run.commands);
    assert!(tables.starts_with(
        "Table 9: Alpha command data\nTime (s)  Command (Sent)\n   2.000  1 – Turn Left\n"
    ));
    assert!(tables.contains(
        "Table 11: Tango command data\nTime (s)  Command (Received)\n   2.500  1 – Turn Left\n"
    ));
    assert_eq!(
        run.commands
            .iter()
            .filter(|c| c.kind == CommandKind::Sent)
            .count(),
        4
    );
    let alpha = report::pose_table(&run.samples, ALPHA);
    let lines: Vec<&str> = alpha.lines().collect();
    assert_eq!(lines.len(), 2 + 14, "title, header, seconds 0..=13");
    assert_eq!(lines[2], "   0.000  -190.494  -200.000    0.000");
    assert_eq!(lines[3], "   1.000  -180.494  -200.000    0.000");
    // At 5 s Alpha has pivoted 3 rad in place.
    assert_eq!(lines[7], "   5.000  -170.494  -200.000  171.887");
}

fn check_png(path: &Path, width: u32, height: u32) {
    let bytes = std::fs::read(path).unwrap();
    assert!(
        bytes.len() > 10 * 1024,
        "{} is only {} bytes",
        path.display(),
        bytes.len()
    );
    assert_eq!(&bytes[..8], b"\x89PNG\r\n\x1a\n", "PNG signature");
    // IHDR must be the first chunk: length 13, type, then big-endian width and height.
    assert_eq!(&bytes[8..16], b"\0\0\0\x0dIHDR");
    let w = u32::from_be_bytes(bytes[16..20].try_into().unwrap());
    let h = u32::from_be_bytes(bytes[20..24].try_into().unwrap());
    assert_eq!((w, h), (width, height), "{}", path.display());
    // Decode fully and make sure the picture is not blank.
    let decoder = png::Decoder::new(std::io::Cursor::new(&bytes));
    let mut reader = decoder.read_info().unwrap();
    let mut buf = vec![0; reader.output_buffer_size().unwrap()];
    let info = reader.next_frame(&mut buf).unwrap();
    assert_eq!((info.width, info.height), (width, height));
    let px = info.color_type.samples();
    let colours: std::collections::HashSet<&[u8]> =
        buf[..info.buffer_size()].chunks_exact(px).collect();
    assert!(
        colours.len() > 50,
        "{} has only {} colours",
        path.display(),
        colours.len()
    );
}

fn out_dir() -> PathBuf {
    PathBuf::from(env!("CARGO_TARGET_TMPDIR")).join("hetcomm-sim-demo")
}

#[test]
fn writes_report_and_plots() {
    let run = run();
    let dir = out_dir();
    let tables = report::write_tables(&dir, &run.commands, &run.samples).unwrap();
    assert_eq!(tables.len(), 4);
    let csv = std::fs::read_to_string(dir.join("poses.csv")).unwrap();
    assert_eq!(csv.lines().count(), 1 + 131 * 3);
    assert_eq!(
        csv.lines().nth(1),
        Some("0.000000,Alpha,-190.494000,-200.000000,0.000000")
    );
    let plots = plot::write_all(&dir, &run.samples, &run.commands, &[]).unwrap();
    let names: Vec<String> = plots
        .iter()
        .map(|p| p.file_name().unwrap().to_string_lossy().into_owned())
        .collect();
    assert_eq!(names, ["x.png", "y.png", "theta.png", "trajectory.png"]);
    for p in &plots[..3] {
        check_png(p, plot::WIDTH, plot::time_series_height(3));
    }
    check_png(&plots[3], plot::WIDTH, plot::TRAJECTORY_HEIGHT);
}

#[test]
fn plots_refuse_empty_input() {
    let dir = out_dir().join("empty");
    assert!(matches!(
        plot::plot_trajectory(&dir, &[]),
        Err(plot::PlotError::NoData)
    ));
    assert!(matches!(
        plot::plot_time_series(&dir, &[], &[], plot::Quantity::X, &[]),
        Err(plot::PlotError::NoData)
    ));
}
