#!/usr/bin/env bash
# Large ROS messages through the bridges at 30 Hz (issue 40): sensor_msgs/Image 640x480 rgb8
# (921,600 bytes) and sensor_msgs/PointCloud2 of 100,000 points (1.6 MB), both ways through
# `ros1_bridge` (a rospy node on a master of its own) and `ros2_bridge` (a Cyclone DDS Python
# node, reliable), beside the same node talking to itself (rospy -> rospy, cyclonedds Python ->
# cyclonedds Python: what `rostopic hz` would show of the peer alone). Prints a Markdown
# section on stdout; benchmarks/run.sh appends it to RESULTS.md.
#
#   bash benchmarks/ros-large.sh            # 300 messages a run (10 s), 3 interleaved rounds
#   COUNT=90 ROUNDS=1 bash benchmarks/ros-large.sh
#
# The hetcomm rows are the release builds of the bridges' tests (crates/hetcomm-link-ros1/
# tests/large_messages.rs, crates/hetcomm-link-ros2/tests/large_messages.rs), which check
# every byte of every message and print rate and latency; the baseline rows run the tests'
# own node (tests/py/large_node.py) as both publisher and reader. Rate: messages a second
# between the first and last arrival at the reader; latency: header stamp (the publisher's
# wall clock just before publishing) to arrival, same host. Each row keeps the round with the
# median rate. Needs ROS 1 (scripts/install.sh apt) and target/py-venv with cyclonedds
# (scripts/install.sh python).
set -uo pipefail
cd "$(dirname "$0")/.."
ROOT=$(pwd)
COUNT=${COUNT:-300}
ROUNDS=${ROUNDS:-3}
TMP=$(mktemp -d)
PIDS=()
cleanup() { for p in "${PIDS[@]}"; do kill "$p" 2>/dev/null; done; rm -rf "$TMP"; }
trap cleanup EXIT
log() { echo "== $*" >&2; }

export ROS_HOSTNAME=127.0.0.1
PY2=${HETCOMM_ROS2_PYTHON:-$ROOT/target/py-venv/bin/python}
export HETCOMM_ROS2_PYTHON=$PY2 HETCOMM_LARGE_COUNT=$COUNT
NODE1=crates/hetcomm-link-ros1/tests/py/large_node.py
NODE2=crates/hetcomm-link-ros2/tests/py/large_node.py

ROS1_CMD="cargo test --release -p hetcomm-link-ros1 --test large_messages --no-run"
ROS2_CMD="cargo test --release --manifest-path crates/hetcomm-link-ros2/Cargo.toml --test large_messages --no-run"
# The test executable a `cargo test --no-run` command built.
test_binary() {
    $1 --message-format=json 2>/dev/null \
        | sed -n 's/.*"executable":"\([^"]*large_messages[^"]*\)".*/\1/p' | tail -1
}
log "$ROS1_CMD"
BIN1=$(test_binary "$ROS1_CMD")
log "$ROS2_CMD"
BIN2=$(test_binary "$ROS2_CMD")

# `figures FILE`: "rate p50 max" of a reader's lines `K ok LATENCY_MS ARRIVAL_S`; fails unless
# every one of COUNT arrived intact.
figures() {
    /usr/bin/python3 - "$1" "$COUNT" <<'PY'
import sys
rows = [l.split() for l in open(sys.argv[1]) if len(l.split()) == 4]
ok = [r for r in rows if r[1] == "ok"]
if len(ok) != int(sys.argv[2]):
    sys.exit(f"{len(ok)} of {sys.argv[2]} arrived intact")
lat = sorted(float(r[2]) for r in rows)
at = [float(r[3]) for r in rows]
print(f"{(len(at) - 1) / (max(at) - min(at)):.1f} {lat[len(lat) // 2]:.1f} {lat[-1]:.1f}")
PY
}

# `baseline ROS KIND`: the node publishing to itself; prints "rate p50 max".
baseline() {
    local out=$TMP/base.txt
    if [ "$1" = ros1 ]; then
        /usr/bin/python3 $NODE1 read --topic /bench/$2 --type "$2" --count "$COUNT" >"$out" &
        local reader=$!
        sleep 2
        /usr/bin/python3 $NODE1 publish --topic /bench/$2 --type "$2" --count "$COUNT" >/dev/null
    else
        "$PY2" $NODE2 read --domain 45 --topic /bench/$2 --type "$2" --count "$COUNT" >"$out" &
        local reader=$!
        sleep 2
        "$PY2" $NODE2 publish --domain 45 --topic /bench/$2 --type "$2" --count "$COUNT" >/dev/null
    fi
    wait $reader
    figures "$out"
}

