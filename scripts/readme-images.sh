#!/usr/bin/env bash
# Regenerates the README's images, docs/img/demo-*.png, from the demonstration: they are the
# plots that the README's own command (`cargo run --release -p hetcomm-cli -- demo`) writes.
#
#   bash scripts/readme-images.sh
#
# crates/hetcomm-cli/tests/demo_output.rs checks that the images match what the demo draws.
set -euo pipefail
cd "$(dirname "$0")/.."
out="$(mktemp -d)"
trap 'rm -rf "$out"' EXIT
cargo run --release -p hetcomm-cli -- demo --out "$out" >/dev/null
cp "$out/trajectory.png" docs/img/demo-trajectory.png
cp "$out/theta.png" docs/img/demo-theta.png
echo "wrote docs/img/demo-trajectory.png and docs/img/demo-theta.png"
