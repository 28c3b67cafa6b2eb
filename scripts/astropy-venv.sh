#!/usr/bin/env bash
# Python virtual environment holding astropy and numpy, the reference reader and the
# numeric oracle of the Rust tests (host-sim/tests/fits_astropy.rs, kcor_luts.rs, cli.rs).
# Nothing is installed into the system Python (Debian refuses it, PEP 668, and a user's
# own environment is theirs): the venv lives in target/astropy-venv.
#
# Creates it when missing or broken and prints its python path as the last line of
# stdout; fast when it is already good:
#
#   PY=$(scripts/astropy-venv.sh | tail -n 1)
set -euo pipefail

ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
source "$ROOT/scripts/venv.sh"
make_venv astropy-venv 'import astropy.io.fits, numpy' astropy numpy
