#!/usr/bin/env bash
# The main job: open the IMPREsS workstation on the sample scan (made and cached by the
# simulator on first use). Extra arguments go to `impress`.
set -euo pipefail
here="$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)"
"$here/scripts/bootstrap.sh"
exec "$here/.venv/bin/impress" demo "$@"
