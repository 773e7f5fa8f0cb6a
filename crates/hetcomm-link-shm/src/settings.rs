//! The settings of an `shm` transport and the names it gives iceoryx2's services and nodes.

/// Settings of an `shm` transport (the keys of `docs/shm.md`).
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct ShmSettings {
    /// First part of every service and node name (`PREFIX/FLEET/<System>`).
    pub prefix: String,
    /// The fleet part of the names; None: the fleet file's `name`, else `fleet`.
    pub fleet: Option<String>,
    /// Largest frame (header and payload) a send takes, bytes. A publisher's segment starts at
    /// [`ShmSettings::initial_frame`] per sample and grows (doubling) up to this when larger
    /// frames are sent.
    pub max_frame: usize,
    /// Bytes per sample a publisher reserves when it opens.
    pub initial_frame: usize,
    /// Frames a destination's queue holds before sends to it are refused as congested.
    pub queue_depth: usize,
    /// Publishers one destination's service admits (the fleet's other systems, and room for a
    /// foreign peer or a restarting process); None: the fleet's systems and one more.
    pub max_publishers: Option<usize>,
    /// Subscribers one destination's service admits: 1, the destination itself, unless a
    /// monitor (a second reader that takes every frame too) is wanted.
    pub max_subscribers: usize,
    /// How often a link looks for peers whose process died, milliseconds.
    pub liveness_ms: u32,
    /// How long a send waits for room in a full queue before it is refused as congested,
    /// milliseconds (0: refuse at once). A send made while the link reads (an
    /// acknowledgement) never waits.
    pub send_wait_ms: u32,
}

impl Default for ShmSettings {
    fn default() -> Self {
        ShmSettings {
            prefix: "hetcomm".into(),
            fleet: None,
            max_frame: DEFAULT_MAX_FRAME,
            initial_frame: DEFAULT_INITIAL_FRAME,
            queue_depth: 16,
            max_publishers: None,
            max_subscribers: 1,
            liveness_ms: 100,
            send_wait_ms: 200,
        }
    }
}

/// The default `initial_frame`: a 64 KiB payload with its header fits without growing the
/// segment. Growing is slow under a stream of frames (iceoryx2 maps a new, larger segment and
/// keeps the old one until its samples come back): 64 KiB frames from a 4 KiB start ran at
/// 4 k msg/s, from this one at 97 k msg/s (docs/shm.md, "Memory").
pub const DEFAULT_INITIAL_FRAME: usize = 64 * 1024 + 1024;

/// The default `max_frame`: a 1 MiB payload with room for its header (and a fragment's).
pub const DEFAULT_MAX_FRAME: usize = 1024 * 1024 + 64 * 1024;

impl ShmSettings {
    /// Shared memory one publisher may map at most: its samples at `max_frame`. iceoryx2
    /// preallocates what its queue, the subscriber's borrows and its own loans can hold.
    pub fn publisher_bound(&self) -> usize {
        self.samples_per_publisher() * self.max_frame
    }

    /// Shared memory one publisher maps when it opens.
    pub fn publisher_initial(&self) -> usize {
        self.samples_per_publisher() * self.initial_frame.min(self.max_frame)
    }

    /// Samples a publisher preallocates: every queue it can fill, every sample a subscriber
    /// may borrow, its own loans.
    fn samples_per_publisher(&self) -> usize {
        self.max_subscribers * (self.queue_depth + BORROWED) + LOANS
    }
}

/// Samples a subscriber holds at once (it releases each after handing it to the sink).
pub(crate) const BORROWED: usize = 2;
/// Samples a publisher loans at once (one send at a time per destination).
pub(crate) const LOANS: usize = 2;

/// Checks a name part (`prefix`, `fleet`): iceoryx2 names allow most characters, but `/`
/// separates the parts and an empty part would make names collide.
pub fn validate_part(part: &str) -> Result<(), String> {
    if part.is_empty() {
        return Err("it is empty".into());
    }
    if let Some(c) = part
        .chars()
        .find(|c| !(c.is_ascii_alphanumeric() || matches!(c, '-' | '_' | '.' | '/')))
    {
        return Err(format!(
            "`{c}` is not allowed (letters, digits, `-`, `_`, `.`, `/`)"
        ));
    }
    if part.starts_with('/') || part.ends_with('/') || part.contains("//") {
        return Err("a `/` may only separate two parts".into());
    }
    Ok(())
}

/// The service (publish-subscribe and event) frames for system `name` go through, and the
/// name of that system's iceoryx2 node: `PREFIX/FLEET/<name>`.
pub fn service_name(prefix: &str, fleet: &str, name: &str) -> String {
    format!("{prefix}/{fleet}/{name}")
}
