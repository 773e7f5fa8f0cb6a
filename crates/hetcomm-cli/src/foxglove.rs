//! `--foxglove HOST:PORT` of `monitor`, `demo --realtime`, `listen` and `replay`, and the
//! rovers' poses in `demo --record`'s recordings: one way in to `hetcomm-foxglove` (feature
//! `foxglove`, docs/foxglove.md). Without the feature the flag is refused, never ignored.

use hetcomm::Comm;
use hetcomm_record::stats::{PairRow, SystemRow};
use hetcomm_record::Recorder;
use hetcomm_sim::Pose;

/// The `--foxglove` flag, the same on every command that has it.
#[derive(clap::Args, Clone, Debug, Default)]
pub struct FoxgloveArgs {
    /// Serve this run to Foxglove / Lichtblick over the Foxglove WebSocket protocol on
    /// HOST:PORT (port 0 picks one, printed on stderr): the statistics, and for the systems
    /// this command opens every message, outcome and security counter; the demo's rovers in
    /// 3D (docs/foxglove.md; needs a build with `--features foxglove`).
    #[arg(long, value_name = "HOST:PORT")]
    pub foxglove: Option<String>,
}

#[cfg(feature = "foxglove")]
mod imp {
    use parking_lot::Mutex;

    use hetcomm_foxglove::{FoxgloveView, PoseRecording, RoverPose, Watch};

    use super::*;

    /// A running server and, once given systems, what it watches.
    pub struct Live {
        view: FoxgloveView,
        watch: Mutex<Option<Watch>>,
    }

    /// Starts the server; `name` is the command clients are shown.
    pub fn start(addr: &str, name: &str) -> anyhow::Result<Live> {
        let view = FoxgloveView::start(addr, name)?;
        // On stderr, so stdout stays the command's own; the tests read the port here.
        eprintln!(
            "foxglove: serving on ws://{}:{} (open it in Foxglove: Open connection, Foxglove WebSocket)",
            addr.rsplit_once(':').map_or(addr, |(h, _)| h),
            view.port()
        );
        Ok(Live {
            view,
            watch: Mutex::new(None),
        })
    }

    fn rovers(poses: &[(String, Pose)]) -> Vec<RoverPose<'_>> {
        poses
            .iter()
            .map(|(name, p)| RoverPose {
                name,
                x: p.x,
                y: p.y,
                heading_deg: p.theta_deg,
            })
            .collect()
    }

    impl Live {
        /// One refresh of a monitor's statistics.
        pub fn publish(&self, pairs: &[PairRow], systems: &[SystemRow]) -> anyhow::Result<()> {
            self.view.publish(pairs, systems)
        }

        /// Publishes `systems`' traffic and counters from now until [`Live::finish`].
        pub fn watch(&self, systems: &[Comm]) -> anyhow::Result<()> {
            let watch = self.view.watch(systems)?;
            *self.watch.lock() = Some(watch);
            Ok(())
        }

        /// The rovers' poses now.
        pub fn poses(&self, poses: &[(String, Pose)]) {
            self.view.publish_poses(&rovers(poses));
        }

        /// Stops watching and says on stderr what was published and dropped.
        pub fn finish(&self) {
            let watch = self.watch.lock().take();
            if let Some(w) = watch {
                let c = w.finish();
                eprintln!(
                    "foxglove: {} messages and outcomes observed, {} published, {} dropped (queue full), {} unpublishable",
                    c.observed, c.published, c.dropped, c.unpublishable
                );
            }
        }
    }

    /// Writes the rovers' poses into a recording with Foxglove's well-known schemas.
    pub struct PoseRecorder(PoseRecording);

    impl PoseRecorder {
        /// The recording's pose channels.
        pub fn new() -> PoseRecorder {
            PoseRecorder(PoseRecording::default())
        }

        /// A note for the user when a recording gets no poses (never, with the feature).
        pub const NOTE: Option<&'static str> = None;

        /// Writes the poses at `time` on the recorded systems' clock.
        pub fn write(&self, recorder: &Recorder, poses: &[(String, Pose)], time: hetcomm::Time) {
            self.0.write(recorder, &rovers(poses), time);
        }
    }
}

#[cfg(not(feature = "foxglove"))]
mod imp {
    use super::*;

    /// Never made: without the feature [`start`] refuses.
    pub enum Live {}

    /// Refuses: this build has no Foxglove server.
    pub fn start(_addr: &str, _name: &str) -> anyhow::Result<Live> {
        anyhow::bail!("this build has no Foxglove server: rebuild with `--features foxglove`")
    }

    impl Live {
        pub fn publish(&self, _pairs: &[PairRow], _systems: &[SystemRow]) -> anyhow::Result<()> {
            match *self {}
        }
        pub fn watch(&self, _systems: &[Comm]) -> anyhow::Result<()> {
            match *self {}
        }
        pub fn poses(&self, _poses: &[(String, Pose)]) {
            match *self {}
        }
        pub fn finish(&self) {
            match *self {}
        }
    }

    /// Without the feature a recording holds no poses for Foxglove's 3D panel.
    pub struct PoseRecorder;

    impl PoseRecorder {
        pub fn new() -> PoseRecorder {
            PoseRecorder
        }

        /// What the user is told when recording.
        pub const NOTE: Option<&'static str> = Some(
            "this build has no `foxglove` feature: the recording holds no rover poses for \
             Foxglove's 3D panel",
        );

        pub fn write(&self, _recorder: &Recorder, _poses: &[(String, Pose)], _time: hetcomm::Time) {
        }
    }
}

pub use imp::{start, Live, PoseRecorder};

impl FoxgloveArgs {
    /// The server when the flag is given (`name`: the command, shown to clients).
    pub fn start(&self, name: &str) -> anyhow::Result<Option<Live>> {
        self.foxglove.as_deref().map(|a| start(a, name)).transpose()
    }
}
