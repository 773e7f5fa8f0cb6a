#!/usr/bin/env bash
# Tests of the `ros1` transport against a real ROS master.
#
# Installs the ROS 1 tools when missing (through scripts/install.sh: ros-core, python3-rospy,
# python3-rostopic, the message packages; python3-msgpack for the rospy example), then
# runs the transport crate's tests (conformance, master restart, first frame to a new peer,
# rospy interop, rostopic; the `ros1_bridge` against rosmsg, rostopic pub/echo and the rospy
# rover examples/ros1/tango_rover.py, Tango following included), `hetcomm validate` on the
# bridge's example fleet, the facade's tests (the security attack suite over ros1
# included) and the CLI's `ros1_send` acceptance test (50
# fresh `hetcomm send` processes, each delivered on the first attempt) with `--features ros1`.
# Called by scripts/test.sh.
set -euo pipefail
cd "$(dirname "$0")/.."

bash scripts/install.sh apt

# Nodes of this machine reach each other (and the test masters) over loopback.
export ROS_HOSTNAME="${ROS_HOSTNAME:-127.0.0.1}"

echo "== cargo test -p hetcomm-link-ros1"
cargo test -p hetcomm-link-ros1

echo "== hetcomm validate on the ROS 1 bridge example (CLI with --features ros1)"
cargo build -q -p hetcomm-cli --features ros1
"${CARGO_TARGET_DIR:-target}/debug/hetcomm" validate examples/ros1/tango-ros1.toml

echo "== facade and CLI with --features ros1"
cargo test -p hetcomm --features ros1 --lib
cargo test -p hetcomm --features ros1 --test security_attacks ros1::
cargo test -p hetcomm-cli --features ros1 --test ros1_send
