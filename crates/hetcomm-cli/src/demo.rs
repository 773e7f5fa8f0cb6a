//! `hetcomm demo`: the leader–follower demonstration with tables and plots.

use std::path::Path;

use anyhow::Context;
use hetcomm_examples::leader_follower::{self, DemoOptions, Layout, CONTROL_PERIOD};
use hetcomm_sim::report::notes::{self, RunFacts};

use crate::security::SecurityArgs;

/// Flags of `hetcomm demo`.
pub struct DemoArgs<'a> {
    /// Seed of the emulated links.
    pub seed: u64,
    /// Folder for the tables, CSV files, plots and NOTES.md.
    pub out: &'a Path,
    /// A fleet file to use instead of the embedded one.
    pub fleet: Option<&'a Path>,
    /// What the table letter R means (inproc, wired, wifi, bluetooth-classic, ros1, zenoh,
    /// mqtt).
    pub r: &'a str,
    /// What the table letter B means (inproc, wired, wifi, bluetooth-classic, bluetooth,
    /// zenoh, mqtt).
    pub b: &'a str,
    /// The MQTT broker of `--r mqtt` / `--b mqtt` (`host:port` or `mqtt://host:port`).
    pub mqtt_broker: &'a str,
    /// One VE with callbacks instead of one polling VE per rover.
    pub single_ve: bool,
    /// Run in real time instead of virtual time.
    pub realtime: bool,
    /// Followers whose autonomy code runs in another process.
    pub external: Vec<String>,
    /// `--keys` / `--insecure`.
    pub security: &'a SecurityArgs,
    /// Recording, replay or monitor statistics taking part in the run.
    pub hooks: Option<leader_follower::Hooks>,
    /// A scenario file to apply.
    pub scenario: Option<&'a Path>,
}

/// A Zenoh router for `--r zenoh` / `--b zenoh`, in this process, and the transport keys that
/// reach it: every system is a client of it (loopback has no multicast for scouting).
#[cfg(feature = "zenoh")]
fn zenoh_router() -> anyhow::Result<(hetcomm_link_zenoh::router::ZenohRouter, String)> {
    let port = std::net::TcpListener::bind("127.0.0.1:0")?
        .local_addr()?
        .port();
    let endpoint = format!("tcp/127.0.0.1:{port}");
    let router =
        hetcomm_link_zenoh::router::ZenohRouter::start(std::slice::from_ref(&endpoint), false)?;
    let keys = format!(
        "mode = \"client\"\nconnect = [\"{endpoint}\"]\nmulticast_scouting = false\nprefix = \"hetcomm-demo/{}\"\n",
        std::process::id()
    );
    Ok((router, keys))
}

/// The keys of the transports that reach a service: a `zenoh` transport (the demo's router)
/// and an `mqtt` one (the broker of `--mqtt-broker`).
struct ServiceKeys<'a> {
    zenoh: &'a str,
    mqtt: &'a str,
}

/// A transport definition for a letter, from a short name.
fn transport_toml(
    name: &str,
    letter: char,
    spec: &str,
    keys: &ServiceKeys<'_>,
) -> anyhow::Result<String> {
    Ok(match spec {
        "zenoh" => format!("[transports.{name}]\nkind = \"zenoh\"\n{}", keys.zenoh),
        "mqtt" => format!("[transports.{name}]\nkind = \"mqtt\"\n{}", keys.mqtt),
        "inproc" => format!("[transports.{name}]\nkind = \"inproc\"\n"),
        "wired" | "wifi" => format!(
            "[transports.{name}]\nkind = \"emulated\"\nprofile = \"{spec}\"\nattempts = 8\n"
        ),
        // Class 1 radios in open field, as in the shipped fleet files (the profile's default
        // short range would cut Charlie off from Tango).
        "bluetooth-classic" => format!(
            "[transports.{name}]\nkind = \"emulated\"\nprofile = \"bluetooth-classic\"\nattempts = 8\ntx_power_dbm = 20.0\npath_loss_exponent = 2.0\nsensitivity_dbm = -90.0\n"
        ),
        "ros1" if letter == 'R' => format!("[transports.{name}]\nkind = \"ros1\"\n"),
        "bluetooth" if letter == 'B' => format!(
            "[transports.{name}]\nkind = \"bluetooth\"\naddresses = {{ Charlie = \"68:A3:C4:4A:B3:BA\", Tango = \"E4:B3:18:09:09:06\" }}\n"
        ),
        other => anyhow::bail!(
            "--{} {other}: expected inproc, wired, wifi, bluetooth-classic, zenoh, mqtt{}",
            letter.to_ascii_lowercase(),
            if letter == 'R' { ", or ros1" } else { ", or bluetooth" }
        ),
    })
}