# `through ROS DIRECTION KIND`: the bridge's test of that direction and kind; "rate p50 max".
through() {
    local bin=$BIN1 name
    [ "$1" = ros2 ] && bin=$BIN2
    case "$1 $2 $3" in
        "ros1 out image") name=images_at_30_hz_reach_rospy_intact ;;
        "ros1 out cloud") name=point_clouds_at_30_hz_reach_rospy_intact ;;
        "ros1 in image") name=images_at_30_hz_from_rospy_arrive_intact ;;
        "ros1 in cloud") name=point_clouds_at_30_hz_from_rospy_arrive_intact ;;
        "ros2 out image") name=images_at_30_hz_reach_a_cyclone_dds_reader_intact ;;
        "ros2 out cloud") name=point_clouds_at_30_hz_reach_a_cyclone_dds_reader_intact ;;
        "ros2 in image") name=images_at_30_hz_from_a_cyclone_dds_writer_arrive_intact ;;
        "ros2 in cloud") name=point_clouds_at_30_hz_from_a_cyclone_dds_writer_arrive_intact ;;
    esac
    (cd "crates/hetcomm-link-$1" && "$bin" --exact "$name" --include-ignored --nocapture) >"$TMP/run.txt" 2>&1
    # "...: N arrived (N intact), R Hz, latency p50 X ms, max Y ms"
    sed -n 's/.*, \([0-9.]*\) Hz, latency p50 \([0-9.]*\) ms, max \([0-9.]*\) ms/\1 \2 \3/p' \
        "$TMP/run.txt" | tail -1
}

MASTER_PORT=$(/usr/bin/python3 -c 'import socket; s = socket.socket(); s.bind(("127.0.0.1", 0)); print(s.getsockname()[1])')
export ROS_MASTER_URI=http://127.0.0.1:$MASTER_PORT ROS_LOG_DIR=$TMP/log
rosmaster --core -p "$MASTER_PORT" >/dev/null 2>&1 &
PIDS+=($!)
sleep 3

# Rows: "ros direction kind"; each round runs every row once, baselines interleaved.
ROWS=("ros1 out image" "ros1 in image" "ros1 out cloud" "ros1 in cloud"
      "ros2 out image" "ros2 in image" "ros2 out cloud" "ros2 in cloud")
for round in $(seq 1 "$ROUNDS"); do
    for ros in ros1 ros2; do
        for kind in image cloud; do
            log "round $round: $ros $kind baseline"
            echo "$(baseline $ros $kind || echo failed)" >>"$TMP/base-$ros-$kind"
        done
    done
    for row in "${ROWS[@]}"; do
        log "round $round: $row"
        # shellcheck disable=SC2086
        r=$(through $row)
        echo "${r:-failed}" >>"$TMP/row-${row// /-}"
    done
done

# The round with the median rate of a file of "rate p50 max" lines.
median() { grep -v failed "$1" | sort -n | awk '{a[NR] = $0} END {if (NR) print a[int((NR + 1) / 2)]; else print "failed"}'; }

echo "### Large ROS messages at 30 Hz (\`bash benchmarks/ros-large.sh\`)"
echo
echo "$COUNT messages a run, $ROUNDS interleaved rounds, the round with the median rate. Commands:"
echo "\`$ROS1_CMD\`, \`$ROS2_CMD\`, then each test by name with HETCOMM_LARGE_COUNT=$COUNT;"
echo "baselines: tests/py/large_node.py publishing to itself."
echo
echo "| path | message | rate (Hz) | latency p50 (ms) | latency max (ms) | baseline rate (Hz) | baseline p50 (ms) | rate × baseline | p50 × baseline |"
echo "|---|---|---|---|---|---|---|---|---|"
for row in "${ROWS[@]}"; do
    read -r ros dir kind <<<"$row"
    read -r rate p50 max <<<"$(median "$TMP/row-${row// /-}")"
    read -r brate bp50 _ <<<"$(median "$TMP/base-$ros-$kind")"
    peer="rospy"
    [ "$ros" = ros2 ] && peer="cyclonedds Python"
    path="hetcomm → ${ros}_bridge → $peer"
    [ "$dir" = in ] && path="$peer → ${ros}_bridge → hetcomm"
    ratio() { /usr/bin/python3 -c "import sys; a, b = sys.argv[1:]; print(f'{float(a) / float(b):.2f}×')" "$1" "$2" 2>/dev/null || echo "-"; }
    echo "| $path | $kind | ${rate:-failed} | ${p50:--} | ${max:--} | ${brate:-failed} | ${bp50:--} | $(ratio "${rate:-x}" "${brate:-x}") | $(ratio "${p50:-x}" "${bp50:-x}") |"
done
