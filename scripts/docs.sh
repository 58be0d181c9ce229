#!/usr/bin/env bash
# Build the documentation site into site/ (mkdocs.yml), warnings as errors: a broken link or anchor, a docstring
# the API pages cannot read, a LightModel parameter or a scene key the reference pages miss all fail the build.
# The site's tools live in .venv-docs, at docs/requirements.txt's versions (installed again only when that file
# changes); the command-line page runs `lpy-light --help` with .venv's lpy-light (scripts/setup.sh makes .venv
# when it is missing).  Extra arguments go to `mkdocs build`.  scripts/test.sh runs this.
set -euo pipefail
cd "$(dirname "$0")/.."
PY=${PYTHON:-python3}
[ -x .venv/bin/python ] || bash scripts/setup.sh
[ -x .venv-docs/bin/python ] || "$PY" -m venv .venv-docs
digest() { .venv-docs/bin/python -c 'import hashlib, sys; print(hashlib.sha256(open(sys.argv[1], "rb").read()).hexdigest())' "$1"; }
stamp=.venv-docs/requirements.sha256
if [ "$(cat "$stamp" 2>/dev/null)" != "$(digest docs/requirements.txt)" ]; then
  .venv-docs/bin/python -m pip install -q --disable-pip-version-check -r docs/requirements.txt
  digest docs/requirements.txt > "$stamp"
fi
export NO_MKDOCS_2_WARNING=1 LPY_LIGHT_PYTHON="$PWD/.venv/bin/python"
.venv-docs/bin/python -m mkdocs build --strict --clean "$@"
