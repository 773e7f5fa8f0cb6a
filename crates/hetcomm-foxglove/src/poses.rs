//! The rovers in Foxglove's 3D panel: their poses as the well-known schemas of the SDK
//! (`foxglove::schemas`, protobuf), live ([`crate::FoxgloveView::publish_poses`]) and in
//! recordings ([`PoseRecording`]).
//!
//! * `/tf` (`foxglove.FrameTransforms`): one transform per rover, parent frame [`WORLD_FRAME`],
//!   child frame the rover's name, translation (x, y, 0) in world units, rotation the heading
//!   about +z;
//! * `/hetcomm/rovers` (`foxglove.SceneUpdate`): one entity per rover, locked to its frame: a
//!   box, an arrow along its heading and its name; and one per rover in the `world` frame,
//!   `<rover>/trail`, the line it has driven so far.

use parking_lot::Mutex;
use std::collections::BTreeMap;
use std::sync::Arc;

use foxglove::messages::{
    line_primitive, ArrowPrimitive, Color, CubePrimitive, FrameTransform, FrameTransforms,
    LinePrimitive, Point3, Pose, Quaternion, SceneEntity, SceneUpdate, TextPrimitive, Timestamp,
    Vector3,
};
use foxglove::{Channel, ChannelBuilder, Context, Encode};
use hetcomm::Time;
use hetcomm_record::{OtherChannel, Recorder};

/// The transforms' topic.
pub const TF_TOPIC: &str = "/tf";
/// The rovers' scene topic.
pub const SCENE_TOPIC: &str = "/hetcomm/rovers";
/// The fixed frame the rovers' frames hang from (the virtual environment's coordinates).
pub const WORLD_FRAME: &str = "world";

/// One rover's pose in the virtual environment.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RoverPose<'a> {
    /// The rover's name: its frame id and its entity's id.
    pub name: &'a str,
    /// East, world units.
    pub x: f64,
    /// North, world units.
    pub y: f64,
    /// Heading in degrees, counter-clockwise from +x.
    pub heading_deg: f64,
}

/// A rover's box (world units: the demo's rovers are about 400 units apart, wheel base 200).
const BOX: Vector3 = Vector3 {
    x: 60.0,
    y: 40.0,
    z: 20.0,
};

fn stamp(ns: u64) -> Timestamp {
    Timestamp::new((ns / 1_000_000_000) as u32, (ns % 1_000_000_000) as u32)
}

fn heading(deg: f64) -> Quaternion {
    let half = deg.to_radians() / 2.0;
    Quaternion {
        x: 0.0,
        y: 0.0,
        z: half.sin(),
        w: half.cos(),
    }
}

/// A colour per rover, the same for a name in every run.
fn colour(name: &str) -> Color {
    const PALETTE: [(f64, f64, f64); 6] = [
        (0.90, 0.30, 0.24),
        (0.20, 0.60, 0.86),
        (0.18, 0.80, 0.44),
        (0.95, 0.77, 0.06),
        (0.61, 0.35, 0.71),
        (0.90, 0.49, 0.13),
    ];
    let i = name
        .bytes()
        .fold(0usize, |h, b| h.wrapping_mul(31) + b as usize)
        % PALETTE.len();
    let (r, g, b) = PALETTE[i];
    Color { r, g, b, a: 1.0 }
}

