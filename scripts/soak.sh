#!/usr/bin/env bash
# The soak (issue 18; not in CI): 10^9 pixels (or PIXELS) through the core and the FPGA
# model with every sum checked against the float reference, random LUT swaps (some asked
# mid-frame, some images corrupted on purpose), saturating segments and random ROIs.
#
#   scripts/soak.sh [PIXELS] [SEED]        e.g. scripts/soak.sh 1e9 18
#
# Prints a summary on stderr and the JSON report on stdout; exits 1 if any check failed.
# Its result goes in docs/reliability.md.
set -euo pipefail
cd "$(dirname "$0")/.."
pixels=$(python3 -c "print(int(float('${1:-1e9}')))")
seed=${2:-18}
cargo run --release --locked -q -p dncal-host --example soak -- --pixels "$pixels" --seed "$seed" --json
