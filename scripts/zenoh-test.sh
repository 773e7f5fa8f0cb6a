#!/usr/bin/env bash
# Everything about the `zenoh` transport (docs/zenoh.md). Called by scripts/test.sh.
#
#   bash scripts/zenoh-test.sh
#
# 1. format and lint the zenoh crate (it is outside the workspace's members, so the
#    workspace-wide steps of test.sh do not see it) and the facade and CLI with `--features zenoh`;
# 2. the crate's tests: the conformance suite (peers, clients of a router; bare and wrapped),
#    fleet keys and their errors, opening errors, delivery, presence, malformed puts;
# 3. a Python eclipse-zenoh program written from the docs talks to `hetcomm listen` / `send`
#    through a `hetcomm zenoh-router` process (scripts/zenoh-python.sh);
# 4. the multi-host run: network namespaces on a bridge, a router process, 30 systems as
#    processes, partition, router restart, join and leave (scripts/zenoh-multihost.py; needs
#    root and iproute2, which CI has: without them this step fails and says so).
#
# zenoh is compiled once (debug) and shared by both workspaces' builds in the same target
# directory: the crate's Cargo.lock pins the versions the main Cargo.lock has.
set -euo pipefail
cd "$(dirname "$0")/.."
ROOT=$PWD
TARGET=${CARGO_TARGET_DIR:-$ROOT/target}
# The zenoh crate is a workspace of its own: without this its builds would go to its own
# target/ (and compile zenoh a second time), where the steps below would not find them.
export CARGO_TARGET_DIR=$TARGET
CRATE=crates/hetcomm-link-zenoh/Cargo.toml

step() { printf '\n== %s\n' "$*"; }

step "zenoh: format and lint"
cargo fmt --manifest-path "$CRATE" --all -- --check
cargo clippy --manifest-path "$CRATE" --all-targets -- -D warnings
cargo clippy -p hetcomm-cli -p hetcomm-bench --features hetcomm-cli/zenoh,hetcomm-bench/hetcomm-zenoh \
    --all-targets -- -D warnings

step "zenoh: crate tests (conformance, keys, opening, delivery, presence)"
cargo test --manifest-path "$CRATE"

step "zenoh: building the CLI and the multi-host node"
cargo build -q -p hetcomm-cli --features zenoh
cargo build -q --manifest-path "$CRATE" --example fleet_node
HETCOMM=$TARGET/debug/hetcomm
NODE=$TARGET/debug/examples/fleet_node

step "zenoh: a Python eclipse-zenoh system against hetcomm listen/send"
bash scripts/install.sh python
VENV=$ROOT/target/py-venv
bash scripts/zenoh-python.sh "$HETCOMM" "$VENV/bin/python"

step "zenoh: multi-host (namespaces, router process, 30 systems)"
if [ "$(id -u)" -ne 0 ] || ! command -v ip >/dev/null 2>&1 || ! ip netns list >/dev/null 2>&1; then
    echo "the multi-host run needs root and iproute2 (network namespaces); not run" >&2
    exit 1
fi
python3 scripts/zenoh-multihost.py "$HETCOMM" "$NODE"
