#!/usr/bin/env bash
# The main job: `dncal demo` on the built-in MV-D1024E camera. Simulates the calibration
# ramps, builds the per-ADC LUTs, streams frames through the core against the float
# reference and writes an HTML report with plots to ./dncal-demo (or -o DIR).
set -euo pipefail
cd "$(dirname "$0")/.."
exec cargo run --release --locked -p dncal-host --bin dncal -- demo "$@"
