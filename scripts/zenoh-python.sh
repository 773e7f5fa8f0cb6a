#!/usr/bin/env bash
# A plain Zenoh program talks to hetcomm over a `zenoh` transport (docs/zenoh.md): the Python
# system crates/hetcomm-link-zenoh/tests/python/zenoh_system.py (eclipse-zenoh + the wire
# format's standard-library port) sends a message that `hetcomm listen` prints, and receives
# (and acknowledges) one that `hetcomm send` reports delivered. A real router process
# (`hetcomm zenoh-router`) carries both; it is stopped at the end.
#
#   bash scripts/zenoh-python.sh HETCOMM_BINARY PYTHON
#
# Called by scripts/zenoh-test.sh, which builds the binary and the venv.
set -euo pipefail
cd "$(dirname "$0")/.."
HETCOMM=$1
PY=$2
WORK=$(mktemp -d)
PIDS=()
cleanup() {
    for p in "${PIDS[@]}"; do kill "$p" 2>/dev/null || true; done
    wait 2>/dev/null || true
    rm -rf "$WORK"
}
trap cleanup EXIT

PORT=$("$PY" -c 'import socket; s=socket.socket(); s.bind(("127.0.0.1",0)); print(s.getsockname()[1])')
ENDPOINT="tcp/127.0.0.1:$PORT"
PREFIX="hetcomm-py/$$"
"$HETCOMM" zenoh-router --listen "$ENDPOINT" >"$WORK/router.out" 2>"$WORK/router.err" &
PIDS+=($!)
for _ in $(seq 100); do grep -q ready "$WORK/router.out" 2>/dev/null && break; sleep 0.05; done
grep -q ready "$WORK/router.out"

cat >"$WORK/fleet.toml" <<TOML
[systems]
Alpha = 0
Py = 2
Py2 = 3
[modules]
M = 0
[transports.z]
kind = "zenoh"
# The Python client writes hetcomm's frames itself and cannot seal them (docs/security.md).
security = "none"
mode = "client"
connect = ["$ENDPOINT"]
multicast_scouting = false
prefix = "$PREFIX"
[table]
columns = ["Alpha", "Py", "Py2"]
Alpha = ["X", "z", "z"]
Py = ["z", "X", "X"]
Py2 = ["z", "X", "X"]
TOML
"$HETCOMM" validate "$WORK/fleet.toml"
SYSTEM="$PY crates/hetcomm-link-zenoh/tests/python/zenoh_system.py --connect $ENDPOINT --prefix $PREFIX --names Alpha=0,Py=2,Py2=3"

echo "-- Python -> hetcomm listen"
"$HETCOMM" listen "$WORK/fleet.toml" --as Alpha --count 1 --json --timeout 30 >"$WORK/listen.out" 2>"$WORK/listen.err" &
LISTEN=$!
PIDS+=($LISTEN)
$SYSTEM --name Py --id 2 --send-to Alpha --to-id 0 --module 0 --type 1 --text "hello from python" >"$WORK/py-send.out"
wait "$LISTEN"
cat "$WORK/listen.out"
grep -q '^ack delivered$' "$WORK/py-send.out" || { cat "$WORK/py-send.out"; exit 1; }
grep -q '"hello from python"' "$WORK/listen.out" || { cat "$WORK/listen.err"; exit 1; }
grep -q 'Py joined (zenoh)' "$WORK/listen.err" || { cat "$WORK/listen.err"; exit 1; }

echo "-- hetcomm send -> Python"
$SYSTEM --name Py --id 2 --receive 1 >"$WORK/py-recv.out" &
RECV=$!
PIDS+=($RECV)
for _ in $(seq 100); do grep -q ready "$WORK/py-recv.out" 2>/dev/null && break; sleep 0.05; done
"$HETCOMM" send "$WORK/fleet.toml" --as Alpha --to Py --module M --type 1 --json '"hello from hetcomm"'
wait "$RECV"
cat "$WORK/py-recv.out"
# "hello from hetcomm" as a MessagePack str (0xb2 + the bytes).
grep -q "\"payload_hex\": \"b2$(printf 'hello from hetcomm' | od -An -tx1 | tr -d ' \n')\"" "$WORK/py-recv.out"
echo "-- hetcomm send --to All -> two Python systems: one put on $PREFIX/all"
for n in Py Py2; do
    id=2; [ "$n" = Py2 ] && id=3
    $SYSTEM --name $n --id $id --receive 1 >"$WORK/bcast-$n.out" &
    PIDS+=($!)
done
for n in Py Py2; do
    for _ in $(seq 100); do grep -q ready "$WORK/bcast-$n.out" 2>/dev/null && break; sleep 0.05; done
done
"$HETCOMM" send "$WORK/fleet.toml" --as Alpha --to All --module M --type 1 --json '"to all"' | tee "$WORK/bcast-send.out"
wait "${PIDS[-1]}" "${PIDS[-2]}"
for n in Py Py2; do
    cat "$WORK/bcast-$n.out"
    # Each took the one frame for all (FLAG_TO_ALL) and acknowledged it.
    grep -q '"to_all": true' "$WORK/bcast-$n.out"
    grep -q "^$n: delivered to the inbox" "$WORK/bcast-send.out"
done
echo "python interop over zenoh: ok"