/// The embedded fleet with R and B mapped as asked.
fn embedded_fleet(
    single_ve: bool,
    r: &str,
    b: &str,
    keys: &ServiceKeys<'_>,
) -> anyhow::Result<hetcomm::config::Fleet> {
    let base = if single_ve {
        leader_follower::EMBEDDED_SINGLE_VE_FLEET
    } else {
        leader_follower::EMBEDDED_FLEET
    };
    // Replace the two transport sections (everything from [transports.wired] to [table]).
    let start = base
        .find("[transports.wired]")
        .context("embedded fleet layout")?;
    let end = base.find("[table]").context("embedded fleet layout")?;
    let text = format!(
        "{}{}\n{}\n{}",
        &base[..start],
        transport_toml("wired", 'R', r, keys)?,
        transport_toml("radio", 'B', b, keys)?,
        &base[end..]
    );
    Ok(hetcomm::parse_fleet(
        &text,
        "<embedded leader-follower fleet>",
        None,
    )?)
}

/// What to say before a run whose progress bar will not be seen: the bar (drawn on stderr,
/// once per simulated second) needs a terminal, and a real-time run takes as long as the
/// scenario, so without one the user is told to wait.
fn progress_notice(realtime: bool, stderr_is_terminal: bool) -> Option<String> {
    (realtime && !stderr_is_terminal).then(|| {
        // leader_follower::run goes on 2 s past the end of the leader's plan.
        let seconds = hetcomm_sim::Scenario::thesis().schedule.end_s() + 2.0;
        format!(
            "running in real time for about {seconds:.0} s (the progress bar is drawn only when stderr is a terminal)"
        )
    })
}

