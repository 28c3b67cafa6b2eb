#!/usr/bin/env bash
# Python virtual environment for the IEEE 1241 histogram-test oracles of
# host-sim/tests/ieee1241_oracle.rs: numpy and astropy for scripts/ieee1241_oracle.py
# (our own numpy implementation, written from the standard's definitions), and
# `adctoolbox` (PyPI, MIT licence, Zhishuai Zhang and Lu Jie, github.com/Arcadia-1/ADCToolbox),
# a third party's ramp/sine histogram analysis and SAR capacitor-mismatch model.
#
# Creates $ROOT/target/adctoolbox-venv when it is missing or broken, installs the
# packages (quietly; chatter to stderr), checks the imports and prints the venv's
# python path as the last line of stdout. Fast when the venv is already good:
#
#   PY=$(scripts/adctoolbox-venv.sh | tail -n 1)
#   "$PY" scripts/ieee1241_oracle.py analyse H.fits --input ramp --out r.json
set -euo pipefail

ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
source "$ROOT/scripts/venv.sh"
make_venv adctoolbox-venv 'import adctoolbox, numpy, astropy.io.fits' "adctoolbox==0.9.1" numpy astropy
