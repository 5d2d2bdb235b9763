#!/usr/bin/env bash
# Build the user guide (docs/*.md) into a static HTML site in site/ (git-ignored by the
# .gitignore the build writes into it). Open site/index.html in a browser.
#
#   scripts/build_docs.sh              # uses .venv (scripts/bootstrap.sh makes it)
#   scripts/build_docs.sh --out DIR    # another output folder
#
# Installs the docs extra's one package, markdown (pinned in constraints.txt), into .venv when
# it is missing, and checks first that docs/cli.md matches the command parsers.
set -euo pipefail
here="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
cd "$here"
PY="${PYTHON:-.venv/bin/python}"
if [ ! -x "$PY" ] && ! command -v "$PY" >/dev/null 2>&1; then
  echo "build_docs: $PY not found: run scripts/bootstrap.sh first (or set PYTHON)" >&2
  exit 1
fi
if ! "$PY" -c "import markdown" 2>/dev/null; then
  echo "build_docs: installing markdown (docs extra) with the pinned version of constraints.txt"
  "$PY" -m pip install -q -c constraints.txt markdown
fi
"$PY" docs/gen_cli.py --check || {
  echo "build_docs: docs/cli.md is stale; regenerate it: $PY docs/gen_cli.py" >&2
  exit 1
}
exec "$PY" scripts/build_docs.py "$@"
