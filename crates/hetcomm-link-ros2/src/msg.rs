//! The message type that carries frames: ROS 2's `std_msgs/msg/UInt8MultiArray`, in CDR.

use serde::{Deserialize, Serialize};

/// The ROS 2 type name of [`FrameMessage`].
pub const FRAME_TYPE: &str = "std_msgs/msg/UInt8MultiArray";

/// `std_msgs/msg/MultiArrayDimension`.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct MultiArrayDimension {
    /// Label of the dimension.
    pub label: String,
    /// Size of the dimension.
    pub size: u32,
    /// Stride of the dimension.
    pub stride: u32,
}

/// `std_msgs/msg/MultiArrayLayout`.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct MultiArrayLayout {
    /// The dimensions (empty for a frame).
    pub dim: Vec<MultiArrayDimension>,
    /// Padding elements at the front of `data` (0 for a frame).
    pub data_offset: u32,
}

/// `std_msgs/msg/UInt8MultiArray`: `layout` is left empty and `data` holds exactly one hetcomm
/// frame (docs/wire-format.md), as on the `ros1` transport.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct FrameMessage {
    /// Left empty.
    pub layout: MultiArrayLayout,
    /// One frame (a CDR `sequence<octet>`, written and read in one piece).
    #[serde(with = "serde_bytes")]
    pub data: Vec<u8>,
}
