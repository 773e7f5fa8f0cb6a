#!/usr/bin/env bash
# The C and C++ API's tests (crates/hetcomm-c, docs/cpp.md), runnable on a fresh machine:
#
#   bash scripts/cpp-test.sh
#
# 1. Debian packages through scripts/install.sh: cmake, g++, pkg-config, valgrind,
#    libmsgpack-cxx-dev;
# 2. the Rust pieces (debug): libhetcomm_c, the Rust interop peer, the hetcomm CLI; the Python
#    package from target/py-venv (made by scripts/test-python.sh, run first when missing);
# 3. the CMake package built and installed into a scratch prefix, and examples/c/hello.c
#    compiled against it through pkg-config;
# 4. the ctest suite (crates/hetcomm-c/tests/native: C API, C++ wrapper, examples, interop
#    with Rust and Python over UDP and TCP, the C++ Tango in the demo, leak loop under
#    valgrind), built against the installed package with find_package(hetcomm);
# 5. the same suite again under AddressSanitizer + UndefinedBehaviorSanitizer (with
#    LeakSanitizer), the demo left out (it already ran and takes 30 s).
# Called by scripts/test.sh.
set -euo pipefail
cd "$(dirname "$0")/.."
ROOT=$PWD
TARGET=${CARGO_TARGET_DIR:-$ROOT/target}
JOBS=$(nproc 2>/dev/null || echo 2)

step() { printf '\n=== %s ===\n' "$*"; }

bash scripts/install.sh

step "Rust: libhetcomm_c, the interop peer, the hetcomm CLI"
# Separate invocations: each package builds with its own features, as the CMake package
# build (`cargo build -p hetcomm-c`) does, so nothing is rebuilt twice.
cargo build -q -p hetcomm-c
cargo build -q -p hetcomm-cli
cargo build -q -p hetcomm-c --example interop_peer

PY=$ROOT/target/py-venv/bin/python
if ! "$PY" -c 'import hetcomm' >/dev/null 2>&1; then
    step "the Python package (scripts/test-python.sh)"
    bash scripts/test-python.sh -q
fi

BUILD=$TARGET/cpp
rm -rf "$BUILD"
PREFIX=$BUILD/prefix

step "CMake package: build and install into $PREFIX"
cmake -S crates/hetcomm-c -B "$BUILD/package" -DHETCOMM_CARGO_PROFILE=dev >/dev/null
cmake --build "$BUILD/package"
cmake --install "$BUILD/package" --prefix "$PREFIX" >/dev/null

step "pkg-config: examples/c/hello.c"
PCDIR=$(dirname "$(find "$PREFIX" -name hetcomm.pc | head -1)")
# shellcheck disable=SC2046
cc -std=c11 -Wall -Wextra -Werror -DHELLO_FLEET="\"$ROOT/examples/c/hello.toml\"" examples/c/hello.c \
    -o "$BUILD/hello_pkgconfig" $(PKG_CONFIG_PATH=$PCDIR pkg-config --cflags --libs hetcomm)
LD_LIBRARY_PATH=$(PKG_CONFIG_PATH=$PCDIR pkg-config --variable=libdir hetcomm) "$BUILD/hello_pkgconfig" >/dev/null

configure() {
    cmake -S crates/hetcomm-c/tests/native -B "$1" -DCMAKE_PREFIX_PATH="$PREFIX" \
        -DHETCOMM_RUST_PEER="$TARGET/debug/examples/interop_peer" -DHETCOMM_PYTHON="$PY" \
        -DHETCOMM_CLI="$TARGET/debug/hetcomm" "${@:2}" >/dev/null
    cmake --build "$1" -j "$JOBS"
}

step "ctest (find_package(hetcomm); valgrind leak check)"
configure "$BUILD/tests" -DHETCOMM_VALGRIND=ON
ctest --test-dir "$BUILD/tests" --output-on-failure

step "ctest under AddressSanitizer + UndefinedBehaviorSanitizer"
configure "$BUILD/tests-asan" -DHETCOMM_SANITIZE=ON
ASAN_OPTIONS=detect_leaks=1:halt_on_error=1:abort_on_error=0 \
UBSAN_OPTIONS=print_stacktrace=1:halt_on_error=1 \
    ctest --test-dir "$BUILD/tests-asan" --output-on-failure -E demo_cpp_tango
