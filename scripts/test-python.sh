#!/usr/bin/env bash
# The Python bindings' test suite, runnable on a fresh machine (needs python3 with venv, cargo,
# and access to PyPI):
#
#   bash scripts/test-python.sh [pytest args...]
#
# 1. the virtual environment target/py-venv with maturin, pytest and the packages the tests
#    import (scripts/install.sh; reused across runs);
# 2. the `hetcomm` wheel (abi3, debug build) built by maturin and installed into it;
# 3. the `hetcomm` CLI (debug), which the cross-process tests run as the Rust peer;
# 4. pytest on crates/hetcomm-py/tests.
set -euo pipefail
cd "$(dirname "$0")/.."
ROOT=$PWD

step() { printf '\n=== %s ===\n' "$*"; }

# maturin, pytest and the packages the tests import, through the one install script.
bash scripts/install.sh python
VENV=$ROOT/target/py-venv
PY=$VENV/bin/python

step "building the hetcomm wheel (maturin, debug)"
WHEELS=$ROOT/target/py-wheels
rm -rf "$WHEELS"
# --profile dev: a debug build, sharing target/ with cargo; --compatibility linux: no
# manylinux audit (this wheel is for this machine's tests, not for upload).
"$VENV/bin/maturin" build --quiet -m crates/hetcomm-py/Cargo.toml --profile dev \
  --interpreter "$PY" --compatibility linux --out "$WHEELS"
"$PY" -m pip install --quiet --disable-pip-version-check --force-reinstall --no-deps "$WHEELS"/hetcomm-*.whl

step "building the hetcomm CLI"
cargo build -q -p hetcomm-cli
export HETCOMM_CLI=$ROOT/target/debug/hetcomm
export HETCOMM_ROOT=$ROOT

step "pytest"
cd crates/hetcomm-py
export PYTHONDONTWRITEBYTECODE=1
exec "$PY" -m pytest -q -p no:cacheprovider tests "$@"
