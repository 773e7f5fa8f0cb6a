#!/usr/bin/env bash
# The one install script: every Debian package and every Python package that the tests, the
# examples and the benchmarks use, in one place. Quick when everything is there already (it
# only asks dpkg and reads a stamp file); a failed install is retried once, after letting dpkg
# finish any half-done configuration (a transient dpkg error was seen on CI).
#
#   bash scripts/install.sh            # both halves
#   bash scripts/install.sh apt        # Debian packages only (uses sudo when not root)
#   bash scripts/install.sh python     # the project venv, target/py-venv, only
#
# Every other script calls this instead of running apt-get or pip itself.
set -euo pipefail
cd "$(dirname "$0")/.."
ROOT=$PWD

APT_PACKAGES=(
    tmux                      # the monitor's test reads a real terminal (capture-pane)
    iproute2                  # network namespaces: the multi-host Zenoh run
    ros-core python3-rospy python3-rostopic ros-std-msgs python3-msgpack  # ROS 1 master, rospy
    ros-geometry-msgs ros-nav-msgs ros-sensor-msgs                         # typed ROS 1 topics
    ros-diagnostic-msgs ros-tf2-msgs ros-actionlib-msgs   # rosmsg md5 of every shipped ROS 1 type
    python3-geometry-msgs python3-nav-msgs python3-sensor-msgs
    python3-diagnostic-msgs python3-tf2-msgs python3-actionlib-msgs  # rosmsg md5 loads the Python classes
    cyclonedds-tools          # ddsperf: the DDS baseline of the benchmarks
    cmake g++ pkg-config valgrind libmsgpack-cxx-dev                       # the C and C++ API
    libclang-dev              # bindgen, for Cyclone DDS under the ros2 transport (ros2-cyclone)
    faketime                  # libfaketime: a live sender's wall clock stepped (hetcomm-cli clock_step)
    mosquitto mosquitto-clients  # the MQTT broker and mosquitto_pub/_sub (scripts/mqtt-test.sh)
)

# Installed into target/py-venv, the one venv every Python step uses.
PIP_PACKAGES=(
    "maturin>=1.9,<2" "pytest>=7"  # the bindings' wheel and tests
    "cryptography>=42"             # a port of the secured-frame spec (test_secured_vectors.py)
    "mcap>=1.1,<2"                 # reads the CLI's recordings back
    "cyclonedds==11.0.1"           # a foreign ROS 2 node (no ROS 2 install)
    "eclipse-zenoh==1.10.2"        # a plain Zenoh client written from docs/zenoh.md
    "websockets>=12"               # a Foxglove WebSocket client written from the protocol docs
    "protobuf>=4"                  # decodes Foxglove's well-known schemas from their descriptors
    "paho-mqtt>=2,<3"              # a plain MQTT client written from docs/mqtt.md
    "iceoryx2==0.10.0"             # a foreign system on the shm transport (docs/shm.md)
)

step() { printf '\n=== %s ===\n' "$*"; }

# Runs the command; on failure runs `$RECOVER` (if set) and the command once more.
retry_once() {
    "$@" && return 0
    echo "install failed; retrying once: $*" >&2
    sleep 5
    if [ -n "${RECOVER:-}" ]; then eval "$RECOVER" || true; fi
    "$@"
}

install_apt() {
    local missing=() pkg
    for pkg in "${APT_PACKAGES[@]}"; do
        if ! dpkg-query -W -f='${Status}' "$pkg" 2>/dev/null | grep -q "install ok installed"; then
            missing+=("$pkg")
        fi
    done
    [ ${#missing[@]} -eq 0 ] && return 0
    step "installing Debian packages: ${missing[*]}"
    local sudo=""
    [ "$(id -u)" -eq 0 ] || sudo="sudo"
    RECOVER="$sudo dpkg --configure -a" retry_once $sudo apt-get update -qq
    RECOVER="$sudo dpkg --configure -a" retry_once \
        $sudo env DEBIAN_FRONTEND=noninteractive apt-get install -y -qq "${missing[@]}" >/dev/null
}

install_python() {
    local venv=$ROOT/target/py-venv
    local stamp=$venv/.hetcomm-packages
    local want
    want=$(printf '%s\n' "${PIP_PACKAGES[@]}")
    if [ ! -x "$venv/bin/python" ]; then
        step "python venv in target/py-venv"
        python3 -m venv "$venv"
    fi
    # The stamp holds the list last installed: a changed list installs again.
    if [ -f "$stamp" ] && [ "$(cat "$stamp")" = "$want" ]; then
        return 0
    fi
    step "installing Python packages into target/py-venv: ${PIP_PACKAGES[*]}"
    retry_once "$venv/bin/python" -m pip install --quiet --disable-pip-version-check --upgrade pip
    retry_once "$venv/bin/python" -m pip install --quiet --disable-pip-version-check "${PIP_PACKAGES[@]}"
    printf '%s\n' "$want" >"$stamp"
}

case "${1:-all}" in
    apt) install_apt ;;
    python) install_python ;;
    all) install_apt; install_python ;;
    *) echo "usage: bash scripts/install.sh [apt|python]" >&2; exit 2 ;;
esac
