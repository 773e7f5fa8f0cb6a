#!/usr/bin/env bash
# Everything about the `mqtt` transport (docs/mqtt.md), against a real mosquitto. Called by
# scripts/test.sh.
#
#   bash scripts/mqtt-test.sh
#
# 1. format and lint the mqtt crate (it is outside the workspace's members, so the
#    workspace-wide steps of test.sh do not see it) and the facade and CLI with `--features mqtt`;
# 2. one mosquitto for the whole group, on free ports of 127.0.0.1: an anonymous listener, one
#    that wants username `robot` / password `s3cret`, and a TLS one that wants a client
#    certificate, with a test CA this script makes (openssl); stopped at the end;
# 3. the crate's tests against it: the conformance suite (QoS 0 and 1, bare, emulated,
#    secured), fleet keys and their errors, delivery, presence, username/password, TLS, bad
#    input, and the broker killed and restarted mid-stream (those start brokers of their own);
#    and the `mqtt_bridge` kind with the Python AGV examples/mqtt/agv.py (tests/bridge.rs);
# 4. interoperation on an unsecured transport: mosquitto_sub watches a `hetcomm send`'s frame,
#    mosquitto_pub publishes a frame that `hetcomm listen` prints, and a Python paho-mqtt
#    system (crates/hetcomm-link-mqtt/tests/python/mqtt_system.py, written from the docs)
#    talks to `hetcomm listen` and `hetcomm send` both ways;
# 5. the demonstrations: `hetcomm demo --r mqtt`, and `hetcomm demo --fleet
#    examples/mqtt/leader-follower-mqtt.toml` with Tango as a plain MQTT robot
#    (examples/mqtt/tango_rover.py), checked against the simulated run; and the reliability
#    experiment with R on the broker.
set -euo pipefail
cd "$(dirname "$0")/.."
ROOT=$PWD
TARGET=${CARGO_TARGET_DIR:-$ROOT/target}
# The mqtt crate is a workspace of its own: without this its builds would go to its own
# target/ (and compile the shared crates a second time).
export CARGO_TARGET_DIR=$TARGET
CRATE=crates/hetcomm-link-mqtt/Cargo.toml

step() { printf '\n== %s\n' "$*"; }

bash scripts/install.sh apt

step "mqtt: format and lint"
cargo fmt --manifest-path "$CRATE" --all -- --check
cargo clippy --manifest-path "$CRATE" --all-targets -- -D warnings
cargo clippy -p hetcomm-cli --features hetcomm-cli/mqtt --all-targets -- -D warnings

WORK=$(mktemp -d)
PIDS=()
cleanup() {
    for p in "${PIDS[@]}"; do kill "$p" 2>/dev/null || true; done
    wait 2>/dev/null || true
    rm -rf "$WORK"
}
trap cleanup EXIT

free_port() { python3 -c 'import socket; s=socket.socket(); s.bind(("127.0.0.1",0)); print(s.getsockname()[1])'; }

step "mqtt: a test CA, server and client certificates, a password file"
TLS=$WORK/tls
mkdir -p "$TLS"
openssl_quiet() { openssl "$@" 2>/dev/null; }
openssl_quiet req -x509 -newkey rsa:2048 -nodes -days 2 -subj /CN=hetcomm-test-ca \
    -keyout "$TLS/ca.key" -out "$TLS/ca.crt"
# A CA that signed nothing here: a client trusting it must refuse the broker.
openssl_quiet req -x509 -newkey rsa:2048 -nodes -days 2 -subj /CN=another-ca \
    -keyout "$TLS/other-ca.key" -out "$TLS/other-ca.crt"