/// `world` → each rover's frame, stamped `ns` (nanoseconds on the clock of the log times).
fn frame_transforms(rovers: &[RoverPose<'_>], ns: u64) -> FrameTransforms {
    FrameTransforms {
        transforms: rovers
            .iter()
            .map(|r| FrameTransform {
                timestamp: Some(stamp(ns)),
                parent_frame_id: WORLD_FRAME.to_string(),
                child_frame_id: r.name.to_string(),
                translation: Some(Vector3 {
                    x: r.x,
                    y: r.y,
                    z: 0.0,
                }),
                rotation: Some(heading(r.heading_deg)),
            })
            .collect(),
    }
}

/// A trail point is added once a rover is this far (world units) from the last one.
const TRAIL_STEP: f64 = 1.0;
/// Points kept per trail (the oldest go first).
const TRAIL_POINTS: usize = 2000;

/// The line each rover has driven, for its trail entity.
#[derive(Debug, Default)]
pub(crate) struct Trails(Mutex<BTreeMap<String, Vec<Point3>>>);

impl Trails {
    /// Adds the rovers' positions (where they moved far enough) and returns every trail.
    fn extend(&self, rovers: &[RoverPose<'_>]) -> Vec<(String, Vec<Point3>)> {
        let mut trails = self.0.lock();
        for r in rovers {
            let trail = trails.entry(r.name.to_string()).or_default();
            let far = trail
                .last()
                .map_or(true, |p| (p.x - r.x).hypot(p.y - r.y) >= TRAIL_STEP);
            if far {
                if trail.len() == TRAIL_POINTS {
                    trail.remove(0);
                }
                trail.push(Point3 {
                    x: r.x,
                    y: r.y,
                    z: 0.0,
                });
            }
        }
        trails.iter().map(|(n, t)| (n.clone(), t.clone())).collect()
    }
}

/// A box, a heading arrow and a label per rover, each in (and locked to) its rover's frame,
/// and each rover's trail in the `world` frame.
fn scene_update(
    rovers: &[RoverPose<'_>],
    ns: u64,
    trails: &[(String, Vec<Point3>)],
) -> SceneUpdate {
    let identity = |x: f64, z: f64| Pose {
        position: Some(Vector3 { x, y: 0.0, z }),
        orientation: Some(heading(0.0)),
    };
    SceneUpdate {
        deletions: Vec::new(),
        entities: rovers
            .iter()
            .map(|r| {
                let color = colour(r.name);
                SceneEntity {
                    timestamp: Some(stamp(ns)),
                    frame_id: r.name.to_string(),
                    id: r.name.to_string(),
                    lifetime: None,
                    frame_locked: true,
                    cubes: vec![CubePrimitive {
                        pose: Some(identity(0.0, BOX.z / 2.0)),
                        size: Some(BOX),
                        color: Some(color),
                    }],
                    arrows: vec![ArrowPrimitive {
                        pose: Some(identity(BOX.x / 2.0, BOX.z / 2.0)),
                        shaft_length: 30.0,
                        shaft_diameter: 6.0,
                        head_length: 15.0,
                        head_diameter: 15.0,
                        color: Some(color),
                    }],
                    texts: vec![TextPrimitive {
                        pose: Some(identity(0.0, BOX.z * 2.5)),
                        billboard: true,
                        font_size: 16.0,
                        scale_invariant: true,
                        color: Some(Color {
                            r: 1.0,
                            g: 1.0,
                            b: 1.0,
                            a: 1.0,
                        }),
                        text: r.name.to_string(),
                    }],
                    ..SceneEntity::default()
                }
            })
            .chain(trails.iter().map(|(name, points)| SceneEntity {
                timestamp: Some(stamp(ns)),
                frame_id: WORLD_FRAME.to_string(),
                id: format!("{name}/trail"),
                lines: vec![LinePrimitive {
                    r#type: line_primitive::Type::LineStrip as i32,
                    pose: Some(identity(0.0, 0.0)),
                    thickness: 2.0,
                    scale_invariant: true,
                    points: points.clone(),
                    color: Some(colour(name)),
                    ..LinePrimitive::default()
                }],
                ..SceneEntity::default()
            }))
            .collect(),
    }
}

/// The live channels of the poses.
pub(crate) struct PoseChannels {
    tf: Channel<FrameTransforms>,
    scene: Channel<SceneUpdate>,
    trails: Trails,
}

impl PoseChannels {
    pub(crate) fn new(context: &Arc<Context>) -> PoseChannels {
        PoseChannels {
            tf: ChannelBuilder::new(TF_TOPIC).context(context).build(),
            scene: ChannelBuilder::new(SCENE_TOPIC).context(context).build(),
            trails: Trails::default(),
        }
    }

    /// Publishes the poses stamped now on the wall clock (the viewer may be on another host).
    pub(crate) fn publish(&self, rovers: &[RoverPose<'_>]) {
        let ns = Time::now_wall().as_micros() * 1000;
        self.tf.log_with_time(&frame_transforms(rovers, ns), ns);
        let trails = self.trails.extend(rovers);
        self.scene
            .log_with_time(&scene_update(rovers, ns, &trails), ns);
    }
}

/// Writes the poses into a recording beside its events, with the well-known schemas, so the
/// recording opens in Foxglove with the rovers in the 3D panel.
#[derive(Debug)]
pub struct PoseRecording {
    tf: OtherChannel,
    scene: OtherChannel,
    trails: Trails,
}

impl Default for PoseRecording {
    fn default() -> Self {
        PoseRecording {
            tf: other_channel::<FrameTransforms>(TF_TOPIC),
            scene: other_channel::<SceneUpdate>(SCENE_TOPIC),
            trails: Trails::default(),
        }
    }
}

impl PoseRecording {
    /// Writes the poses at `time`, on the recorded systems' clock (the recording's log
    /// times; the messages' stamps are the same instant). A message that does not encode is
    /// counted as lost by the recorder's summary, like any other.
    pub fn write(&self, recorder: &Recorder, rovers: &[RoverPose<'_>], time: Time) {
        let ns = time.as_micros() * 1000;
        write_encoded(recorder, &self.tf, &frame_transforms(rovers, ns), time);
        let trails = self.trails.extend(rovers);
        let scene = scene_update(rovers, ns, &trails);
        write_encoded(recorder, &self.scene, &scene, time);
    }
}

fn write_encoded<T: Encode>(recorder: &Recorder, channel: &OtherChannel, msg: &T, time: Time) {
    let mut buf = Vec::with_capacity(msg.encoded_len().unwrap_or(256));
    match msg.encode(&mut buf) {
        Ok(()) => recorder.write_other(channel, time, &buf),
        // Counted as lost: an empty write of a channel that cannot exist would hide it.
        Err(_) => recorder.count_lost(),
    }
}

fn other_channel<T: Encode>(topic: &str) -> OtherChannel {
    let schema = T::get_schema();
    OtherChannel {
        topic: topic.to_string(),
        message_encoding: T::get_message_encoding(),
        schema_name: schema.as_ref().map(|s| s.name.clone()).unwrap_or_default(),
        schema_encoding: schema
            .as_ref()
            .map(|s| s.encoding.clone())
            .unwrap_or_default(),
        schema: schema.map(|s| s.data.into_owned()).unwrap_or_default(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn poses_become_transforms_and_entities_in_the_rovers_frames() {
        let rovers = [
            RoverPose {
                name: "Alpha",
                x: -190.5,
                y: -200.0,
                heading_deg: 90.0,
            },
            RoverPose {
                name: "Tango",
                x: 191.5,
                y: 60.0,
                heading_deg: 180.0,
            },
        ];
        let tf = frame_transforms(&rovers, 1_500_000_000_250);
        assert_eq!(tf.transforms.len(), 2);
        let a = &tf.transforms[0];
        assert_eq!(
            (a.parent_frame_id.as_str(), a.child_frame_id.as_str()),
            ("world", "Alpha")
        );
        assert_eq!(a.translation.unwrap().x, -190.5);
        let q = a.rotation.unwrap();
        assert!(
            (q.z - std::f64::consts::FRAC_1_SQRT_2).abs() < 1e-12,
            "{q:?}"
        );
        assert!(
            (q.w - std::f64::consts::FRAC_1_SQRT_2).abs() < 1e-12,
            "{q:?}"
        );
        assert_eq!(a.timestamp, Some(Timestamp::new(1500, 250)));
        let scene = scene_update(&rovers, 0, &[]);
        assert_eq!(scene.entities[1].frame_id, "Tango");
        assert!(scene.entities[1].frame_locked);
        assert_eq!(scene.entities[1].texts[0].text, "Tango");
        // Trails grow as the rovers move, in the world frame.
        let trails = Trails::default();
        trails.extend(&rovers);
        let moved = [RoverPose {
            x: -180.0,
            ..rovers[0]
        }];
        let t = trails.extend(&moved);
        assert_eq!(t[0].0, "Alpha");
        assert_eq!(t[0].1.len(), 2);
        assert_eq!(
            trails.extend(&moved)[0].1.len(),
            2,
            "no point while standing still"
        );
        let scene = scene_update(&moved, 0, &t);
        let trail = scene
            .entities
            .iter()
            .find(|e| e.id == "Alpha/trail")
            .unwrap();
        assert_eq!(trail.frame_id, "world");
        assert_eq!(trail.lines[0].points[1].x, -180.0);
        let ch = other_channel::<FrameTransforms>(TF_TOPIC);
        assert_eq!(ch.schema_name, "foxglove.FrameTransforms");
        assert_eq!(
            (ch.schema_encoding.as_str(), ch.message_encoding.as_str()),
            ("protobuf", "protobuf")
        );
        assert!(!ch.schema.is_empty());
    }
}
