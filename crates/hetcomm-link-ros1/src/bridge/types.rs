//! The ROS 1 side of the bridge's types: each known schema's generated Rust type (for its MD5
//! sum and definition, and for a subscriber that ROS 1 matches by MD5 sum), and the receive
//! task that turns its messages into hetcomm frames.

use std::sync::{Arc, Mutex};

use hetcomm_rosmsg::bridge::{FrameMaker, Tally};
use hetcomm_rosmsg::codec::{self, Wire};
use hetcomm_rosmsg::schema::RosType;
use roslibrust::ros1::{NodeHandle, Subscriber};
use roslibrust::{MessageDescriptor, RosMessageType};
use tokio::sync::mpsc;

use super::Inbound;
use crate::msgs::{geometry_msgs, nav_msgs, sensor_msgs, std_msgs};

/// Calls `$body` with `$T` the generated type of the schema named `$name` (one of
/// `Flavour::Ros1.known()`, which settings are checked against).
macro_rules! with_type {
    ($name:expr, $T:ident => $body:expr) => {
        match $name {
            "std_msgs/String" => {
                type $T = std_msgs::String;
                $body
            }
            "std_msgs/Float64" => {
                type $T = std_msgs::Float64;
                $body
            }
            "geometry_msgs/Twist" => {
                type $T = geometry_msgs::Twist;
                $body
            }
            "geometry_msgs/Pose" => {
                type $T = geometry_msgs::Pose;
                $body
            }
            "geometry_msgs/PoseStamped" => {
                type $T = geometry_msgs::PoseStamped;
                $body
            }
            "nav_msgs/Odometry" => {
                type $T = nav_msgs::Odometry;
                $body
            }
            _ => {
                type $T = sensor_msgs::NavSatFix;
                $body
            }
        }
    };
}

/// The ROS 1 description (type name, MD5 sum, full definition) of a known type.
pub fn description(schema: &RosType) -> &'static MessageDescriptor {
    fn of<T: RosMessageType>() -> &'static MessageDescriptor {
        &T::DESCRIPTION
    }
    with_type!(schema.name, T => of::<T>())
}

/// Subscribes to `inb`'s topic with its type's MD5 sum and spawns the task that converts each
/// message into a frame for `frames`.
pub(super) async fn subscribe(
    node: &NodeHandle,
    inb: Inbound,
    queue: usize,
    maker: Arc<Mutex<FrameMaker>>,
    frames: mpsc::Sender<Vec<u8>>,
    tally: Arc<Tally>,
) -> Result<(), String> {
    let topic = inb.mapping.topic.clone();
    with_type!(inb.mapping.ros_type(), T => {
        let sub: Subscriber<T> = node
            .subscribe(&topic, queue)
            .await
            .map_err(|e| format!("subscribing to {topic}: {e}"))?;
        tokio::spawn(receive(sub, inb, maker, frames, tally));
    });
    Ok(())
}

async fn receive<T: RosMessageType>(
    mut sub: Subscriber<T>,
    inb: Inbound,
    maker: Arc<Mutex<FrameMaker>>,
    frames: mpsc::Sender<Vec<u8>>,
    tally: Arc<Tally>,
) {
    let (topic, schema) = (&inb.mapping.topic, inb.mapping.schema);
    while let Some(next) = sub.next().await {
        let msg = match next {
            Ok(msg) => msg,
            Err(e) => {
                // roslibrust does not export its error type: a lag says how many it skipped
                // ("you are too slow, N messages were skipped"), anything else is one message.
                let text = e.to_string();
                let lagged = text
                    .strip_prefix("you are too slow, ")
                    .and_then(|rest| rest.split(' ').next()?.parse::<u64>().ok());
                match lagged {
                    Some(n) => tally.dropped(
                        n,
                        format!("the bridge fell behind on {topic}: messages were lost"),
                    ),
                    None => tally.dropped(
                        1,
                        format!(
                            "a message on {topic} is not a {}: {text} (dropped)",
                            schema.name
                        ),
                    ),
                }
                continue;
            }
        };
        // The generated type checked the wire bytes; the schema names the fields.
        let value = roslibrust_serde_rosmsg::to_vec_skip_length(&msg)
            .map_err(|e| e.to_string())
            .and_then(|body| codec::decode(&body, schema, Wire::Ros1));
        let value = match value {
            Ok(v) => v,
            Err(e) => {
                let why = format!(
                    "a message on {topic} is not a {}: {e} (dropped)",
                    schema.name
                );
                tally.dropped(1, why);
                continue;
            }
        };
        let frame = maker.lock().unwrap_or_else(|e| e.into_inner()).frame(
            inb.module,
            inb.mapping.message,
            &value,
        );
        match frame {
            Ok(f) => {
                tally.received();
                // Waits only while the sink is busy; the subscriber's queue absorbs bursts.
                if frames.send(f).await.is_err() {
                    return;
                }
            }
            Err(e) => tally.dropped(1, format!("a message on {topic} {e}")),
        }
    }
}
