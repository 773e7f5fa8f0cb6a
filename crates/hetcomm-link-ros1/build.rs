//! Generates the Rust types of the ROS 1 messages this crate uses from the `.msg` files in
//! `msg/` (copied from Debian's ROS 1 packages), with roslibrust's code generator:
//! `std_msgs/UInt8MultiArray` (and the two messages it uses) for the `ros1` transport, and the
//! standard types the `ros1_bridge` maps (their MD5 sums and full definitions).

use std::path::PathBuf;

fn main() {
    // Read at run time, not baked in with env!: a build script compiled for one checkout and
    // reused from a shared target directory must look in the checkout being built.
    let manifest = std::env::var("CARGO_MANIFEST_DIR").expect("cargo sets CARGO_MANIFEST_DIR");
    let dir = PathBuf::from(manifest).join("msg");
    let (source, paths) =
        roslibrust_codegen::find_and_generate_ros_messages_without_ros_package_path(vec![
            dir.clone()
        ])
        .unwrap_or_else(|e| panic!("generating ROS message types from {}: {e}", dir.display()));
    let out = PathBuf::from(std::env::var("OUT_DIR").expect("cargo sets OUT_DIR"));
    std::fs::write(out.join("ros_msgs.rs"), source.to_string())
        .unwrap_or_else(|e| panic!("writing generated ROS message types: {e}"));
    println!("cargo:rerun-if-changed=msg");
    for p in paths {
        println!("cargo:rerun-if-changed={}", p.display());
    }
}
