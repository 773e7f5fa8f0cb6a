//! Scale: many systems in one process (broadcast cost, memory per system) and the
//! virtual-time simulator's speed.

use std::time::{Duration, Instant};

use std::fmt::Write;

use hetcomm::config::Fleet;
use hetcomm::sim::{SimFleet, SimOptions};
use hetcomm::{LocalFleet, SystemId, Time};

use crate::child::DATA;

/// A star fleet: `Hub` talks to every leaf and every leaf to `Hub` over one transport of
/// `kind`; one module `M`. The systems and the transport come from a fleet file; the table's
/// 2 × (n − 1) pairs are put into the [`Fleet`] directly: written out, the table of a
/// 10 000-system star would be 100 M cells (400 MB of text to parse) of which all but
/// 20 000 are `X`.
pub fn star_fleet(n: usize, kind: &str, acked: bool) -> Result<Fleet, String> {
    let n = n.max(2);
    let mut t = String::with_capacity(n * 16 + 256);
    t.push_str("[systems]\nHub = 0\n");
    for i in 1..n {
        let _ = writeln!(t, "S{i} = {i}");
    }
    t.push_str("[modules]\nM = 0\n[inbox]\ncapacity = 4096\n[transports.t]\n");
    let delivery = if acked {
        "acknowledged"
    } else {
        "unacknowledged"
    };
    let _ = writeln!(t, "kind = \"{kind}\"\ndelivery = \"{delivery}\"");
    let mut fleet =
        hetcomm::config::parse_str(&t, "bench-star.toml", None).map_err(|e| e.to_string())?;
    let transport = fleet
        .transports
        .iter()
        .position(|t| t.name == "t")
        .ok_or("the star fleet has no transport `t`")?;
    let hub = fleet.systems[0].id;
    let leaves: Vec<SystemId> = fleet.systems[1..].iter().map(|s| s.id).collect();
    for leaf in leaves {
        fleet.table.insert((hub, leaf), transport);
        fleet.table.insert((leaf, hub), transport);
    }
    Ok(fleet)
}

/// Resident set size of this process, bytes (0 if /proc is unreadable).
pub fn rss_bytes() -> u64 {
    let page = {
        // SAFETY: sysconf has no preconditions.
        let p = unsafe { libc::sysconf(libc::_SC_PAGESIZE) };
        if p > 0 {
            p as u64
        } else {
            4096
        }
    };
    std::fs::read_to_string("/proc/self/statm")
        .ok()
        .and_then(|s| s.split_whitespace().nth(1)?.parse::<u64>().ok())
        .map(|pages| pages * page)
        .unwrap_or(0)
}

/// What one fleet size gave.
#[derive(Clone, Debug, Default)]
pub struct ScaleResult {
    /// Systems in the fleet.
    pub systems: usize,
    /// Wall time to parse and open the fleet, seconds.
    pub open_s: f64,
    /// RSS growth from opening, per system, bytes.
    pub rss_per_system: f64,
    /// One unacknowledged broadcast from the hub, divided by the destinations, ns.
    pub broadcast_ns_per_dest: f64,
    /// The same with acknowledged delivery (tickets not waited for), ns.
    pub broadcast_ack_ns_per_dest: f64,
}

fn broadcast_cost(n: usize, acked: bool, rounds: u32) -> Result<(f64, f64, f64), String> {
    let fleet = star_fleet(n, "inproc", acked)?;
    let before = rss_bytes();
    let t0 = Instant::now();
    let f = LocalFleet::open(fleet).map_err(|e| e.to_string())?;
    let open_s = t0.elapsed().as_secs_f64();
    let after = rss_bytes();
    let hub = f
        .system("Hub")
        .and_then(|s| s.module("M"))
        .map_err(|e| e.to_string())?;
    let payload = [7u8; 64];
    // One untimed round warms caches and allocations.
    let _ = hub.broadcast_raw("M", DATA, &payload, Default::default());
    let mut total = Duration::ZERO;
    for _ in 0..rounds {
        let t = Instant::now();
        let ticket = hub
            .broadcast_raw("M", DATA, &payload, Default::default())
            .map_err(|e| e.to_string())?;
        total += t.elapsed();
        drop(ticket);
    }
    let per_dest = total.as_nanos() as f64 / rounds.max(1) as f64 / (n - 1).max(1) as f64;
    let rss = after.saturating_sub(before) as f64 / n as f64;
    Ok((open_s, rss, per_dest))
}

/// Broadcast cost and memory for a fleet of `n` systems in this process.
pub fn scale(n: usize, rounds: u32) -> Result<ScaleResult, String> {
    let (open_s, rss, unack) = broadcast_cost(n, false, rounds)?;
    let (_, _, ack) = broadcast_cost(n, true, rounds)?;
    Ok(ScaleResult {
        systems: n,
        open_s,
        rss_per_system: rss,
        broadcast_ns_per_dest: unack,
        broadcast_ack_ns_per_dest: ack,
    })
}

/// The leader–follower demonstration in virtual time: (simulated s, wall s).
pub fn leader_follower() -> Result<(f64, f64), String> {
    let opts = hetcomm_examples::leader_follower::DemoOptions::default();
    let r = hetcomm_examples::leader_follower::run(&opts).map_err(|e| e.to_string())?;
    Ok((r.simulated_s, r.wall.as_secs_f64()))
}

/// What a simulated fleet run gave.
#[derive(Clone, Debug, Default)]
pub struct SimResult {
    /// Systems.
    pub systems: usize,
    /// Wall seconds to open the fleet in the simulator.
    pub open_s: f64,
    /// RSS growth from opening, per system, bytes.
    pub rss_per_system: f64,
    /// Simulated seconds.
    pub simulated_s: f64,
    /// Wall seconds (opening excluded).
    pub wall_s: f64,
    /// Messages taken out of inboxes.
    pub delivered: u64,
}

/// A star fleet of `n` systems in `SimFleet` (acknowledged links): every 100 ms of virtual
/// time each leaf sends a 64-byte status to the hub and the hub broadcasts a 64-byte command;
/// every module drains its inbox.
pub fn sim_fleet(n: usize, simulated_s: f64) -> Result<SimResult, String> {
    let fleet = star_fleet(n, "inproc", true)?;
    let before = rss_bytes();
    let t_open = Instant::now();
    let sim = SimFleet::open(fleet, SimOptions::default()).map_err(|e| e.to_string())?;
    let open_s = t_open.elapsed().as_secs_f64();
    let rss_per_system = rss_bytes().saturating_sub(before) as f64 / n.max(1) as f64;
    let modules = sim
        .systems()
        .iter()
        .map(|c| c.module("M"))
        .collect::<Result<Vec<_>, _>>()
        .map_err(|e| e.to_string())?;
    let payload = [7u8; 64];
    let period_us = 100_000u64;
    let steps = (simulated_s * 1e6 / period_us as f64).ceil() as u64;
    let mut delivered = 0u64;
    let t0 = Instant::now();
    for step in 1..=steps {
        for (i, m) in modules.iter().enumerate() {
            if i == 0 {
                let _ = m.broadcast_raw("M", DATA, &payload, Default::default());
            } else {
                let _ = m.send_raw("Hub", "M", DATA, &payload, Default::default());
            }
        }
        sim.run_until(Time::from_micros(step * period_us));
        for m in &modules {
            while m.try_recv_raw().is_some() {
                delivered += 1;
            }
        }
    }
    Ok(SimResult {
        systems: n,
        open_s,
        rss_per_system,
        simulated_s: sim.now().as_secs_f64(),
        wall_s: t0.elapsed().as_secs_f64(),
        delivered,
    })
}
