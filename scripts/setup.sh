#!/usr/bin/env bash
# Create .venv (if needed) and install lpy-light into it with its test extras, at the versions CI tested
# (constraints.txt: the kernel's stored numbers were recorded with them).
set -euo pipefail
cd "$(dirname "$0")/.."
PY=${PYTHON:-python3}
if [ ! -x .venv/bin/python ]; then
  "$PY" -m venv .venv
fi
.venv/bin/python -m pip install -q --upgrade pip
.venv/bin/python -m pip install -q -c constraints.txt -e ".[test]"
