//! Running the trials: a simulated (or real) fleet per trial, the sends, and the counting.

// The parent's imports and types.
use super::*;
use hetcomm::config::RegisteredSettings;
use hetcomm::link::emulation::EmulatedSettings;

/// What runs a trial: the virtual-time simulator, or the real transports in real time.
enum Driver {
    Sim(SimFleet),
    Real {
        fleet: LocalFleet,
        start: std::time::Instant,
    },
}

impl Driver {
    fn system(&self, name: &str) -> Result<Comm, hetcomm::OpenError> {
        match self {
            Driver::Sim(sim) => sim.system(name),
            Driver::Real { fleet, .. } => fleet.system(name),
        }
    }

    fn systems(&self) -> &[Comm] {
        match self {
            Driver::Sim(sim) => sim.systems(),
            Driver::Real { fleet, .. } => fleet.systems(),
        }
    }

    /// Lets time pass up to `at` after the start of the trial.
    fn run_until(&self, at: Time) {
        match self {
            Driver::Sim(sim) => sim.run_until(at),
            Driver::Real { start, .. } => {
                let due = *start + at.saturating_since(Time::ZERO);
                std::thread::sleep(due.saturating_duration_since(std::time::Instant::now()));
            }
        }
    }

    /// The time to stamp a send with, on the clock receivers stamp arrivals with.
    fn now(&self) -> Time {
        match self {
            Driver::Sim(sim) => sim.now(),
            Driver::Real { .. } => Time::now_wall(),
        }
    }

    /// Runs until every send ended (or `limit` after the start), then returns the seconds
    /// the trial took on its own clock.
    fn finish(&self, limit: Duration, tickets: &[&Ticket]) -> f64 {
        match self {
            Driver::Sim(sim) => {
                sim.run_idle(Time::ZERO + limit);
                sim.now().as_secs_f64()
            }
            Driver::Real { start, .. } => {
                let deadline = *start + limit;
                for t in tickets {
                    let left = deadline.saturating_duration_since(std::time::Instant::now());
                    let _ = t.wait_timeout(left);
                }
                // Unacknowledged messages may still be on their way: a short grace period.
                std::thread::sleep(Duration::from_millis(200));
                start.elapsed().as_secs_f64()
            }
        }
    }

    fn net_stats(&self) -> SimNetStats {
        match self {
            Driver::Sim(sim) => sim.net_stats(),
            Driver::Real { .. } => SimNetStats::default(),
        }
    }
}

/// The fleet of one mode: delivery, budgets and loss set on a copy of `base`.
pub fn fleet_for_mode(
    base: &Fleet,
    mode: Mode,
    config: &ReliabilityConfig,
) -> Result<Fleet, ExperimentError> {
    let mut fleet = base.clone();
    let letter = config.lossy_letter;
    let mut found = config.loss == LossModel::Profile;
    for t in &mut fleet.transports {
        match mode {
            Mode::Thesis => t.delivery = DeliveryMode::Unacknowledged,
            Mode::Acknowledged => {
                t.delivery = DeliveryMode::Acknowledged;
                t.attempts = config.attempts;
                // Each sender's messages reach each receiver in the order sent.
                t.ordered = true;
            }
        }
        if config.loss == LossModel::Profile || t.tag != letter as u8 {
            continue;
        }
        let Some(mut settings) = t.settings.registered::<EmulatedSettings>().cloned() else {
            return Err(ExperimentError::Invalid(format!(
                "the loss options apply to the transport of letter {letter}, but `{}` is a {} \
                 transport, not an emulated one",
                t.name, t.kind
            )));
        };
        let p = &mut settings.params;
        match config.loss {
            LossModel::Profile => {}
            LossModel::Iid { percent } => {
                p.insert("loss_percent".into(), percent);
                p.insert("burst_loss_percent".into(), 0.0);
            }
            LossModel::Bursty {
                percent,
                burst_length,
            } => {
                p.insert("loss_percent".into(), 0.0);
                p.insert("burst_loss_percent".into(), percent);
                p.insert("burst_length_mean".into(), burst_length);
            }
        }
        hetcomm::link::emulation::ModelParams::from_settings(&settings).map_err(|e| {
            ExperimentError::Invalid(format!("transport `{}` with the loss options: {e}", t.name))
        })?;
        t.settings = TransportSettings::Registered(RegisteredSettings::new(settings));
        found = true;
    }
    if !found {
        return Err(ExperimentError::Invalid(format!(
            "the loss options apply to the transport of letter {letter}, but no transport of the \
             fleet has that letter"
        )));
    }
    Ok(fleet)
}

