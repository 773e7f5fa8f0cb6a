#!/usr/bin/env bash
# The live Foxglove view (docs/foxglove.md). Called by scripts/test.sh.
#
#   bash scripts/foxglove-test.sh
#
# 1. format and lint the hetcomm-foxglove crate (outside the workspace's members, so the
#    workspace-wide steps of test.sh do not see it) and the CLI with `--features foxglove`;
# 2. the crate's unit tests;
# 3. a live run: a real-time leader–follower demo with `--foxglove 127.0.0.1:0 --record FILE`,
#    reporting its statistics to `hetcomm monitor --foxglove 127.0.0.1:0` in another process;
#    Python clients written from the Foxglove WebSocket protocol (scripts/foxglove-client.py)
#    subscribe to both servers and check what they decode (the monitor's counters; the demo's
#    messages, outcomes, poses and counters), then the recording is read with the `mcap`
#    package and its well-known schemas' fields are checked;
# 4. `hetcomm listen --foxglove` on a secured fleet receiving a keyed sender and an impostor
#    (messages and security rejections checked), and `hetcomm replay --foxglove` of the
#    demo's recording.
set -euo pipefail
cd "$(dirname "$0")/.."
ROOT=$PWD
TARGET=${CARGO_TARGET_DIR:-$ROOT/target}
# Same target directory as the workspace, and the crate's Cargo.lock pins the versions of the
# main Cargo.lock: the dependencies build once for both.
export CARGO_TARGET_DIR=$TARGET
CRATE=crates/hetcomm-foxglove/Cargo.toml
PY=${FOXGLOVE_PYTHON:-$ROOT/target/py-venv/bin/python}
# websockets, mcap, protobuf (quick when they are installed already).
[ -n "${FOXGLOVE_PYTHON:-}" ] || bash scripts/install.sh python

step() { printf '\n== %s\n' "$*"; }

step "foxglove: format and lint"
cargo fmt --manifest-path "$CRATE" --all -- --check
cargo clippy --manifest-path "$CRATE" --all-targets -- -D warnings
cargo clippy -p hetcomm-cli --features foxglove --all-targets -- -D warnings

step "foxglove: crate tests"
cargo test -q --manifest-path "$CRATE"

step "foxglove: a live monitor and a live demo served to WebSocket clients, and the demo's recording"
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
# The WebSocket port printed on stderr by a command started with `--foxglove 127.0.0.1:0`.
ws_port() {
    local err=$1
    for _ in $(seq 100); do
        grep -qs 'foxglove: serving on' "$err" && break
        sleep 0.1
    done
    local port
    port=$(sed -n 's|^foxglove: serving on ws://[^:]*:\([0-9]*\).*|\1|p' "$err")
    [ -n "$port" ] || { cat "$err" >&2; echo "no Foxglove server in $err" >&2; return 1; }
    echo "$port"
}
# One real-time demo serves both views: it reports to a monitor (a second process, as a
# multi-process fleet's would), serves its own messages and poses with --foxglove, and records.
udp_port=$((20000 + RANDOM % 20000))
"$HETCOMM" monitor examples/leader_follower/fleet.toml --json --listen "127.0.0.1:$udp_port" \
    --foxglove 127.0.0.1:0 --duration 60 >"$work/monitor.jsonl" 2>"$work/monitor.err" &
pids+=($!)
monitor_ws=$(ws_port "$work/monitor.err")
HETCOMM_MONITOR=127.0.0.1:$udp_port "$HETCOMM" demo --realtime --foxglove 127.0.0.1:0 \
    --record "$work/run.mcap" --out "$work/demo" >"$work/demo.log" 2>"$work/demo.err" &
demo_pid=$!
pids+=($demo_pid)
demo_ws=$(ws_port "$work/demo.err")
"$PY" scripts/foxglove-client.py monitor "$monitor_ws" &
monitor_client=$!
"$PY" scripts/foxglove-client.py demo "$demo_ws"
wait "$monitor_client"
wait "$demo_pid" || { cat "$work/demo.err" >&2; echo "the demo failed" >&2; exit 1; }
# What the demo's server counted, and that it dropped nothing.
grep -E '^foxglove: [0-9]+ messages and outcomes observed, [0-9]+ published, 0 dropped' \
    "$work/demo.err" || { cat "$work/demo.err" >&2; exit 1; }
grep -E 'pose messages for Foxglove' "$work/demo.err"
"$PY" scripts/foxglove-client.py mcap "$work/run.mcap"

step "foxglove: listen on a secured fleet, with rejected frames; replay of the demo's recording"
# The relay chain's fleet on free ports, with keys made here.
base=$((30000 + RANDOM % 20000))
sed -e "s/47310/$base/; s/47311/$((base + 1))/; s/47320/$((base + 2))/; s/47321/$((base + 3))/" \
    examples/relay_chain.toml >"$work/chain.toml"
"$HETCOMM" keygen --fleet "$work/chain.toml" --out "$work/keys" >/dev/null
"$HETCOMM" listen "$work/chain.toml" --as Charlie --foxglove 127.0.0.1:0 --timeout 60 \
    >"$work/listen.out" 2>"$work/listen.err" &
listen_pid=$!
pids+=($listen_pid)
listen_ws=$(ws_port "$work/listen.err")
# Alpha sends with its keys, and an impostor without them (unauthenticated frames Charlie's
# security layer rejects), until the client has seen both.
(
    for _ in $(seq 60); do
        "$HETCOMM" send "$work/chain.toml" --as Alpha --to Charlie --module Plan --type 5 \
            --json '{"n":1}' --timeout 2 >/dev/null 2>&1 || true
        "$HETCOMM" send "$work/chain.toml" --insecure --as Alpha --to Charlie --module Plan \
            --type 5 --json '{"n":2}' --timeout 1 >/dev/null 2>&1 || true
        sleep 0.3
    done
) &
senders=$!
pids+=($senders)
"$PY" scripts/foxglove-client.py listen "$listen_ws"
kill "$senders" 2>/dev/null || true
kill -TERM "$listen_pid"
wait "$listen_pid"
grep -E '^foxglove: [0-9]+ messages and outcomes observed, [0-9]+ published, 0 dropped' \
    "$work/listen.err" || { cat "$work/listen.err" >&2; exit 1; }
"$HETCOMM" replay "$work/run.mcap" --into examples/leader_follower/fleet.toml --speed 2 \
    --foxglove 127.0.0.1:0 >"$work/replay.out" 2>"$work/replay.err" &
replay_pid=$!
pids+=($replay_pid)
replay_ws=$(ws_port "$work/replay.err")
"$PY" scripts/foxglove-client.py replay "$replay_ws"
# The replay's exit code says whether every send was made, not how they ended.
wait "$replay_pid" || { cat "$work/replay.err" >&2; exit 1; }
grep -E '^foxglove: [0-9]+ messages and outcomes observed, [0-9]+ published, 0 dropped' \
    "$work/replay.err" || { cat "$work/replay.err" >&2; exit 1; }
echo "foxglove: live views and the recording checked"
