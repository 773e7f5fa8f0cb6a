#!/usr/bin/env bash
# Plain MQTT programs talk to hetcomm over an unsecured `mqtt` transport (docs/mqtt.md):
#
# * mosquitto_sub watches the fleet and prints the frame `hetcomm send` publishes (decoded by
#   the wire format's standard-library port, crates/hetcomm-py/tests/docport.py);
# * mosquitto_pub publishes a frame built from docs/wire-format.md that `hetcomm listen` prints;
# * the Python paho-mqtt system crates/hetcomm-link-mqtt/tests/python/mqtt_system.py sends a
#   message that `hetcomm listen` prints (and shows it joining), and receives and acknowledges
#   one that `hetcomm send` reports delivered.
#
#   bash scripts/mqtt-interop.sh HETCOMM_BINARY PYTHON BROKER_HOST:PORT
#
# Called by scripts/mqtt-test.sh, which starts the broker and builds the binary and the venv.
set -euo pipefail
cd "$(dirname "$0")/.."
HETCOMM=$1
PY=$2
BROKER=$3
HOST=${BROKER%:*}
PORT=${BROKER##*:}
WORK=$(mktemp -d)
PIDS=()
cleanup() {
    for p in "${PIDS[@]}"; do kill "$p" 2>/dev/null || true; done
    wait 2>/dev/null || true
    rm -rf "$WORK"
}
trap cleanup EXIT
FLEET="interop-$$"
SUB=(mosquitto_sub -V mqttv5 -h "$HOST" -p "$PORT")
PUB=(mosquitto_pub -V mqttv5 -h "$HOST" -p "$PORT")

cat >"$WORK/fleet.toml" <<TOML
[systems]
Alpha = 0
Py = 2
Watcher = 3
Pub = 4
[modules]
M = 0
[transports.m]
kind = "mqtt"
broker = "$BROKER"
fleet = "$FLEET"
# Plain MQTT clients write hetcomm's frames themselves and cannot seal them (docs/security.md).
security = "none"
# Watcher acknowledges nothing: frames to it are sent without confirmation. Topics of their
# own: two transports on one broker under the same topics would carry each other's frames.
[transports.u]
kind = "mqtt"
broker = "$BROKER"
fleet = "$FLEET-u"
security = "none"
delivery = "unacknowledged"
[table]
columns = ["Alpha", "Py", "Watcher", "Pub"]
Alpha = ["X", "m", "u", "X"]
Py = ["m", "X", "X", "X"]
Watcher = ["u", "X", "X", "X"]
Pub = ["u", "X", "X", "X"]
TOML
"$HETCOMM" validate "$WORK/fleet.toml"

# Waits until SYSTEM has announced itself online under fleet level LEVEL.
wait_online() {
    for _ in $(seq 100); do
        "${SUB[@]}" -t "hetcomm/$2/@presence/$1" -C 1 -W 1 2>/dev/null | grep -q '^online$' && return 0
        sleep 0.1
    done
    echo "$1 never came online" >&2
    return 1
}

echo "-- hetcomm send -> mosquitto_sub"
"${PUB[@]}" -t "hetcomm/$FLEET-u/@presence/Watcher" -r -q 1 -m online
"${SUB[@]}" -t "hetcomm/$FLEET-u/+" -C 1 -W 20 -F '%t %x' >"$WORK/sub.out" &
SUBPID=$!
PIDS+=($SUBPID)
sleep 0.5
"$HETCOMM" send "$WORK/fleet.toml" --as Alpha --to Watcher --module M --type 5 --json '"seen by mosquitto_sub"'
wait "$SUBPID"
cat "$WORK/sub.out"
"$PY" - "$WORK/sub.out" "$FLEET" <<'PY'
import sys
sys.path.insert(0, "crates/hetcomm-py/tests")
import docport
topic, hexed = open(sys.argv[1]).read().split()
h, payload = docport.decode_frame(bytes.fromhex(hexed))
assert topic == f"hetcomm/{sys.argv[2]}-u/Watcher", topic
assert (h["source"]["system"], h["destination"]["system"], h["message_type"]) == (0, 3, 5), h
assert payload == docport.msgpack_str("seen by mosquitto_sub"), payload
print("mosquitto_sub saw Alpha's frame to Watcher, decoded from docs/wire-format.md")
PY
"${PUB[@]}" -t "hetcomm/$FLEET-u/@presence/Watcher" -r -q 1 -m offline

echo "-- mosquitto_pub -> hetcomm listen"
"$PY" - "$WORK/frame.bin" <<'PY'
import sys, time
sys.path.insert(0, "crates/hetcomm-py/tests")
import docport
h = {"kind": docport.KIND_DATA, "flags": 0, "priority": 100, "transport": ord("U"),
     "source": {"system": 4, "module": 0}, "destination": {"system": 0, "module": 0},
     "incarnation": 77, "seq": 1, "message_type": 9, "timestamp": int(time.time() * 1e6)}
open(sys.argv[1], "wb").write(docport.encode_frame(h, docport.msgpack_str("from mosquitto_pub")))
PY
"$HETCOMM" listen "$WORK/fleet.toml" --as Alpha --count 1 --json --timeout 30 >"$WORK/listen1.out" 2>"$WORK/listen1.err" &
LISTEN=$!
PIDS+=($LISTEN)
wait_online Alpha "$FLEET-u"
"${PUB[@]}" -t "hetcomm/$FLEET-u/Alpha" -q 1 -f "$WORK/frame.bin"
wait "$LISTEN"
cat "$WORK/listen1.out"
grep -q '"from mosquitto_pub"' "$WORK/listen1.out" || { cat "$WORK/listen1.err"; exit 1; }

SYSTEM="$PY crates/hetcomm-link-mqtt/tests/python/mqtt_system.py --broker $BROKER --fleet $FLEET --names Alpha=0,Py=2,Watcher=3,Pub=4"

echo "-- Python paho-mqtt -> hetcomm listen"
"$HETCOMM" listen "$WORK/fleet.toml" --as Alpha --count 1 --json --timeout 30 >"$WORK/listen2.out" 2>"$WORK/listen2.err" &
LISTEN=$!
PIDS+=($LISTEN)
wait_online Alpha "$FLEET"
$SYSTEM --name Py --id 2 --send-to Alpha --to-id 0 --module 0 --type 1 --text "hello from python" >"$WORK/py-send.out"
wait "$LISTEN"
cat "$WORK/listen2.out" "$WORK/listen2.err"
grep -q '^ack delivered$' "$WORK/py-send.out" || { cat "$WORK/py-send.out"; exit 1; }
grep -q '"hello from python"' "$WORK/listen2.out"
# Once: Py joins once, and Alpha's one link on Py's transport sees it.
[ "$(grep -c 'Py joined (mqtt)' "$WORK/listen2.err")" = 1 ]

echo "-- hetcomm send -> Python paho-mqtt"
$SYSTEM --name Py --id 2 --receive 1 >"$WORK/py-recv.out" &
RECV=$!
PIDS+=($RECV)
for _ in $(seq 100); do grep -q ready "$WORK/py-recv.out" 2>/dev/null && break; sleep 0.05; done
"$HETCOMM" send "$WORK/fleet.toml" --as Alpha --to Py --module M --type 1 --json '"hello from hetcomm"' | tee "$WORK/send.out"
wait "$RECV"
cat "$WORK/py-recv.out"
grep -q "delivered" "$WORK/send.out"
# "hello from hetcomm" as a MessagePack str (0xb2 + the bytes).
grep -q "\"payload_hex\": \"b2$(printf 'hello from hetcomm' | od -An -tx1 | tr -d ' \n')\"" "$WORK/py-recv.out"
# Leave the broker as found: no retained messages of this run.
for level in "$FLEET" "$FLEET-u"; do
    for s in Alpha Py Watcher Pub; do "${PUB[@]}" -t "hetcomm/$level/@presence/$s" -r -n -q 1; done
done
echo "mqtt interop (mosquitto_sub, mosquitto_pub, paho-mqtt): ok"
