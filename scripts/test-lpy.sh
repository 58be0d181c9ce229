#!/usr/bin/env bash
# The L-Py tests against the real L-Py and PlantGL: the bundle in ../shared/lpy installed into .venv-lpy with the
# project.  Skipped, with one line saying so, where the bundle is not there (L-Py then comes from conda).
set -euo pipefail
cd "$(dirname "$0")/.."
BUNDLE=${LPY_BUNDLE:-../shared/lpy/install.sh}
if [ ! -f "$BUNDLE" ]; then
  echo "test-lpy: no L-Py bundle at $BUNDLE: the L-Py tests are skipped (with conda: pytest -m lpy)"
  exit 0
fi
PY=${PYTHON:-python3}
if ! "$PY" -c 'import sys; sys.exit(sys.version_info[:2] != (3, 11))'; then
  echo "test-lpy: the bundle needs Python 3.11 ($PY is $("$PY" -V 2>&1)): the L-Py tests are skipped"
  exit 0
fi
[ -x .venv-lpy/bin/python ] || "$PY" -m venv .venv-lpy
bash "$BUNDLE" .venv-lpy
# the versions of constraints.txt but numpy's: the bundle is built against numpy 1.x
.venv-lpy/bin/python -m pip install -q -c <(grep -v '^numpy==' constraints.txt; echo 'numpy<2') -e ".[test]"
.venv-lpy/bin/python -m pytest -q -m "lpy and not slow" tests
