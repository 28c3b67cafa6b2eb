#!/usr/bin/env bash
# The main job: `dncal demo` on the built-in MV-D1024E camera. Simulates the calibration
# ramps, builds the per-ADC LUTs, streams frames through the core against the float
# reference and writes an HTML report with plots to ./dncal-demo (or -o DIR). Where the
# K-Coronagraph's deployed tables are beside the project (../shared/data/kcor-luts), the
# report also judges the paper's Fig. 5 on a real camera's ADCs (--kcor-tables).
set -euo pipefail
cd "$(dirname "$0")/.."
extra=()
tables="$PWD/../shared/data/kcor-luts"
if [[ -d "$tables" && " $* " != *" --kcor-tables"* ]]; then
    extra=(--kcor-tables "$tables")
fi
exec cargo run --release --locked -p dncal-host --bin dncal -- demo "${extra[@]}" "$@"
