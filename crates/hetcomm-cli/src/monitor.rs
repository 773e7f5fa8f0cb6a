//! `hetcomm monitor`: per-pair statistics of a live fleet, refreshed once a second, from the
//! reports that processes publish to the monitor's UDP address
//! ([`hetcomm_record::stats`] explains the design).

use std::io::{IsTerminal, Write};
use std::net::UdpSocket;
use std::path::Path;
use std::time::{Duration, Instant};

use anyhow::Context;
use hetcomm_record::stats::{MonitorState, PairRow, SystemRow};
use ratatui::crossterm::event::{self, Event, KeyCode, KeyModifiers};
use ratatui::layout::{Constraint, Layout};
use ratatui::style::{Modifier, Style};
use ratatui::widgets::{Block, Paragraph, Row, Table};

/// Flags of `hetcomm monitor`.
pub struct MonitorArgs<'a> {
    /// The fleet file.
    pub fleet: &'a Path,
    /// UDP address to receive reports on.
    pub listen: &'a str,
    /// JSON lines instead of the terminal view.
    pub json: bool,
    /// Exit after this long.
    pub duration: Option<Duration>,
    /// Also serve the statistics over the Foxglove WebSocket protocol on this `host:port`.
    pub foxglove: Option<&'a str>,
}

/// Runs the monitor until `q` / Ctrl-C (terminal view), the duration, or a closed stdout
/// (JSON lines).
pub fn run(args: MonitorArgs<'_>) -> anyhow::Result<()> {
    let fleet = hetcomm::load_fleet(args.fleet)?;
    let addr = hetcomm_record::stats::resolve(args.listen)
        .map_err(|e| anyhow::anyhow!("--listen {}: {e}", args.listen))?;
    let socket = UdpSocket::bind(addr).with_context(|| format!("binding {addr}"))?;
    socket.set_read_timeout(Some(Duration::from_millis(50)))?;
    let title = format!(
        "hetcomm monitor — fleet {} ({} systems) — reports on udp {} (HETCOMM_MONITOR={})",
        fleet.name.as_deref().unwrap_or("(unnamed)"),
        fleet.systems.len(),
        socket.local_addr()?,
        socket.local_addr()?
    );
    if !args.json && !std::io::stdout().is_terminal() {
        anyhow::bail!("stdout is not a terminal: use --json for a script");
    }
    let view = args
        .foxglove
        .map(|addr| crate::foxglove::start(addr, "hetcomm monitor"))
        .transpose()?;
    let started = Instant::now();
    let mut state = MonitorState::default();
    let mut buf = vec![0u8; 65536];
    let mut next_refresh = Instant::now();
    let mut terminal = (!args.json).then(ratatui::init);
    let result = (|| -> anyhow::Result<()> {
        loop {
            if args.duration.is_some_and(|d| started.elapsed() >= d) {
                return Ok(());
            }
            match socket.recv_from(&mut buf) {
                Ok((n, _)) => state.ingest_bytes(&buf[..n], Instant::now()),
                Err(e)
                    if matches!(
                        e.kind(),
                        std::io::ErrorKind::WouldBlock | std::io::ErrorKind::TimedOut
                    ) => {}
                Err(e) => return Err(e.into()),
            }
            if let Some(t) = terminal.as_mut() {
                while event::poll(Duration::ZERO)? {
                    if let Event::Key(k) = event::read()? {
                        let ctrl_c = k.code == KeyCode::Char('c')
                            && k.modifiers.contains(KeyModifiers::CONTROL);
                        if k.code == KeyCode::Char('q') || k.code == KeyCode::Esc || ctrl_c {
                            return Ok(());
                        }
                    }
                }
                let _ = t;
            }
            let now = Instant::now();
            if now < next_refresh {
                continue;
            }
            next_refresh = now + Duration::from_secs(1);
            let pairs = state.pairs();
            let systems = state.systems(now);
            if let Some(v) = &view {
                v.publish(&pairs, &systems)?;
            }
            match terminal.as_mut() {
                Some(t) => {
                    t.draw(|f| draw(f, &title, &pairs, &systems, state.bad_reports))?;
                }
                None => {
                    let line = serde_json::json!({
                        "t_s": started.elapsed().as_secs_f64(),
                        "pairs": pairs,
                        "systems": systems,
                        "bad_reports": state.bad_reports,
                    });
                    let mut out = std::io::stdout().lock();
                    if writeln!(out, "{line}").and_then(|_| out.flush()).is_err() {
                        return Ok(()); // stdout closed: the script is done with us
                    }
                }
            }
        }
    })();
    if terminal.is_some() {
        ratatui::restore();
    }
    result
}

