#!/usr/bin/env bash
# Everything about the `ros2` and `ros2_bridge` transports (docs/ros2.md, docs/ros-bridges.md).
# Called by scripts/test.sh.
#
#   bash scripts/ros2-test.sh
#
# 1. format and lint the ros2 crate (it is outside the workspace's members, so the
#    workspace-wide steps of test.sh do not see it), and the facade and CLI with
#    `--features ros2`;
# 2. the Python side: Cyclone DDS's Python package (PyPI `cyclonedds`, wheels that bundle the
#    C library; no ROS 2 install) in the project's venv, target/py-venv (scripts/install.sh);
# 3. the crate's tests, built once with the `cyclone` feature (the second DDS backend, Cyclone
#    DDS through `cyclors`, compiled from source with cmake: about a minute more on 2 cores), so
#    that every link test runs on rustdds and on Cyclone DDS: the link conformance suite (bare
#    and wrapped in emulation), fleet keys and their errors, delivery through the facade
#    (secured and `security = "none"`), a Cyclone-backed system and a rustdds-backed one
#    exchanging acknowledged messages, frames echoed by a Python `cyclonedds` program, and the
#    bridge against examples/ros2/tango_rover.py (a Cyclone DDS ROS 2 rover): Twist out,
#    Odometry and String back, mismatches, garbage and wrong-type publishers; then, without
#    the feature, the fleet-key test (`dds = "cyclone"` refused, naming the feature); presence
#    (peers up and down) and the plain-DDS `dds` kind against a Python participant with its
#    own IDL type run among the crate's tests; then the CLI's one-shot sends
#    (crates/hetcomm-cli/tests/ros2_send.rs);
# 4. the demos: the rover follows a hetcomm leader (crates/hetcomm-link-ros2/examples/tango_follows.rs),
#    printing a table; it fails if Tango ends more than 1 m from its target. Then the thesis's
#    demonstration, `hetcomm demo --fleet examples/ros2/leader-follower-ros2.toml`, with the
#    rover as Tango: Tango must receive the leader's four commands in order and keep within
#    a bound of where the simulated run (virtual time, every rover ours) puts it.
#
# rustdds is compiled once (debug) and shared by both workspaces' builds in the same target
# directory: the crate's Cargo.lock pins the versions the main Cargo.lock has.
set -euo pipefail
cd "$(dirname "$0")/.."
ROOT=$PWD
export CARGO_TARGET_DIR=${CARGO_TARGET_DIR:-$ROOT/target}
CRATE=crates/hetcomm-link-ros2/Cargo.toml

step() { printf '\n== %s\n' "$*"; }

step "ros2: Debian packages (cmake and libclang build Cyclone DDS for the cyclone feature)"
bash scripts/install.sh apt

step "ros2: format and lint"
# Not `--all`: that would also check the path dependencies (main workspace crates), with
# settings that differ from the workspace's own `cargo fmt` run.
cargo fmt --manifest-path "$CRATE" -- --check
cargo clippy --manifest-path "$CRATE" --all-targets -- -D warnings
cargo clippy --manifest-path "$CRATE" --all-targets --features cyclone -- -D warnings
cargo clippy -p hetcomm-cli --features ros2 --all-targets -- -D warnings

step "ros2: Cyclone DDS for Python in target/py-venv"
bash scripts/install.sh python
VENV=$ROOT/target/py-venv
export HETCOMM_ROS2_PYTHON=$VENV/bin/python

step "ros2: crate tests on rustdds and Cyclone DDS (conformance, keys, delivery, interop, bridge)"
cargo test --manifest-path "$CRATE" --features cyclone
cargo test --manifest-path "$CRATE" --test fleet the_keys_parse

step "ros2: one-shot hetcomm send processes (50 over ros2, 20 through the bridge to Cyclone DDS)"
cargo test -p hetcomm-cli --features ros2 --test ros2_send

step "ros2: hetcomm validate on the bridge example (CLI with --features ros2)"
cargo build -q -p hetcomm-cli --features ros2
"$CARGO_TARGET_DIR/debug/hetcomm" validate examples/ros2/tango-ros2.toml

step "ros2: demo: Tango (Cyclone DDS rover) follows hetcomm's leader through typed topics"
cargo build -q --manifest-path "$CRATE" --example tango_follows
PREFIX=/hc_demo_$$
"$HETCOMM_ROS2_PYTHON" examples/ros2/tango_rover.py --prefix "$PREFIX" --domain 5 --seconds 40 >/dev/null &
ROVER=$!
trap 'kill $ROVER 2>/dev/null || true' EXIT
"$CARGO_TARGET_DIR/debug/examples/tango_follows" --prefix "$PREFIX" --domain 5 --seconds 15
kill $ROVER 2>/dev/null || true
wait $ROVER 2>/dev/null || true
trap - EXIT

step "ros2: hetcomm demo with Tango as an external ROS 2 robot (examples/ros2/leader-follower-ros2.toml)"
OUT=$(mktemp -d)
PREFIX=/hc_lf_$$
# The shipped fleet on its own domain and topics, so that parallel runs do not meet.
sed -e "s#\"/tango/#\"$PREFIX/#" -e 's/^domain_id = 0 /domain_id = 7 /' \
    examples/ros2/leader-follower-ros2.toml > "$OUT/fleet.toml"
grep -q "^domain_id = 7 " "$OUT/fleet.toml" && grep -q "\"$PREFIX/odom\"" "$OUT/fleet.toml"
"$HETCOMM_ROS2_PYTHON" examples/ros2/tango_rover.py --prefix "$PREFIX" --domain 7 --seconds 60 \
    > "$OUT/rover.log" &
ROVER=$!
trap 'kill $ROVER 2>/dev/null || true' EXIT
"$CARGO_TARGET_DIR/debug/hetcomm" demo --fleet "$OUT/fleet.toml" --out "$OUT/ros2" > "$OUT/ros2.txt"
kill $ROVER 2>/dev/null || true
wait $ROVER 2>/dev/null || true
trap - EXIT
sed -n '/Table 11/,/^$/p;/Table 15/,/^$/p' "$OUT/ros2.txt"
"$CARGO_TARGET_DIR/debug/hetcomm" demo --out "$OUT/sim" > /dev/null 2> "$OUT/sim.err" \
    || { cat "$OUT/sim.err"; exit 1; }
"$HETCOMM_ROS2_PYTHON" scripts/tango-follows.py "$OUT/ros2" "$OUT/sim"
rm -rf "$OUT"
