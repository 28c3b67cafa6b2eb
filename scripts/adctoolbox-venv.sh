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
VENV="$ROOT/target/adctoolbox-venv"
PY="$VENV/bin/python"
MARKER="$VENV/.adctoolbox-0.9.1-ok"
PACKAGES=("adctoolbox==0.9.1" "numpy" "astropy")

import_ok() {
    "$PY" -c 'import adctoolbox, numpy, astropy.io.fits' >/dev/null 2>&1
}

if [[ -f "$MARKER" && -x "$PY" ]] && "$PY" -c 'import sys' >/dev/null 2>&1; then
    echo "$PY"
    exit 0
fi

{
    if [[ -x "$PY" ]] && import_ok; then
        echo "adctoolbox-venv: existing venv at $VENV works"
    else
        if [[ -e "$VENV" ]]; then
            echo "adctoolbox-venv: venv at $VENV is broken or incomplete; recreating it"
            rm -rf -- "$VENV"
        fi
        mkdir -p "$ROOT/target"
        echo "adctoolbox-venv: creating $VENV"
        python3 -m venv "$VENV"
        "$PY" -m pip install --quiet --disable-pip-version-check "${PACKAGES[@]}"
    fi
    if ! import_ok; then
        echo "adctoolbox-venv: import adctoolbox, numpy, astropy fails in $VENV:"
        "$PY" -c 'import adctoolbox, numpy, astropy.io.fits' || true
        exit 1
    fi
    "$PY" -c 'import numpy, astropy; from importlib.metadata import version; print("adctoolbox-venv: adctoolbox", version("adctoolbox"), "numpy", numpy.__version__, "astropy", astropy.__version__)'
    touch "$MARKER"
} 1>&2

echo "$PY"
