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
source "$ROOT/scripts/venv.sh"
make_venv emva1288-venv 'import emva1288.process, emva1288.camera, numpy
assert numpy.__version__.split(".")[0] == "1", numpy.__version__' "numpy<2" "emva1288==1.0.2"
