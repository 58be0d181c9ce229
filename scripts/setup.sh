#!/usr/bin/env bash
# Create .venv (if needed) and install lpy-light into it with its test extras, at the versions CI tested
# (constraints.txt: the kernel's stored numbers were recorded with them).  Then compile the main job's kernel
# (`lpy-light run`'s, nee on a chamber's sensors: ~30 s on 2 cores, once per version of lpy-light and numba: cached
# in ~/.cache/lpy-light for every clone and venv of that version), so that the first run traces at once.
set -euo pipefail
cd "$(dirname "$0")/.."
PY=${PYTHON:-python3}
if [ ! -x .venv/bin/python ]; then
  "$PY" -m venv .venv
fi
.venv/bin/python -m pip install -q --upgrade pip
.venv/bin/python -m pip install -q -c constraints.txt -e ".[test]"
.venv/bin/lpy-light compile
