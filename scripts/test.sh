#!/usr/bin/env bash
# Set up .venv and run the default test suite (fast; `-m slow` for the long statistical runs).
# Where the L-Py/PlantGL bundle of this machine is at hand (../shared/lpy/install.sh, our machines and CI), also
# set up .venv-lpy with it (it pins numpy < 2, hence a venv of its own) and run the L-Py tests there against the
# real L-Py; elsewhere (a user's machine: L-Py comes from conda) those tests are skipped.
# Then the documentation site is built with warnings as errors (scripts/docs.sh: a broken link fails it).
# Each runs whatever the one before gives; each one's result is reported at the end, and the script exits
# non-zero if any failed.  Arguments go to the core suite's pytest, and the L-Py suite and the docs are left out.
set -uo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh || exit $?
.venv/bin/python -m pytest -q "$@"
core=$?
lpy=0
docs=0
if [ $# -eq 0 ]; then
  bash scripts/test-lpy.sh
  lpy=$?
  bash scripts/docs.sh
  docs=$?
fi
verdict() { case $1 in 0) echo "passed" ;; 5) echo "no test ran (exit 5)" ;; *) echo "FAILED (exit $1)" ;; esac; }
echo "test.sh: core suite (.venv): $(verdict $core)"
if [ $# -eq 0 ]; then
  echo "test.sh: L-Py suite (.venv-lpy): $(verdict $lpy)"
  echo "test.sh: docs site (scripts/docs.sh, mkdocs --strict): $([ $docs -eq 0 ] && echo built || echo "FAILED (exit $docs)")"
fi
[ $core -eq 0 ] && [ $lpy -eq 0 ] && [ $docs -eq 0 ]
