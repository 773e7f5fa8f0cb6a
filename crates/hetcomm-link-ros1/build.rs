//! Generates the Rust types of the ROS 1 messages this crate uses from the `.msg` files in
//! `msg/` (copied from Debian's ROS 1 packages), with roslibrust's code generator:
//! `std_msgs/UInt8MultiArray` (and the two messages it uses) for the `ros1` transport, and the
//! standard types the `ros1_bridge` maps (their MD5 sums and full definitions). And the
//! subscriber slots of the `ros1_bridge`: one Rust type per shipped ROS 1 type
//! (`hetcomm-rosmsg/msg/ros1-md5sums.txt`), so that ROS 1 checks each subscription's MD5 sum.

use std::path::PathBuf;

fn main() {
    // Read at run time, not baked in with env!: a build script compiled for one checkout and
    // reused from a shared target directory must look in the checkout being built.
    let manifest = std::env::var("CARGO_MANIFEST_DIR").expect("cargo sets CARGO_MANIFEST_DIR");
    let dir = PathBuf::from(&manifest).join("msg");
    let (source, paths) =
        roslibrust_codegen::find_and_generate_ros_messages_without_ros_package_path(vec![
            dir.clone()
        ])
        .unwrap_or_else(|e| panic!("generating ROS message types from {}: {e}", dir.display()));
    let out = PathBuf::from(std::env::var("OUT_DIR").expect("cargo sets OUT_DIR"));
    std::fs::write(out.join("ros_msgs.rs"), source.to_string())
        .unwrap_or_else(|e| panic!("writing generated ROS message types: {e}"));
    println!("cargo:rerun-if-changed=msg");
    slots(&PathBuf::from(&manifest), &out);
    for p in paths {
        println!("cargo:rerun-if-changed={}", p.display());
    }
}

/// Writes `$OUT_DIR/slots.rs`: `SLOTS`, the (type, MD5 sum) of every shipped ROS 1 type, and
/// `subscribe_slot`, which subscribes with the slot type of an index.
fn slots(manifest: &std::path::Path, out: &std::path::Path) {
    let table = manifest.join("../hetcomm-rosmsg/msg/ros1-md5sums.txt");
    let text = std::fs::read_to_string(&table)
        .unwrap_or_else(|e| panic!("reading {}: {e}", table.display()));
    let rows: Vec<(&str, &str)> = text
        .lines()
        .filter(|l| !l.starts_with('#') && !l.trim().is_empty())
        .map(|l| l.split_once(' ').expect("`TYPE MD5` lines"))
        .collect();
    let mut src = format!(
        "pub(super) const SLOTS: [(&str, &str); {}] = [\n",
        rows.len()
    );
    for (name, md5) in &rows {
        src.push_str(&format!("    ({name:?}, {md5:?}),\n"));
    }
    src.push_str("];\n\n");
    src.push_str(
        "/// Subscribes to `topic` with the slot type of `SLOTS[index]`.\n\
         pub(super) async fn subscribe_slot(index: usize, node: &NodeHandle, topic: &str, \
         queue: usize) -> Result<Guard, String> {\n    match index {\n",
    );
    for i in 0..rows.len() {
        src.push_str(&format!(
            "        {i} => subscribe_typed::<{i}>(node, topic, queue).await,\n"
        ));
    }
    src.push_str("        _ => Err(format!(\"no slot {index}\")),\n    }\n}\n");
    std::fs::write(out.join("slots.rs"), src).unwrap_or_else(|e| panic!("writing slots.rs: {e}"));
    println!("cargo:rerun-if-changed={}", table.display());
}
