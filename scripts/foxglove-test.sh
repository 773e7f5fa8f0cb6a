#!/usr/bin/env bash
# The live Foxglove view (docs/foxglove.md). Called by scripts/test.sh.
#
#   bash scripts/foxglove-test.sh
#
# 1. format and lint the hetcomm-foxglove crate (outside the workspace's members, so the
#    workspace-wide steps of test.sh do not see it) and the CLI with `--features foxglove`;
# 2. the crate's unit tests;
# 3. a live run: `hetcomm monitor --foxglove 127.0.0.1:0` receiving the reports of a real-time
#    leader–follower demo, and a Python client written from the Foxglove WebSocket protocol
#    (scripts/foxglove-client.py) subscribing and checking the counters it decodes.
set -euo pipefail
cd "$(dirname "$0")/.."
ROOT=$PWD
TARGET=${CARGO_TARGET_DIR:-$ROOT/target}
# Same target directory as the workspace, and the crate's Cargo.lock pins the versions of the
# main Cargo.lock: the dependencies build once for both.
export CARGO_TARGET_DIR=$TARGET
CRATE=crates/hetcomm-foxglove/Cargo.toml
PY=${FOXGLOVE_PYTHON:-$ROOT/target/py-venv/bin/python}

step() { printf '\n== %s\n' "$*"; }

step "foxglove: format and lint"
cargo fmt --manifest-path "$CRATE" --all -- --check
cargo clippy --manifest-path "$CRATE" --all-targets -- -D warnings
cargo clippy -p hetcomm-cli --features foxglove --all-targets -- -D warnings

step "foxglove: crate tests"
cargo test -q --manifest-path "$CRATE"

step "foxglove: a live monitor served to a WebSocket client"
cargo build -q -p hetcomm-cli --features foxglove
HETCOMM=$TARGET/debug/hetcomm
work=$(mktemp -d)
pids=()
cleanup() {
    for p in "${pids[@]}"; do kill "$p" 2>/dev/null || true; done
    wait 2>/dev/null || true
    rm -rf "$work"
}
trap cleanup EXIT
# Port 0 for both: the monitor's UDP port is fixed below, the WebSocket port is read back.
udp_port=$((20000 + RANDOM % 20000))
"$HETCOMM" monitor examples/leader_follower/fleet.toml --json --listen "127.0.0.1:$udp_port" \
    --foxglove 127.0.0.1:0 --duration 60 >"$work/monitor.jsonl" 2>"$work/monitor.err" &
pids+=($!)
for _ in $(seq 100); do
    grep -q 'foxglove: serving on' "$work/monitor.err" && break
    sleep 0.1
done
ws_port=$(sed -n 's|^foxglove: serving on ws://[^:]*:\([0-9]*\).*|\1|p' "$work/monitor.err")
[ -n "$ws_port" ] || { cat "$work/monitor.err"; echo "monitor did not start its server" >&2; exit 1; }
HETCOMM_MONITOR=127.0.0.1:$udp_port "$HETCOMM" demo --realtime --out "$work/demo" >"$work/demo.log" 2>&1 &
pids+=($!)
"$PY" scripts/foxglove-client.py "$ws_port"
echo "foxglove: live view checked"
