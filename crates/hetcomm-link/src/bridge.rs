//! What every bridge kind shares, whatever the foreign side speaks (ROS 1, ROS 2, MQTT JSON):
//! naming the bridged robot and the mapped modules ([`robot_id`], [`module_id`], [`hosts`]),
//! counting and reporting bad input from the foreign side once per problem ([`Tally`]), and
//! turning a foreign message, once converted to a MessagePack payload, into a hetcomm frame
//! from the robot ([`FrameMaker`]).
//!
//! A bridge is a link to a system that runs something else than hetcomm (its `robot`): it
//! converts payloads both ways, nobody on the other side acknowledges or seals, and what
//! cannot be converted is refused and counted where a user sees it (the link's
//! `frames_dropped`).

use parking_lot::Mutex;
use std::collections::{BTreeSet, HashMap};
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::{SystemTime, UNIX_EPOCH};

use hetcomm_config::Fleet;
use hetcomm_core::wire::{self, FrameKind, Header};
use hetcomm_core::{Address, MessageType, ModuleId, SystemId, Time};

use crate::LinkStats;

/// The id of the bridge's `robot`, which must be in the fleet and not be `local` (it runs
/// `runs`, e.g. "ROS 1" or "plain MQTT", not hetcomm).
pub fn robot_id(
    fleet: &Fleet,
    local: SystemId,
    robot: &str,
    runs: &str,
) -> Result<SystemId, String> {
    let id = fleet
        .systems
        .iter()
        .find(|s| s.name == robot)
        .map(|s| s.id)
        .ok_or_else(|| format!("robot `{robot}` is not in [systems]"))?;
    if id == local {
        return Err(format!(
            "`{robot}` is the external {runs} robot of this bridge: it runs {runs}, not hetcomm"
        ));
    }
    Ok(id)
}

/// The id of the module `name` that the mapping of `topic` names.
pub fn module_id(fleet: &Fleet, name: &str, topic: &str) -> Result<ModuleId, String> {
    fleet
        .modules
        .iter()
        .find(|m| m.name == name)
        .map(|m| m.id)
        .ok_or_else(|| {
            format!("the mapping of {topic} names module `{name}`, which is not in [modules]")
        })
}

/// Whether system `local` hosts `module`: true unless its `[systems]` entry lists its
/// modules and leaves this one out. A bridge reads a subscribed topic only where its module
/// is hosted: elsewhere the messages would have nowhere to go (e.g. a system that only
/// publishes the robot's commands).
pub fn hosts(fleet: &Fleet, local: SystemId, module: ModuleId) -> bool {
    fleet
        .systems
        .iter()
        .find(|s| s.id == local)
        .and_then(|s| s.modules.as_ref())
        .is_none_or(|hosted| hosted.contains(&module))
}

/// A bridge's counts (the link's stats) and what went wrong with input from the foreign side,
/// each distinct problem once, in order; shared by its send side and its receive tasks.
pub struct Tally {
    kind: &'static str,
    sent: AtomicU64,
    received: AtomicU64,
    dropped: AtomicU64,
    seen: Mutex<BTreeSet<String>>,
}

impl Tally {
    /// Nothing counted yet; `kind` (e.g. `ros1_bridge`) prefixes what is printed.
    pub fn new(kind: &'static str) -> Tally {
        Tally {
            kind,
            sent: AtomicU64::new(0),
            received: AtomicU64::new(0),
            dropped: AtomicU64::new(0),
            seen: Mutex::default(),
        }
    }

    /// One message handed to the foreign side.
    pub fn sent(&self) {
        self.sent.fetch_add(1, Ordering::Relaxed);
    }

    /// One message from the foreign side handed to the system.
    pub fn received(&self) {
        self.received.fetch_add(1, Ordering::Relaxed);
    }

    /// Records `problem`, one that costs no message here (printed to stderr the first time
    /// it is seen); true the first time.
    pub fn report(&self, problem: String) -> bool {
        let mut seen = self.seen.lock();
        let new = seen.insert(problem.clone());
        if new {
            eprintln!("hetcomm {}: {problem}", self.kind);
        }
        new
    }

    /// `n` messages from the foreign side dropped because of `problem` (reported the first
    /// time).
    pub fn dropped(&self, n: u64, problem: String) {
        self.dropped.fetch_add(n, Ordering::Relaxed);
        self.report(problem);
    }

    /// A problem that costs messages no one can count (a publisher ROS does not connect):
    /// counted as one drop and reported, the first time it is seen only.
    pub fn dropped_once(&self, problem: String) {
        if self.report(problem) {
            self.dropped.fetch_add(1, Ordering::Relaxed);
        }
    }

    /// Every distinct problem seen so far.
    pub fn problems(&self) -> Vec<String> {
        let seen = self.seen.lock();
        seen.iter().cloned().collect()
    }

