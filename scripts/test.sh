#!/usr/bin/env bash
# Set up .venv and run the default test suite (fast; `-m slow` for the long statistical runs).
# Where the L-Py/PlantGL bundle of this machine is at hand (../shared/lpy/install.sh, our machines and CI), also
# set up .venv-lpy with it (it pins numpy < 2, hence a venv of its own) and run the L-Py tests there against the
# real L-Py; elsewhere (a user's machine: L-Py comes from conda) those tests are skipped.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
.venv/bin/python -m pytest -q "$@"
if [ $# -eq 0 ]; then
  bash scripts/test-lpy.sh
fi