fn latency(us: Option<u64>) -> String {
    match us {
        Some(us) if us >= 10_000 => format!("{:.0} ms", us as f64 / 1e3),
        Some(us) if us >= 1_000 => format!("{:.1} ms", us as f64 / 1e3),
        Some(us) => format!("{us} µs"),
        None => "–".into(),
    }
}

/// A system's path switches: how many, and the last one.
fn switches(s: &SystemRow) -> String {
    match &s.last_switch {
        Some(l) => format!(
            "{} (last: to {} {} → {})",
            s.path_switches, l.destination, l.from, l.to
        ),
        None => s.path_switches.to_string(),
    }
}

fn draw(
    f: &mut ratatui::Frame<'_>,
    title: &str,
    pairs: &[PairRow],
    systems: &[SystemRow],
    bad: u64,
) {
    let inbox_rows: usize = systems.iter().map(|s| s.inboxes.len().max(1)).sum();
    let [head, top, bottom] = Layout::vertical([
        Constraint::Length(2),
        Constraint::Length(pairs.len() as u16 + 3),
        Constraint::Length(inbox_rows as u16 + 3),
    ])
    .areas(f.area());
    let mut status = format!(
        "{title}\n{} pairs from {} reporting systems; q to quit",
        pairs.len(),
        systems.len()
    );
    if bad > 0 {
        status += &format!("; {bad} datagrams were not reports");
    }
    f.render_widget(Paragraph::new(status), head);
    let bold = Style::default().add_modifier(Modifier::BOLD);
    let header = Row::new([
        "source",
        "dest",
        "transport",
        "msg/s",
        "sends",
        "deliv",
        "sent",
        "unconf",
        "failed",
        "retx",
        "recv",
        "p50",
        "p99",
    ])
    .style(bold);
    let rows = pairs.iter().map(|p| {
        let c = &p.counters;
        Row::new([
            c.source.clone(),
            c.destination.clone(),
            c.transport.clone(),
            format!("{:.1}", p.rate),
            c.sends.to_string(),
            c.delivered.to_string(),
            c.sent.to_string(),
            c.unconfirmed.to_string(),
            c.failed.to_string(),
            c.retransmissions.to_string(),
            c.received.to_string(),
            latency(c.latency_p50_us),
            latency(c.latency_p99_us),
        ])
    });
    let widths = [
        Constraint::Length(12),
        Constraint::Length(12),
        Constraint::Length(10),
        Constraint::Length(7),
        Constraint::Length(7),
        Constraint::Length(7),
        Constraint::Length(6),
        Constraint::Length(7),
        Constraint::Length(7),
        Constraint::Length(6),
        Constraint::Length(7),
        Constraint::Length(8),
        Constraint::Length(8),
    ];
    f.render_widget(
        Table::new(rows, widths)
            .header(header)
            .block(Block::bordered().title(" pairs (per ordered pair and transport) ")),
        top,
    );
    let header = Row::new([
        "system",
        "module",
        "depth",
        "capacity",
        "dropped",
        "report age",
        "path switches",
    ])
    .style(bold);
    let rows = systems.iter().flat_map(|s| {
        s.inboxes.iter().map(move |i| {
            Row::new([
                s.system.clone(),
                i.module.clone(),
                i.depth.to_string(),
                i.capacity.to_string(),
                i.dropped.to_string(),
                format!("{:.1} s", s.age_s),
                switches(s),
            ])
        })
    });
    let widths = [
        Constraint::Length(12),
        Constraint::Length(10),
        Constraint::Length(7),
        Constraint::Length(9),
        Constraint::Length(8),
        Constraint::Length(11),
        Constraint::Min(14),
    ];
    f.render_widget(
        Table::new(rows, widths)
            .header(header)
            .block(Block::bordered().title(" inboxes ")),
        bottom,
    );
}
