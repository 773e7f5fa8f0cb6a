#!/usr/bin/env bash
# The whole test suite, runnable on a fresh machine: installs what the tests need, starts the
# services they talk to, runs every check, and stops the services again.
#
#   bash scripts/test.sh
#
# CI (.ci/run) runs exactly this.
set -euo pipefail
cd "$(dirname "$0")/.."
# One build from scratch: incremental state would only add gigabytes of disk (CI ran out once).
export CARGO_INCREMENTAL="${CARGO_INCREMENTAL:-0}"

step() { printf '\n=== %s ===\n' "$*"; }

# Rust toolchain components used below (rustup-managed machines have them; install if not).
if ! cargo fmt --version >/dev/null 2>&1 || ! cargo clippy --version >/dev/null 2>&1; then
  step "installing rustfmt and clippy"
  rustup component add rustfmt clippy
fi

# Every Debian and Python package the steps below use, through the one install script.
step "install"
bash scripts/install.sh

step "format"
cargo fmt --all -- --check

step "lint"
cargo clippy --workspace --all-targets -- -D warnings
# Transports behind features: compiled and linted here even where they cannot run (this
# kernel has no AF_BLUETOOTH; docs/bluetooth.md says what is and is not exercised).
cargo clippy -p hetcomm --features bluetooth --all-targets -- -D warnings
cargo clippy -p hetcomm --features ros1 --all-targets -- -D warnings

step "tests"
cargo test --workspace

# Tests that need what only this script sets up, `#[ignore]`d so that a plain `cargo test`
# reports them as not run: two network namespaces need root (CI runs as root) and iproute2
# (scripts/install.sh).
step "tests that need root: hetcomm listen/send between two network namespaces"
cargo test -p hetcomm-cli --test netns -- --ignored

step "ROS 1 against a real master (installs ros-core when missing)"
bash scripts/ros1-test.sh

step "ROS 2: conformance, a Cyclone DDS (Python) rover through typed topics"
bash scripts/ros2-test.sh

step "Zenoh: conformance, a Python Zenoh client, multi-host in network namespaces"
bash scripts/zenoh-test.sh

step "MQTT: conformance, presence, auth, TLS, broker restart, mosquitto clients and paho-mqtt (one mosquitto)"
bash scripts/mqtt-test.sh

step "Shared memory (iceoryx2): conformance, a peer killed and restarted, backpressure, foreign segments"
bash scripts/shm-test.sh

step "Foxglove: the live view served to a WebSocket client"
bash scripts/foxglove-test.sh

step "python bindings"
bash scripts/test-python.sh

step "C and C++ API (CMake package, ctest, sanitizers, valgrind)"
bash scripts/cpp-test.sh

step "benchmarks (smoke: every measurement briefly, no timing assertions)"
cargo run -q -p hetcomm-bench -- --quick >/dev/null

step "examples"
cargo run -q -p hetcomm-examples --example two_systems >/dev/null
cargo run -q -p hetcomm-examples --example readme >/dev/null
example_dir=$(mktemp -d)
cargo run -q -p hetcomm-cli -- generate-config >"$example_dir/fleet.toml"
cargo run -q -p hetcomm-cli -- keygen --fleet "$example_dir/fleet.toml" --out "$example_dir/keys" >/dev/null
cargo run -q -p hetcomm-cli -- validate "$example_dir/fleet.toml"
rm -rf "$example_dir"

echo
echo "all checks passed"
