#!/usr/bin/env bash
# Tests of the `ros1` transport against a real ROS master.
#
# Installs the ROS 1 tools when missing (through scripts/install.sh: ros-core, python3-rospy,
# python3-rostopic, the message packages; python3-msgpack for the rospy example), then
# runs the transport crate's tests (conformance, master restart, first frame to a new peer,
# rospy interop, rostopic; the `ros1_bridge` against rosmsg, rostopic pub/echo and the rospy
# rover examples/ros1/tango_rover.py, Tango following included), `hetcomm validate` on the
# bridge's example fleets, the thesis's demonstration with the rospy rover as Tango
# (`hetcomm demo --fleet examples/ros1/leader-follower-ros1.toml` on a master of its own:
# Tango must receive the leader's four commands in order and keep within 10 units and 15
# degrees of the simulated run each second, scripts/tango-follows.py), the facade's tests
# (the security attack suite over ros1 included) and the CLI's `ros1_send` acceptance test
# (50 fresh `hetcomm send` processes, each delivered on the first attempt) and the bridge's
# (20 one-shot `hetcomm send` processes reach a running `rostopic echo`) with
# `--features ros1`.
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
HETCOMM="${CARGO_TARGET_DIR:-target}/debug/hetcomm"
"$HETCOMM" validate examples/ros1/tango-ros1.toml
"$HETCOMM" validate examples/ros1/leader-follower-ros1.toml

echo "== hetcomm demo with Tango as an external ROS 1 robot (examples/ros1/leader-follower-ros1.toml)"
OUT=$(mktemp -d)
# A master of its own on a free port, and the shipped fleet pointed at it.
PORT=$(/usr/bin/python3 -c 'import socket; s = socket.socket(); s.bind(("127.0.0.1", 0)); print(s.getsockname()[1])')
export ROS_MASTER_URI=http://127.0.0.1:$PORT ROS_LOG_DIR=$OUT/log
sed -e "s#^master_uri = \"http://127.0.0.1:11311\"#master_uri = \"$ROS_MASTER_URI\"#" \
    examples/ros1/leader-follower-ros1.toml > "$OUT/fleet.toml"
grep -q "^master_uri = \"$ROS_MASTER_URI\"" "$OUT/fleet.toml"
rosmaster --core -p "$PORT" > "$OUT/master.log" 2>&1 &
MASTER=$!
ROVER=
trap 'kill $ROVER $MASTER 2>/dev/null || true' EXIT
/usr/bin/python3 - "$ROS_MASTER_URI" <<'PY'
"""Waits (at most 15 s) for the master to answer."""
import sys, time, xmlrpc.client
deadline = time.monotonic() + 15
while True:
    try:
        xmlrpc.client.ServerProxy(sys.argv[1]).getSystemState("/ros1_test")
        break
    except OSError:
        assert time.monotonic() < deadline, f"no ROS master at {sys.argv[1]}"
        time.sleep(0.2)
PY
/usr/bin/python3 examples/ros1/tango_rover.py --prefix /tango --seconds 60 > "$OUT/rover.log" &
ROVER=$!
"$HETCOMM" demo --fleet "$OUT/fleet.toml" --out "$OUT/ros1" > "$OUT/ros1.txt"
kill $ROVER $MASTER 2>/dev/null || true
wait $ROVER $MASTER 2>/dev/null || true
trap - EXIT
unset ROS_MASTER_URI ROS_LOG_DIR
sed -n '/Table 11/,/^$/p;/Table 15/,/^$/p' "$OUT/ros1.txt"
"$HETCOMM" demo --out "$OUT/sim" > /dev/null 2> "$OUT/sim.err" || { cat "$OUT/sim.err"; exit 1; }
/usr/bin/python3 scripts/tango-follows.py "$OUT/ros1" "$OUT/sim"
rm -rf "$OUT"

echo "== facade and CLI with --features ros1"
cargo test -p hetcomm --features ros1 --lib
cargo test -p hetcomm --features ros1 --test security_attacks ros1::
cargo test -p hetcomm-cli --features ros1 --test ros1_send
# One-shot `hetcomm send` processes through the ros1_bridge to rostopic echo and rospy.
cargo test -p hetcomm-cli --features ros1 --test ros1_bridge_send