    /// The link's stats: sent, received and dropped messages.
    pub fn stats(&self) -> LinkStats {
        LinkStats {
            frames_sent: self.sent.load(Ordering::Relaxed),
            frames_received: self.received.load(Ordering::Relaxed),
            frames_dropped: self.dropped.load(Ordering::Relaxed),
            ..LinkStats::default()
        }
    }
}

/// Makes the hetcomm frames of messages received from the robot: data from (robot, module) to
/// (this system, module), numbered per module under one random incarnation.
pub struct FrameMaker {
    local: SystemId,
    robot: SystemId,
    incarnation: u32,
    seq: HashMap<ModuleId, u64>,
    /// Frames with a CRC of their header only ([`FrameMaker::header_crc`]).
    header_crc: bool,
}

impl FrameMaker {
    /// Frames from `robot` to `local`.
    pub fn new(local: SystemId, robot: SystemId) -> FrameMaker {
        FrameMaker {
            local,
            robot,
            incarnation: rand::random::<u32>() | 1,
            seq: HashMap::new(),
            header_crc: false,
        }
    }

    /// Makes frames whose CRC covers their header only (`wire::FLAG_HEADER_CRC`), for a
    /// bridge whose link says [`Link::checksums_payload`](crate::Link::checksums_payload):
    /// its frames are made and handed to the sink in this process, where a CRC of the payload
    /// protects nothing and costs a pass over every byte (megabytes for a camera image).
    pub fn header_crc(mut self) -> FrameMaker {
        self.header_crc = true;
        self
    }

    /// The frame of `payload` (MessagePack, converted from the foreign message) for `module`
    /// as message type `message`, stamped with the wall clock now (a stamp crosses hosts).
    pub fn frame_of(&mut self, module: ModuleId, message: u32, payload: &[u8]) -> Vec<u8> {
        let seq = self.seq.entry(module).or_insert(0);
        *seq += 1;
        let us = SystemTime::now()
            .duration_since(UNIX_EPOCH)
            .map(|d| d.as_micros() as u64)
            .unwrap_or(0);
        let at = |system| Address { system, module };
        let data = Header::data(at(self.robot), at(self.local), MessageType(message));
        let header_crc = if self.header_crc {
            wire::FLAG_HEADER_CRC
        } else {
            0
        };
        let header = Header {
            kind: FrameKind::Data,
            incarnation: self.incarnation,
            seq: *seq,
            timestamp: Time::from_micros(us),
            flags: data.flags | header_crc,
            ..data
        };
        wire::encode(&header, payload)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_problem_is_reported_once_and_every_drop_counted() {
        let t = Tally::new("test_bridge");
        t.dropped(1, "a message on /x is not JSON (dropped)".into());
        t.dropped(2, "a message on /x is not JSON (dropped)".into());
        t.dropped_once("a publisher of another type".into());
        t.dropped_once("a publisher of another type".into());
        t.sent();
        t.received();
        assert_eq!(t.problems().len(), 2);
        let s = t.stats();
        assert_eq!(
            (s.frames_sent, s.frames_received, s.frames_dropped),
            (1, 1, 4)
        );
    }

    #[test]
    fn frames_from_the_robot_are_numbered_per_module() {
        let mut m = FrameMaker::new(SystemId(0), SystemId(4));
        let a = m.frame_of(ModuleId(2), 41, &[0x80]);
        let b = m.frame_of(ModuleId(2), 41, &[0x80]);
        let c = m.frame_of(ModuleId(3), 42, &[0xc0]);
        let (a, b, c) = (
            wire::decode(&a).unwrap(),
            wire::decode(&b).unwrap(),
            wire::decode(&c).unwrap(),
        );
        assert_eq!((a.header.seq, b.header.seq, c.header.seq), (1, 2, 1));
        assert_eq!(a.header.source.system, SystemId(4));
        assert_eq!(
            a.header.destination,
            Address {
                system: SystemId(0),
                module: ModuleId(2)
            }
        );
        assert_eq!(c.header.message_type, MessageType(42));
        assert_eq!(c.payload, &[0xc0]);
        assert_eq!(a.header.incarnation, c.header.incarnation);
    }

    #[test]
    fn header_crc_frames_leave_the_payload_unchecked_and_others_check_it() {
        let payload = vec![0xc4, 3, 1, 2, 3];
        let whole = FrameMaker::new(SystemId(0), SystemId(4)).frame_of(ModuleId(2), 41, &payload);
        let mut header_only = FrameMaker::new(SystemId(0), SystemId(4)).header_crc();
        let mut fast = header_only.frame_of(ModuleId(2), 41, &payload);
        assert!(wire::decode(&whole).unwrap().header.payload_checked());
        assert!(!wire::decode(&fast).unwrap().header.payload_checked());
        // A changed payload byte still decodes: only the header is covered.
        let last = fast.len() - 1;
        fast[last] ^= 0xff;
        assert_eq!(wire::decode(&fast).unwrap().payload, &[0xc4, 3, 1, 2, 0xfc]);
    }
}
