#!/usr/bin/env bash
# The Python package's speed ratios (issue 41; docs/python.md): builds the release wheel
# into target/python-bench-venv (as a user's `pip install ./python` builds it), makes a
# linearity set with the release `dncal`, and runs python/bench/speed.py, which times
# Corrector.add against the core's own rate on the same frames, and fit_linearity
# against `dncal linearity`'s analysis, alternating, in one process. Not part of the
# tests (a benchmark, not a timed test). Prints the JSON.
#
#   scripts/python-bench.sh [RUNS]          the two ratios (python/bench/speed.py)
#   scripts/python-bench.sh --dask [ARGS]   the Dask fit's scaling (python/bench/dask_scale.py)
#   scripts/python-bench.sh --dask-files [ARGS]  the Dask fit from a file on 1, 2, 4 worker
#                                           processes against in memory (python/bench/dask_files.py)
set -euo pipefail

ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
source "$ROOT/scripts/venv.sh"
PY=$(make_venv python-bench-venv 'import numpy, astropy.io.fits, maturin, dask.array, distributed' "maturin>=1.9,<2" "numpy>=1.21" astropy "dask[array]" distributed | tail -n 1)
PATH="$(dirname "$PY"):$PATH" "$PY" -m pip install --quiet --disable-pip-version-check \
    --no-build-isolation --no-deps --force-reinstall "$ROOT/python" >&2
if [[ "${1:-}" == --dask ]]; then
    shift
    exec "$PY" "$ROOT/python/bench/dask_scale.py" "$@"
fi
if [[ "${1:-}" == --dask-files ]]; then
    shift
    exec "$PY" "$ROOT/python/bench/dask_files.py" "$@"
fi
cargo build --quiet --release --locked -p dncal-host --bin dncal
SET="$ROOT/target/python-bench-linearity.fits"
# The paper's ROI size (128 x 128) at 41 levels, as `dncal bench`'s linearity set.
[[ -f "$SET" ]] || "$ROOT/target/release/dncal" --quiet simulate linearity --roi 256x256+384+384 --levels 41 --frames 16 -o "$SET" >/dev/null
"$PY" "$ROOT/python/bench/speed.py" "$SET" --runs "${1:-9}"
