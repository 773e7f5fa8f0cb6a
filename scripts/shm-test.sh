#!/usr/bin/env bash
# Everything about the `shm` transport (docs/shm.md). Called by scripts/test.sh.
#
#   bash scripts/shm-test.sh
#
# 1. format and lint the shm crate (it is outside the workspace's members, so the
#    workspace-wide steps of test.sh do not see it);
# 2. its tests: the conformance suite bare and emulated; between real processes (the
#    crate's shm-test-peer program) a peer killed with SIGKILL mid-stream, a restarted peer, a
#    peer that never reads, a foreign service and a foreign publisher; the fleet keys, and
#    security off by default and on with `[security] in_process = true`, through the facade;
#    and a Python system on the `iceoryx2` package (tests/python/shm_system.py) exchanging
#    frames with hetcomm on an unsecured transport;
# 3. the relay-chain example with one hop on `shm`, three processes.
set -euo pipefail
cd "$(dirname "$0")/.."
ROOT=$PWD
TARGET=${CARGO_TARGET_DIR:-$ROOT/target}
# The shm crate is a workspace of its own: without this its builds would go to its own
# target/ (and compile the shared crates a second time).
export CARGO_TARGET_DIR=$TARGET
CRATE=crates/hetcomm-link-shm/Cargo.toml

step() { printf '\n== %s\n' "$*"; }

step "shm: format and lint"
cargo fmt --manifest-path "$CRATE" --all -- --check
cargo clippy --manifest-path "$CRATE" --all-targets -- -D warnings

bash scripts/install.sh python
export HETCOMM_SHM_PYTHON=$ROOT/target/py-venv/bin/python

step "shm: conformance, processes killed and restarted, backpressure, foreign segments, fleet, Python"
cargo test --manifest-path "$CRATE"

step "shm: the relay-chain example with its Charlie - Tango hop in shared memory (three processes)"
# Built first, outside the test's build deadline (iceoryx2 for the examples' workspace).
cargo build -q --manifest-path examples/Cargo.toml --features shm --example relay_chain
cargo test -p hetcomm-cli --test relay_chain_example -- --ignored relay_chain_example_with_an_shm_hop