/// The systems that send (those with at least one route), by id, each with its destinations.
fn senders(fleet: &Fleet) -> Vec<(SystemId, Vec<SystemId>)> {
    fleet
        .systems
        .iter()
        .map(|s| {
            let dests: Vec<SystemId> = fleet
                .systems
                .iter()
                .filter(|d| d.id != s.id && fleet.route(s.id, d.id).is_some())
                .map(|d| d.id)
                .collect();
            (s.id, dests)
        })
        .filter(|(_, d)| !d.is_empty())
        .collect()
}

/// Point-to-point destinations: `[trial][sender index][k]`.
fn plan(
    senders: &[(SystemId, Vec<SystemId>)],
    config: &ReliabilityConfig,
) -> Vec<Vec<Vec<SystemId>>> {
    let mut rng = ChaCha8Rng::seed_from_u64(config.seed);
    (0..config.trials)
        .map(|_| {
            senders
                .iter()
                .map(|(_, dests)| {
                    (0..config.point_to_point)
                        .map(|_| dests[rng.gen_range(0..dests.len())])
                        .collect()
                })
                .collect()
        })
        .collect()
}

/// The module the experiment uses: `Plan` if the fleet has it, else its first module.
pub(crate) fn module_name(fleet: &Fleet) -> Result<String, ExperimentError> {
    fleet
        .module_by_name("Plan")
        .or(fleet.modules.first())
        .map(|m| m.name.clone())
        .ok_or_else(|| ExperimentError::Invalid("the fleet defines no modules".into()))
}

/// Transport indices the table uses, in fleet order.
fn used_transports(fleet: &Fleet) -> Vec<usize> {
    let used: HashSet<usize> = fleet.table.values().copied().collect();
    (0..fleet.transports.len())
        .filter(|i| used.contains(i))
        .collect()
}

fn letter_of(fleet: &Fleet, index: usize) -> String {
    let t = &fleet.transports[index];
    if t.tag.is_ascii_graphic() {
        (t.tag as char).to_string()
    } else {
        t.name.clone()
    }
}

fn transport_info(fleet: &Fleet, index: usize) -> TransportInfo {
    let t = &fleet.transports[index];
    let (profile, params) = match t.settings.registered::<EmulatedSettings>() {
        Some(s) => (s.profile.clone(), s.params.clone()),
        None => (None, BTreeMap::new()),
    };
    TransportInfo {
        letter: letter_of(fleet, index),
        name: t.name.clone(),
        kind: t.kind.to_string(),
        delivery: match t.delivery {
            DeliveryMode::Acknowledged => "acknowledged".into(),
            DeliveryMode::Unacknowledged => "unacknowledged".into(),
        },
        attempts: t.attempts,
        profile,
        params,
    }
}

/// One send of a trial.
struct SendRecord {
    from: SystemId,
    to: SystemId,
    /// 0 for the broadcast, 1… for the point-to-point messages.
    index: u8,
    at: Time,
    ticket: Ticket,
}

/// Runs the experiment on `fleet` (see the module docs).
pub fn run(
    fleet: &Fleet,
    config: &ReliabilityConfig,
) -> Result<ReliabilityReport, ExperimentError> {
    validate(config)?;
    let senders = senders(fleet);
    if senders.is_empty() {
        return Err(ExperimentError::Invalid(
            "the fleet's table has no traffic: no system can send".into(),
        ));
    }
    let plan = plan(&senders, config);
    let mut modes = Vec::with_capacity(config.modes.len());
    for &mode in &config.modes {
        let mode_fleet = fleet_for_mode(fleet, mode, config)?;
        modes.push(run_mode(&mode_fleet, mode, config, &senders, &plan)?);
    }
    let messages_per_trial = senders
        .iter()
        .map(|(_, d)| d.len() as u64 + config.point_to_point as u64)
        .sum();
    Ok(ReliabilityReport {
        experiment: "reliability".into(),
        trials: config.trials,
        seed: config.seed,
        acknowledged_attempts: config.attempts,
        loss: config.loss,
        loss_description: config.loss.describe(),
        lossy_transport: config.lossy_letter.to_string(),
        messages_per_trial,
        thesis: ThesisReference::published(),
        modes,
    })
}

