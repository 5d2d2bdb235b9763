#!/usr/bin/env bash
# Run the whole test suite (offscreen Qt). Extra arguments go to pytest.
set -euo pipefail
here="$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)"
"$here/scripts/bootstrap.sh"
cd "$here"
export QT_QPA_PLATFORM=offscreen
# two workers, each taking whole files (module fixtures render once per file); the suite is
# about twice as fast on two cores; IMPRESS_TEST_WORKERS=0 runs it in one process. The files
# go out in collection order, the longest first (tests/conftest.py: LONG_FILES), not
# reordered by their number of tests
workers="${IMPRESS_TEST_WORKERS:-2}"
if [ "$workers" = 0 ]; then
  exec .venv/bin/python -m pytest "$@"
fi
exec .venv/bin/python -m pytest -n "$workers" --dist loadfile --no-loadscope-reorder "$@"
