#!/usr/bin/env bash
# The Python package (python/, docs/python.md): builds its wheel with maturin into a
# venv of its own under target/ (target/python-venv: numpy, pytest, astropy, dask,
# distributed, maturin, all from the registry; nothing outside the project is touched),
# then runs its pytest suite against the `dncal` binary of the same build.
#
#   scripts/python.sh          install the package into the venv and run the tests
#   scripts/python.sh install  only install; prints the venv's python as the last line
#
# The wheel is built in the `checked` profile (optimized, overflow checks on), as
# scripts/test.sh and scripts/demo.sh build the rest; maturin selects only this package,
# so a dependency whose features differ from the workspace build's is compiled again here.
# A user's `pip install ./python` builds the release profile.
set -euo pipefail

ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
source "$ROOT/scripts/venv.sh"
PY=$(make_venv python-venv 'import numpy, pytest, astropy.io.fits, dask.array, distributed, maturin' \
    "maturin>=1.9,<2" "numpy>=1.21" pytest astropy "dask[array]" distributed | tail -n 1)
# maturin's build backend runs the `maturin` of PATH: the venv's.
PATH="$(dirname "$PY"):$PATH" MATURIN_PEP517_ARGS="--profile checked" "$PY" -m pip install --quiet --disable-pip-version-check \
    --no-build-isolation --no-deps --force-reinstall "$ROOT/python" >&2
if [[ "${1:-}" == install ]]; then
    echo "$PY"
    exit 0
fi
# The CLI the tests compare against: DNCAL_BIN (scripts/test.sh gives the binary its
# `cargo test` has just built and tested), else this checkout's, built here.
if [[ -z "${DNCAL_BIN:-}" ]]; then
    (cd "$ROOT" && cargo build --profile checked --quiet --locked -p dncal-host --bin dncal)
    export DNCAL_BIN="$(cd "$ROOT" && realpath -m "${CARGO_TARGET_DIR:-target}")/checked/dncal"
fi
cd "$ROOT/python"
"$PY" -m pytest -q tests