fn run_mode(
    fleet: &Fleet,
    mode: Mode,
    config: &ReliabilityConfig,
    senders: &[(SystemId, Vec<SystemId>)],
    plan: &[Vec<Vec<SystemId>>],
) -> Result<ModeReport, ExperimentError> {
    let module = module_name(fleet)?;
    let columns = used_transports(fleet);
    let column_of: HashMap<usize, usize> =
        columns.iter().enumerate().map(|(c, &i)| (i, c)).collect();
    let col = |from: SystemId, to: SystemId| -> usize {
        fleet
            .table
            .get(&(from, to))
            .and_then(|i| column_of.get(i))
            .copied()
            .unwrap_or(0)
    };
    let name_of = |id: SystemId| -> String {
        fleet
            .system(id)
            .map(|s| s.name.clone())
            .unwrap_or_else(|| id.0.to_string())
    };
    // Rows: every system of the fleet (a system may only receive).
    let mut rows: Vec<SystemRow> = fleet
        .systems
        .iter()
        .map(|s| SystemRow {
            system: s.name.clone(),
            per_transport: columns
                .iter()
                .map(|&i| TransportCounts {
                    transport: letter_of(fleet, i),
                    ..Default::default()
                })
                .collect(),
        })
        .collect();
    let row_of: HashMap<SystemId, usize> = fleet
        .systems
        .iter()
        .enumerate()
        .map(|(r, s)| (s.id, r))
        .collect();
    let losses = match mode {
        Mode::Thesis => LossVisibility::Reported,
        Mode::Acknowledged => LossVisibility::Silent,
    };
    let timing = match mode {
        Mode::Thesis => None,
        Mode::Acknowledged => Some(config.timing),
    };

    let mut messages = 0u64;
    let mut received = 0u64;
    let mut duplicates_delivered = 0u64;
    let mut out_of_order = 0u64;
    let mut duplicates_suppressed = 0u64;
    let mut acc = Accounting::default();
    let mut failure_reasons = BTreeMap::new();
    let mut transmissions = 0u64;
    let mut max_attempts = 0u32;
    let mut attempts_sum = 0u64;
    let mut resolved = 0u64;
    let mut delays = Vec::new();
    let mut network_drops = BTreeMap::new();
    let mut network_frames = 0u64;
    let mut virtual_seconds = 0.0;

    for (trial, destinations) in plan.iter().enumerate() {
        let trial_no = trial as u32;
        let sim = if config.realtime {
            Driver::Real {
                fleet: LocalFleet::open(fleet.clone())?,
                start: std::time::Instant::now(),
            }
        } else {
            Driver::Sim(SimFleet::open(
                fleet.clone(),
                SimOptions {
                    seed: config.seed.wrapping_add(trial as u64),
                    losses,
                    timing,
                },
            )?)
        };
        let _scenario = match (&config.scenario, &sim) {
            (Some(sc), Driver::Sim(s)) => Some(s.apply_scenario(sc, config.seed)),
            (Some(sc), Driver::Real { fleet, .. }) => Some(fleet.apply_scenario(sc, config.seed)),
            (None, _) => None,
        }
        .transpose()
        .map_err(|e| ExperimentError::Invalid(e.to_string()))?;
        let modules = senders
            .iter()
            .map(|(id, _)| {
                sim.system(&name_of(*id))
                    .and_then(|c| c.module(&module))
                    .map_err(ExperimentError::from)
            })
            .collect::<Result<Vec<_>, _>>()?;
        let receivers = fleet
            .systems
            .iter()
            .map(|s| {
                sim.system(&s.name)
                    .and_then(|c| c.module(&module))
                    .map(|m| (s.id, m))
                    .map_err(ExperimentError::from)
            })
            .collect::<Result<Vec<_>, _>>()?;
        let refused = |from: SystemId, to: &str, e: hetcomm::SendError| ExperimentError::Send {
            from: name_of(from),
            to: to.to_string(),
            reason: e.to_string(),
        };
        let mut sends: Vec<SendRecord> = Vec::new();
        for step in 0..=config.point_to_point {
            let at = Time::ZERO + config.spacing * step;
            sim.run_until(at);
            for (s, ((from, _), m)) in senders.iter().zip(&modules).enumerate() {
                let now = sim.now();
                if step == 0 {
                    let msg = Message1 {
                        trial: trial_no,
                        sender: from.0,
                    };
                    let b = m
                        .broadcast(&module, &msg)
                        .map_err(|e| refused(*from, "All", e))?;
                    for t in b.tickets() {
                        let to = fleet
                            .system_by_name(t.destination())
                            .map(|d| d.id)
                            .unwrap_or(*from);
                        sends.push(SendRecord {
                            from: *from,
                            to,
                            index: 0,
                            at: now,
                            ticket: t.clone(),
                        });
                    }
                } else {
                    let to = destinations[s][step as usize - 1];
                    let to_name = name_of(to);
                    let msg = Message2 {
                        trial: trial_no,
                        sender: from.0,
                        index: step as u8,
                    };
                    let ticket = m
                        .send(&to_name, &module, &msg)
                        .map_err(|e| refused(*from, &to_name, e))?;
                    sends.push(SendRecord {
                        from: *from,
                        to,
                        index: step as u8,
                        at: now,
                        ticket,
                    });
                }
            }
        }
        let tickets: Vec<&Ticket> = sends.iter().map(|r| &r.ticket).collect();
        virtual_seconds += sim.finish(config.time_limit, &tickets);

        // Send side.
        for rec in &sends {
            messages += 1;
            let c = &mut rows[row_of[&rec.from]].per_transport[col(rec.from, rec.to)];
            c.transmit_attempts += 1;
            match rec.ticket.try_outcome() {
                None => acc.unresolved_tickets += 1,
                Some(outcome) => {
                    let attempts = outcome.attempts();
                    resolved += 1;
                    attempts_sum += attempts as u64;
                    max_attempts = max_attempts.max(attempts);
                    c.additional_attempts += attempts.saturating_sub(1) as u64;
                    match &outcome {
                        Outcome::Failed { reason, .. } => {
                            c.failed += 1;
                            *failure_reasons.entry(reason_name(reason)).or_insert(0) += 1;
                        }
                        Outcome::Unconfirmed { .. } => c.unconfirmed += 1,
                        Outcome::Delivered { .. }
                        | Outcome::Sent { .. }
                        | Outcome::Relayed { .. } => c.transmit_successes += 1,
                    }
                }
            }
        }
        let sent_at: HashMap<(SystemId, SystemId, u8), Time> = sends
            .iter()
            .map(|rec| ((rec.from, rec.to, rec.index), rec.at))
            .collect();

        // Receive side.
        let mut seen: HashSet<(SystemId, SystemId, u8)> = HashSet::new();
        // Per (sender, receiver): the index of the last message received, to check order
        // (each sender sends index 0, the broadcast, then 1..=5).
        let mut last_index: HashMap<(SystemId, SystemId), u8> = HashMap::new();
        for (me, m) in &receivers {
            while let Some(raw) = m.try_recv_raw() {
                let from = raw.envelope.source().system;
                let index = if raw.envelope.message_type() == Message1::TYPE {
                    match hetcomm::payload::decode::<Message1>(&raw.payload) {
                        Ok(msg) if msg.trial == trial_no => 0u8,
                        _ => continue,
                    }
                } else if raw.envelope.message_type() == Message2::TYPE {
                    match hetcomm::payload::decode::<Message2>(&raw.payload) {
                        Ok(msg) if msg.trial == trial_no => msg.index,
                        _ => continue,
                    }
                } else {
                    continue;
                };
                let key = (from, *me, index);
                if !seen.insert(key) {
                    duplicates_delivered += 1;
                    continue;
                }
                received += 1;
                if let Some(last) = last_index.insert((from, *me), index) {
                    if index < last {
                        out_of_order += 1;
                    }
                }
                rows[row_of[me]].per_transport[col(from, *me)].receivals += 1;
                let sent = sent_at
                    .get(&key)
                    .copied()
                    .unwrap_or(raw.envelope.timestamp());
                delays.push(
                    raw.envelope
                        .received_at
                        .as_micros()
                        .saturating_sub(sent.as_micros()),
                );
            }
        }

        for comm in sim.systems() {
            let r = comm.stats().router;
            acc.accepted += r.sends;
            acc.delivered += r.delivered;
            acc.sent += r.sent;
            acc.unconfirmed += r.unconfirmed;
            acc.failed += r.failed;
            acc.in_flight += r.in_flight();
            duplicates_suppressed += r.duplicates;
            transmissions += r.transmissions;
        }
        let net = sim.net_stats();
        network_frames += net.frames_sent;
        for (k, v) in net.dropped {
            *network_drops.entry(k).or_insert(0) += v;
        }
    }
    let cells = || rows.iter().flat_map(|r| &r.per_transport);
    let outcome_failed: u64 = cells().map(|c| c.failed).sum();
    let outcome_unconfirmed: u64 = cells().map(|c| c.unconfirmed).sum();
    acc.balanced = acc.accepted
        == acc.delivered + acc.sent + acc.unconfirmed + acc.failed + acc.in_flight
        && acc.accepted == messages
        && acc.failed == outcome_failed
        && acc.unconfirmed == outcome_unconfirmed
        && acc.unresolved_tickets == acc.in_flight;
    let description = match mode {
        Mode::Thesis => format!(
            "unacknowledged delivery; the transport reports a failed transmission and the router \
             retries after a pause ({} ms, doubling) up to the transport's attempt budget; \
             success = the transport accepted the frame",
            timing.unwrap_or_default().link_retry.as_secs_f64() * 1e3
        ),
        Mode::Acknowledged => format!(
            "acknowledged delivery; losses are silent; the receiving router acknowledges and the \
             sender retransmits on an RTT-based timeout, up to {} attempts",
            config.attempts
        ),
    };
    Ok(ModeReport {
        mode,
        description,
        losses: match (config.realtime, losses) {
            (true, _) => "as the real links behave (real time)".into(),
            (false, LossVisibility::Silent) => "silent".into(),
            (false, LossVisibility::Reported) => "reported".into(),
        },
        transports: columns.iter().map(|&i| transport_info(fleet, i)).collect(),
        timing: TimingInfo::from(timing.unwrap_or_default()),
        systems: rows,
        messages,
        received,
        delivery_ratio_percent: if messages == 0 {
            0.0
        } else {
            100.0 * received as f64 / messages as f64
        },
        duplicates_delivered,
        out_of_order,
        duplicates_suppressed,
        accounting: acc,
        failure_reasons,
        transmissions,
        attempts_per_message: if resolved == 0 {
            0.0
        } else {
            attempts_sum as f64 / resolved as f64
        },
        max_attempts,
        delay: DelayStats::from_micros(delays),
        network_drops,
        network_frames,
        virtual_seconds,
    })
}

fn reason_name(reason: &FailReason) -> String {
    match reason {
        FailReason::NoAcknowledgement => "no-acknowledgement".into(),
        FailReason::Unreachable(_) => "unreachable".into(),
        FailReason::Congested(_) => "congested".into(),
        FailReason::NoSession(_) => "no-session".into(),
        FailReason::InboxFull => "inbox-full".into(),
        FailReason::UnknownModule => "unknown-module".into(),
        FailReason::Link(_) => "link".into(),
        FailReason::Backpressure => "backpressure".into(),
        FailReason::Shutdown => "shutdown".into(),
        FailReason::Relay(_) => "relay".into(),
        #[allow(unreachable_patterns)]
        _ => "other".into(),
    }
}
