#!/usr/bin/env bash
# The main job for now: the correction core on the Cortex-M4 firmware in QEMU against
# the host, bit for bit. Installs the cross toolchain when missing.
set -euo pipefail
cd "$(dirname "$0")/.."
scripts/firmware.sh install
exec cargo run --release --locked -p dncal-host --bin dncal -- firmware-check "$@"
