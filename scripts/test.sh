#!/usr/bin/env bash
# Set up .venv and run the default test suite (fast; `-m slow` for the long statistical runs).
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
.venv/bin/python -m pytest -q "$@"
