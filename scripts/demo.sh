#!/usr/bin/env bash
# The main job: `dncal demo` on the built-in MV-D1024E camera. Simulates the calibration
# ramps, builds the per-ADC LUTs, streams frames through the core against the float
# reference and writes an HTML report with plots to ./dncal-demo (or -o DIR), relative to
# the directory it is run from; the last line names the report by its absolute path.
# Where the K-Coronagraph's deployed tables are beside the project
# (../shared/data/kcor-luts), the report also judges the paper's Fig. 5 on a real
# camera's ADCs (--kcor-tables).
#
# It builds the project exactly as scripts/test.sh does (`cargo test --profile checked
# --workspace --no-run`: optimized, overflow checks on, with the features the tests'
# dependencies add), so that whichever of the two runs second compiles nothing; `cargo
# run -p dncal-host` would resolve fewer features (serde, syn, rand...) and build 34
# crates a second time. Cargo runs in the repository (its configuration, a relative
# CARGO_TARGET_DIR), the demo in the caller's directory.
set -euo pipefail
root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
target="$(cd "$root" && realpath -m "${CARGO_TARGET_DIR:-target}")"
extra=()
tables="$root/../shared/data/kcor-luts"
if [[ -d "$tables" && " $* " != *" --kcor-tables"* ]]; then
    extra=(--kcor-tables "$tables")
fi
(cd "$root" && cargo test --profile checked --workspace --locked --no-run 2>&1) \
    | sed '/^  Executable /d' >&2
exec "$target/checked/dncal" demo "${extra[@]}" "$@"