/// Runs the demonstration and prints its tables and the files written.
pub fn run(args: DemoArgs<'_>) -> anyhow::Result<()> {
    let wants_zenoh = args.fleet.is_none() && (args.r == "zenoh" || args.b == "zenoh");
    // The router lives as long as the run.
    #[cfg(feature = "zenoh")]
    let (_router, zenoh_keys) = match wants_zenoh {
        true => {
            let (router, keys) = zenoh_router()?;
            (Some(router), keys)
        }
        false => (None, String::new()),
    };
    // Without Zenoh compiled in, opening the transport says which feature to rebuild with.
    #[cfg(not(feature = "zenoh"))]
    let zenoh_keys = String::from("mode = \"client\"\nconnect = [\"tcp/127.0.0.1:7447\"]\n");
    let fleet = match args.fleet {
        Some(path) => args.security.load(path)?,
        None => {
            // Every run under a fleet level of its own, so runs sharing a broker do not meet.
            let mqtt_keys = format!(
                "broker = \"{}\"\nfleet = \"hetcomm-demo-{}\"\n",
                args.mqtt_broker,
                std::process::id()
            );
            let keys = ServiceKeys {
                zenoh: &zenoh_keys,
                mqtt: &mqtt_keys,
            };
            let mut fleet = embedded_fleet(args.single_ve, args.r, args.b, &keys)?;
            args.security.apply(&mut fleet)?;
            fleet
        }
    };
    // A bridge stands for a robot that runs ROS, not hetcomm: without its kind compiled in,
    // the simulator would quietly play that robot itself.
    if let Some((t, feature)) = hetcomm::registry().unbuilt_bridges(&fleet).first() {
        anyhow::bail!(
            "transport `{}` is a {} (its robot runs ROS, not hetcomm), which this hetcomm is \
             built without: rebuild with `--features {feature}`",
            t.name,
            t.kind
        );
    }
    // A real transport the demo would switch to real time for must be compiled in, or the
    // run would announce real time and then fail.
    for kind in [args.r, args.b] {
        let Some(kind) = hetcomm::config::TransportKind::parse(kind) else {
            continue; // an emulated profile (wired, wifi, …)
        };
        if let (None, Some(feature)) = (args.fleet, hetcomm::registry().feature_for(kind)) {
            anyhow::bail!(
                "`{kind}` is not built into this hetcomm: rebuild with `--features {feature}`"
            );
        }
    }
    // In virtual time the simulator replaces every link with a simulated one, so `--r ros1`
    // would never reach the ROS master (nor `zenoh` a Zenoh router): a real transport forces
    // real time.
    let wants_mqtt = args.fleet.is_none() && (args.r == "mqtt" || args.b == "mqtt");
    let realtime =
        args.realtime || (args.fleet.is_none() && args.r == "ros1") || wants_zenoh || wants_mqtt;
    // A robot behind a bridge transport (it runs ROS, not hetcomm) moves in real time.
    let bridged = hetcomm::registry().bridged_robots(&fleet);
    if !bridged.is_empty() && !args.realtime {
        eprintln!(
            "{} is a robot behind a bridge (it runs ROS or plain MQTT, not hetcomm): running in real time (as with --realtime)",
            bridged.join(", ")
        );
    }
    let realtime = realtime || !bridged.is_empty();
    if realtime && !args.realtime && bridged.is_empty() {
        eprintln!(
            "--{} uses a real {}: running in real time (as with --realtime)",
            if ["ros1", "zenoh", "mqtt"].contains(&args.r) {
                "r"
            } else {
                "b"
            },
            match args.r {
                "ros1" => "ROS master",
                "mqtt" => "MQTT broker",
                "zenoh" => "Zenoh router",
                _ if args.b == "mqtt" => "MQTT broker",
                _ => "Zenoh router",
            }
        );
    }
    let layout = if args.single_ve {
        Layout::SingleVe
    } else {
        Layout::ThreeVe
    };
    let links = match args.fleet {
        Some(path) => format!("fleet {}", path.display()),
        None => format!("R = {}, B = {}", args.r, args.b),
    };
    eprintln!(
        "leader–follower demonstration: Alpha → Charlie → Tango, {} ({}), {links}, seed {}",
        if args.single_ve {
            "one VE with callbacks"
        } else {
            "three polling VEs"
        },
        if realtime {
            "real time"
        } else {
            "virtual time"
        },
        args.seed
    );
    let terminal = std::io::IsTerminal::is_terminal(&std::io::stderr());
    if let Some(notice) = progress_notice(realtime, terminal) {
        eprintln!("{notice}");
    }
    let scenario = match args.scenario {
        Some(path) => match hetcomm::config::scenario::load_scenario(path, &fleet) {
            Ok(sc) => Some(sc),
            Err(errors) => anyhow::bail!("{errors}"),
        },
        None => None,
    };
    let options = DemoOptions {
        seed: args.seed,
        layout,
        fleet: Some(fleet),
        realtime,
        external: args.external.clone(),
        progress: terminal,
        hooks: args.hooks,
        scenario,
    };
    let report = leader_follower::run(&options).map_err(|e| anyhow::anyhow!("{e}"))?;
    println!("{}", leader_follower::tables(&report));
    println!(
        "# The thesis's Tables 9–15 beside this run's\n\n{}",
        leader_follower::beside_thesis(&report)
    );
    for robot in &report.bridged {
        println!(
            "{robot} ran behind a bridge (ROS or plain MQTT, not hetcomm): its commands went out as velocity (Twist) at the \
             control rate, its poses are its odometry placed at its starting pose, and its \
             \"received\" times are when its odometry first showed each command's velocity.\n"
        );
    }
    let mut scenario_text = String::new();
    if options.scenario.is_some() {
        scenario_text = report.scenario.join("\n") + "\n";
        if !realtime {
            // Virtual time costs milliseconds: the same seed without the scenario shows what
            // it changed.
            let without = leader_follower::run(&DemoOptions {
                scenario: None,
                hooks: None,
                progress: false,
                ..options.clone()
            })
            .map_err(|e| anyhow::anyhow!("{e}"))?;
            scenario_text.push('\n');
            scenario_text.push_str(&leader_follower::scenario::compare(&report, &without));
        }
        println!("{scenario_text}");
    }
    // How and why these figures differ from the thesis's: printed after the tables and
    // written beside them.
    let note = notes::thesis_comparison(
        &report.commands,
        &report.samples,
        &RunFacts {
            realtime,
            control_period_s: CONTROL_PERIOD.as_secs_f64(),
        },
    );
    println!("{note}");
    let mut files =
        leader_follower::write_outputs(&report, args.out).map_err(|e| anyhow::anyhow!("{e}"))?;
    let note_path = args.out.join(notes::NOTES_FILE);
    std::fs::write(&note_path, &note)
        .with_context(|| format!("writing {}", note_path.display()))?;
    files.push(note_path);
    if !scenario_text.is_empty() {
        let path = args.out.join("scenario.txt");
        std::fs::write(&path, &scenario_text)
            .with_context(|| format!("writing {}", path.display()))?;
        files.push(path);
    }
    eprintln!(
        "{:.1} s of scenario in {:.3} s of wall time; wrote:",
        report.simulated_s,
        report.wall.as_secs_f64()
    );
    for f in files {
        eprintln!("  {}", f.display());
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::progress_notice;

    #[test]
    fn real_time_without_a_terminal_says_how_long_to_wait() {
        assert_eq!(
            progress_notice(true, false).as_deref(),
            Some("running in real time for about 15 s (the progress bar is drawn only when stderr is a terminal)")
        );
        // A terminal shows the bar; virtual time is over in milliseconds.
        assert_eq!(progress_notice(true, true), None);
        assert_eq!(progress_notice(false, false), None);
    }
}
