#!/usr/bin/env bash
# The Python bindings' test suite, runnable on a fresh machine (needs python3 with venv, cargo,
# and access to PyPI):
#
#   bash scripts/test-python.sh [pytest args...]
#
# 1. a virtual environment in target/py-venv with maturin, pytest and cryptography (reused
#    across runs);
# 2. the `hetcomm` wheel (abi3, debug build) built by maturin and installed into it;
# 3. the `hetcomm` CLI (debug), which the cross-process tests run as the Rust peer;
# 4. pytest on crates/hetcomm-py/tests.
set -euo pipefail
cd "$(dirname "$0")/.."
ROOT=$PWD

step() { printf '\n=== %s ===\n' "$*"; }

VENV=$ROOT/target/py-venv
PY=$VENV/bin/python
if [ ! -x "$PY" ]; then
  step "python venv in target/py-venv"
  python3 -m venv "$VENV"
fi
if ! "$PY" -c 'import maturin, pytest' >/dev/null 2>&1 && ! { [ -x "$VENV/bin/maturin" ] && "$PY" -c 'import pytest' >/dev/null 2>&1; }; then
  step "installing maturin and pytest"
  "$PY" -m pip install --quiet --disable-pip-version-check --upgrade pip
  "$PY" -m pip install --quiet --disable-pip-version-check "maturin>=1.9,<2" "pytest>=7"
fi

if ! "$PY" -c 'import cryptography' >/dev/null 2>&1; then
  # X25519 and AES-GCM for test_secured_vectors.py, which checks the secured-frame vectors
  # with a port of docs/wire-format.md (the standard library has neither).
  step "installing cryptography"
  "$PY" -m pip install --quiet --disable-pip-version-check "cryptography>=42"
fi
# The `mcap` package reads the CLI's recordings back (tests/test_mcap_recording.py).
if ! "$PY" -c 'import mcap' >/dev/null 2>&1; then
  step "installing mcap"
  "$PY" -m pip install --quiet --disable-pip-version-check "mcap>=1.1,<2"
fi

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
