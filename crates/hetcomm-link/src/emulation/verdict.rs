//! What the link model decides for a frame: a [`Verdict`] (dropped, and why, or the
//! arrivals it makes, each with its delay and any corruption).

use hetcomm_core::Time;

/// Why the model dropped a frame.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum DropReason {
    /// The frame is longer than `mtu_bytes` (the real-time link reports this to the sender as
    /// [`crate::LinkError::TooLarge`] instead of dropping silently).
    Mtu,
    /// Sent during an outage window.
    Outage,
    /// The systems are further apart than `range_m`.
    OutOfRange,
    /// The direction's transmit queue already held `queue_frames` frames.
    QueueFull,
    /// Lost to a weak signal (log-distance path loss).
    PathLoss,
    /// Lost in a Gilbert–Elliott bad state.
    BurstLoss,
    /// Independent (iid) loss.
    Loss,
}

impl DropReason {
    /// Every reason, in the order the model checks them.
    pub const ALL: [DropReason; 7] = [
        DropReason::Mtu,
        DropReason::Outage,
        DropReason::OutOfRange,
        DropReason::QueueFull,
        DropReason::PathLoss,
        DropReason::BurstLoss,
        DropReason::Loss,
    ];

    /// A short lowercase name, e.g. `"queue full"`.
    pub fn as_str(self) -> &'static str {
        match self {
            DropReason::Mtu => "mtu",
            DropReason::Outage => "outage",
            DropReason::OutOfRange => "out of range",
            DropReason::QueueFull => "queue full",
            DropReason::PathLoss => "path loss",
            DropReason::BurstLoss => "burst loss",
            DropReason::Loss => "loss",
        }
    }
}

impl std::fmt::Display for DropReason {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.as_str())
    }
}

/// One bit to flip in a delivered copy: `frame[byte] ^= mask` (`mask` has exactly one bit set).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct BitFlip {
    /// Index of the byte, `< frame length`.
    pub byte: usize,
    /// The bit to flip, as a mask with one bit set.
    pub mask: u8,
}

impl BitFlip {
    /// Flips the bit in `frame` (does nothing if the frame is shorter than expected).
    pub fn apply(&self, frame: &mut [u8]) {
        if let Some(b) = frame.get_mut(self.byte) {
            *b ^= self.mask;
        }
    }
}

/// One copy of a frame that arrives.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct Arrival {
    /// When it arrives at the receiver (on the same clock as the `now` given to the model; never
    /// earlier than `now`).
    pub at: Time,
    /// A bit to flip before handing the copy to the receiver, if the copy is corrupted.
    pub corrupt: Option<BitFlip>,
    /// Whether this copy was held back by `reorder_delay_ms` so that later frames overtake it.
    pub reordered: bool,
}

/// The model's decision about one frame.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Verdict {
    /// The frame is lost, for this reason.
    Drop(DropReason),
    /// The frame arrives, perhaps twice.
    Deliver {
        /// The copy that always arrives.
        first: Arrival,
        /// A second copy, when the frame was duplicated.
        duplicate: Option<Arrival>,
    },
}

impl Verdict {
    /// The reason, if the frame was dropped.
    pub fn drop_reason(&self) -> Option<DropReason> {
        match self {
            Verdict::Drop(r) => Some(*r),
            Verdict::Deliver { .. } => None,
        }
    }

    /// The copies that arrive (none, one or two), first copy first.
    pub fn deliveries(&self) -> impl Iterator<Item = Arrival> {
        let (a, b) = match *self {
            Verdict::Drop(_) => (None, None),
            Verdict::Deliver { first, duplicate } => (Some(first), duplicate),
        };
        a.into_iter().chain(b)
    }
}
