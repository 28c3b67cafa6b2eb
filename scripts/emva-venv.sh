#!/usr/bin/env bash
# Python virtual environment holding the EMVA 1288 reference implementation
# (PyPI `emva1288` 1.0.2, which needs numpy<2 because it calls np.asfarray),
# used as an independent oracle by scripts/emva_reference.py and
# scripts/emva_simulate.py.
#
# Creates $ROOT/target/emva1288-venv when it is missing or broken, installs the
# packages (quietly; all chatter goes to stderr), checks that
# `import emva1288.process, emva1288.camera` works and prints the venv's python
# path as the last line of stdout. Fast when the venv is already good:
#
#   VENV_PY=$(scripts/emva-venv.sh | tail -n 1)
#   "$VENV_PY" scripts/emva_simulate.py --out /tmp/set12 --bits 12
#   "$VENV_PY" scripts/emva_reference.py /tmp/set12/EMVA1288descriptor.txt
set -euo pipefail

ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
VENV="$ROOT/target/emva1288-venv"
PY="$VENV/bin/python"
MARKER="$VENV/.emva1288-1.0.2-ok"
PACKAGES=("numpy<2" "emva1288==1.0.2")

import_ok() {
    "$PY" -c 'import emva1288.process, emva1288.camera, numpy
assert numpy.__version__.split(".")[0] == "1", numpy.__version__' >/dev/null 2>&1
}

# Fast path: marker written after a successful install, and the interpreter
# still runs (the venv breaks when the system python it points to changes).
if [[ -f "$MARKER" && -x "$PY" ]] && compgen -G "$VENV/lib/python3*/site-packages/emva1288/process" >/dev/null \
    && "$PY" -c 'import sys' >/dev/null 2>&1; then
    echo "$PY"
    exit 0
fi

{
    if [[ -x "$PY" ]] && import_ok; then
        echo "emva-venv: existing venv at $VENV works"
    else
        if [[ -e "$VENV" ]]; then
            echo "emva-venv: venv at $VENV is broken or incomplete; recreating it"
            rm -rf -- "$VENV"
        fi
        mkdir -p "$ROOT/target"
        echo "emva-venv: creating $VENV"
        python3 -m venv "$VENV"
        "$PY" -m pip install --quiet --disable-pip-version-check "${PACKAGES[@]}"
    fi
    if ! import_ok; then
        echo "emva-venv: import emva1288.process, emva1288.camera fails in $VENV:"
        "$PY" -c 'import emva1288.process, emva1288.camera' || true
        exit 1
    fi
    "$PY" -c 'import emva1288, numpy; print("emva-venv: emva1288", emva1288.__version__, "numpy", numpy.__version__)'
    touch "$MARKER"
} 1>&2

echo "$PY"