sign() { # NAME SUBJECT [EXTENSIONS]
    openssl_quiet req -newkey rsa:2048 -nodes -subj "$2" -keyout "$TLS/$1.key" -out "$TLS/$1.csr"
    printf '%s\n' "${3:-basicConstraints=CA:FALSE}" >"$TLS/$1.ext"
    openssl_quiet x509 -req -in "$TLS/$1.csr" -CA "$TLS/ca.crt" -CAkey "$TLS/ca.key" \
        -CAcreateserial -days 2 -extfile "$TLS/$1.ext" -out "$TLS/$1.crt"
}
sign server /CN=localhost "subjectAltName=IP:127.0.0.1,DNS:localhost"
sign client /CN=robot
mosquitto_passwd -c -b "$TLS/passwd" robot s3cret
chmod 0644 "$TLS"/*

step "mqtt: one mosquitto for the group (anonymous, password, TLS listeners)"
PLAIN=$(free_port); AUTH=$(free_port); SECURE=$(free_port)
cat >"$WORK/mosquitto.conf" <<CONF
# Stays root when started as root (CI), so that it reads the files above.
user root
persistence false
# Without it mosquitto holds small publishes back (Nagle): 40-85 ms per round trip (docs/mqtt.md).
set_tcp_nodelay true
per_listener_settings true
log_dest stderr
listener $PLAIN 127.0.0.1
allow_anonymous true
listener $AUTH 127.0.0.1
allow_anonymous false
password_file $TLS/passwd
listener $SECURE 127.0.0.1
allow_anonymous true
cafile $TLS/ca.crt
certfile $TLS/server.crt
keyfile $TLS/server.key
require_certificate true
CONF
# Debian installs the broker in /usr/sbin, which a non-root PATH may lack.
MOSQUITTO=$(command -v mosquitto || echo /usr/sbin/mosquitto)
"$MOSQUITTO" -c "$WORK/mosquitto.conf" 2>"$WORK/mosquitto.log" &
PIDS+=($!)
for port in $PLAIN $AUTH $SECURE; do
    for _ in $(seq 100); do
        python3 -c "import socket,sys; socket.create_connection(('127.0.0.1',$port),0.2)" 2>/dev/null && break
        sleep 0.05
    done
done
python3 -c "import socket; socket.create_connection(('127.0.0.1',$SECURE),0.2)" \
    || { cat "$WORK/mosquitto.log"; exit 1; }
export HETCOMM_MQTT_BROKER=127.0.0.1:$PLAIN
export HETCOMM_MQTT_AUTH_BROKER=127.0.0.1:$AUTH
export HETCOMM_MQTT_TLS_BROKER=mqtts://127.0.0.1:$SECURE
export HETCOMM_MQTT_TLS_DIR=$TLS

# paho-mqtt for the bridge's Python AGV (tests/bridge.rs) and the interop script.
bash scripts/install.sh python
PY=$ROOT/target/py-venv/bin/python
export HETCOMM_PYTHON=$PY

step "mqtt: crate tests (conformance, keys, delivery, presence, auth, TLS, bad input, broker restart, mqtt_bridge with the Python AGV)"
cargo test --manifest-path "$CRATE"

step "mqtt: building the CLI"
cargo build -q -p hetcomm-cli --features mqtt
HETCOMM=$TARGET/debug/hetcomm
"$HETCOMM" validate examples/mqtt/agv.toml
"$HETCOMM" validate examples/mqtt/leader-follower-mqtt.toml

step "mqtt: interoperation with mosquitto_sub, mosquitto_pub and a Python paho-mqtt system"
bash scripts/mqtt-interop.sh "$HETCOMM" "$PY" "127.0.0.1:$PLAIN"

step "mqtt: the leader-follower demonstration with R on the broker (hetcomm demo --r mqtt)"
# Real time (about 15 s): every system of the demo is a client of the group's broker, under a
# fleet level of the run's own. It must end, write its tables, and Tango must have followed.
"$HETCOMM" demo --r mqtt --mqtt-broker "127.0.0.1:$PLAIN" --out "$WORK/demo" \
    >"$WORK/demo.out" 2>"$WORK/demo.err" || { cat "$WORK/demo.err"; exit 1; }
grep -q 'Alpha → Charlie → Tango, .*R = mqtt' "$WORK/demo.err" || { cat "$WORK/demo.err"; exit 1; }
# Tango (reached from Charlie over R) received both of Alpha's turns.
awk '/^Table 11: Tango command data/{f=1} /^Table 12/{f=0} f && /Turn Left/{n++} END{exit n<2}' "$WORK/demo.out" \
    && test -s "$WORK/demo/NOTES.md" || { cat "$WORK/demo.out"; exit 1; }
echo "hetcomm demo --r mqtt: ok"

step "mqtt: hetcomm demo with Tango as a plain MQTT robot (examples/mqtt/leader-follower-mqtt.toml)"
# The shipped fleet on the group's broker and topics of this run's own; the rover is
# examples/mqtt/tango_rover.py (paho-mqtt, no hetcomm). Tango must follow as in the simulated
# run (scripts/tango-follows.py, as for the ROS rovers).
LF=$WORK/lf
mkdir -p "$LF"
LFPREFIX=hc_lf_$$
sed -e "s#mqtt://127.0.0.1:1883#mqtt://127.0.0.1:$PLAIN#" -e "s#\"tango/#\"$LFPREFIX/#" \
    examples/mqtt/leader-follower-mqtt.toml > "$LF/fleet.toml"
grep -q "\"$LFPREFIX/odom\"" "$LF/fleet.toml" && grep -q ":$PLAIN\"" "$LF/fleet.toml"
"$PY" examples/mqtt/tango_rover.py --broker "127.0.0.1:$PLAIN" --prefix "$LFPREFIX" --seconds 60 \
    > "$LF/rover.log" 2>&1 &
ROVER=$!
PIDS+=($ROVER)
"$HETCOMM" demo --fleet "$LF/fleet.toml" --out "$LF/mqtt" > "$LF/mqtt.txt" 2> "$LF/mqtt.err" \
    || { cat "$LF/mqtt.err" "$LF/rover.log"; exit 1; }
kill $ROVER 2>/dev/null || true
sed -n '/Table 11/,/^$/p' "$LF/mqtt.txt"
"$HETCOMM" demo --out "$LF/sim" > /dev/null 2> "$LF/sim.err" || { cat "$LF/sim.err"; exit 1; }
"$PY" scripts/tango-follows.py "$LF/mqtt" "$LF/sim"

step "mqtt: the reliability experiment with R on the broker (real time, both modes)"
# The thesis's three-system fleet with R on the group's broker (unsecured, a fleet level of
# its own) and B in process; every message must be received once and every send accounted.
cat >"$WORK/reliability.toml" <<TOML
[systems]
Bravo = 0
Charlie = 1
Delta = 2
[modules]
Plan = 0
[transports.r]
kind = "mqtt"
letter = "R"
broker = "127.0.0.1:$PLAIN"
fleet = "hetcomm-reliability-$$"
security = "none"
[transports.b]
kind = "inproc"
letter = "B"
[table]
columns = ["Bravo", "Charlie", "Delta"]
Bravo   = ["X", "R", "B"]
Charlie = ["B", "X", "R"]
Delta   = ["R", "B", "X"]
TOML
"$HETCOMM" experiment reliability --fleet "$WORK/reliability.toml" --realtime --trials 3 \
    --format json --out "$WORK/reliability" >"$WORK/reliability.json" \
    || { cat "$WORK/reliability.json"; exit 1; }
python3 - "$WORK/reliability.json" <<'PY'
import json, sys
report = json.load(open(sys.argv[1]))
for m in report["modes"]:
    a = m["accounting"]
    line = (f'{m["mode"]}: {m["messages"]} messages, {m["received"]} received, '
            f'{m["duplicates_delivered"]} duplicates, {a["in_flight"]} in flight, '
            f'balanced {a["balanced"]}')
    print(line)
    assert (m["messages"], m["received"]) == (63, 63), line
    assert m["duplicates_delivered"] == 0 and a["in_flight"] == 0 and a["balanced"], line
PY
echo "hetcomm experiment reliability on mqtt: ok"
