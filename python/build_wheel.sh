#!/usr/bin/env bash
# Build the Python package's wheel: the `autotune` binary and the worker library in one.
#
#   python/build_wheel.sh OUT_DIR [AUTOTUNE_BINARY]
#
# (from anywhere; needs cargo and maturin on PATH). AUTOTUNE_BINARY: an `autotune` binary
# built already (as .ci/run has one from `cargo test`), else cargo builds it.
#
# maturin builds one kind of target per wheel (here the native module), so the binary is
# built by cargo first and staged in python/autotune.data/scripts, which the wheel installs
# into the environment's bin/. Both come from the one workspace target directory, so the
# library is compiled once.
set -euo pipefail
out=${1:?usage: python/build_wheel.sh OUT_DIR [AUTOTUNE_BINARY]}
binary=${2:-}
mkdir -p "$out"
out=$(cd "$out" && pwd)
[[ -z $binary ]] || binary=$(cd "$(dirname "$binary")" && pwd)/$(basename "$binary")
cd "$(dirname "$0")/.."
if [[ -z $binary ]]; then
    cargo build --release --locked --bin autotune
    binary=target/release/autotune
fi
mkdir -p python/autotune.data/scripts
# Stripped: the release profile keeps debug info for profiling (80 MB, not 12).
install -m 755 "$binary" python/autotune.data/scripts/autotune
strip python/autotune.data/scripts/autotune
(cd python && maturin build --release --locked --out "$out")
ls "$out"/autotune-*.whl
