//! Generates the Rust type of `std_msgs/UInt8MultiArray` (and the two messages it uses) from the
//! `.msg` files in `msg/std_msgs`, with roslibrust's code generator.

use std::path::PathBuf;

fn main() {
    let dir = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("msg");
    let (source, paths) =
        roslibrust_codegen::find_and_generate_ros_messages_without_ros_package_path(vec![
            dir.clone()
        ])
        .unwrap_or_else(|e| panic!("generating ROS message types from {}: {e}", dir.display()));
    let out = PathBuf::from(std::env::var("OUT_DIR").expect("cargo sets OUT_DIR"));
    std::fs::write(out.join("std_msgs.rs"), source.to_string())
        .unwrap_or_else(|e| panic!("writing generated ROS message types: {e}"));
    println!("cargo:rerun-if-changed=msg");
    for p in paths {
        println!("cargo:rerun-if-changed={}", p.display());
    }
}
