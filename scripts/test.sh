#!/usr/bin/env bash
# Every test of the project, the firmware-in-QEMU test included. Installs the cross
# toolchain (Debian's rustc-web, rust-web-src, lld-22, qemu-system-arm) when missing.
set -euo pipefail
cd "$(dirname "$0")/.."
scripts/firmware.sh install
# The RTL's co-simulation (fpga-model/tests/rtl_cosim.rs) needs Verilator: installed from
# Debian when missing (with iverilog and yosys), and required here, where the test alone
# would skip without it.
scripts/hdl.sh install
export DNCAL_REQUIRE_HDL=1
# The FITS interchange tests open our files in astropy (the astronomers' reference reader),
# in a venv of its own under target/ (the tests also make it when missing): nothing goes
# into the system Python.
scripts/astropy-venv.sh >/dev/null
# The EMVA 1288 reference implementation (emva1288 1.0.2, numpy<2) in a venv of its own,
# the oracle of host-sim/tests/emva_reference.rs (the test also makes it when missing).
scripts/emva-venv.sh >/dev/null
# The IEEE 1241 histogram-test oracles (our numpy implementation of the standard's
# definitions, and the MIT-licensed `adctoolbox`) in a venv of their own under target/,
# the oracles of host-sim/tests/ieee1241_oracle.rs (the test also makes it when missing).
scripts/adctoolbox-venv.sh >/dev/null
# The browser test opens every HTML page the commands write in Debian's headless Chromium
# (host-sim/tests/browser.rs); here a missing browser fails it instead of skipping.
scripts/browser/install.sh
export DNCAL_REQUIRE_BROWSER=1
# The architecture checks of docs/architecture.md: import cycles, string errors, labels in
# path fields, the library reaching into the CLI; a count may fall, never rise.
python3 scripts/arch_check.py --self-test --ratchet scripts/arch_baseline.json >/dev/null
# The `checked` profile (optimized, overflow checks on: Cargo.toml), built by the same
# command scripts/demo.sh builds with: whichever of the two README commands runs second
# compiles nothing.
cargo test --profile checked --workspace --locked
# The Python package: its wheel built into target/python-venv (maturin, numpy, dask... from
# the registry) and its pytest suite, which compares it with the binary just tested.
DNCAL_BIN="$(realpath -m "${CARGO_TARGET_DIR:-target}")/checked/dncal" scripts/python.sh
# Lints (clippy, the core with defmt) are CI's (.ci/run), run after these tests.
