#!/usr/bin/env bash
# Smoke test of the built application (packaging/build.sh first). Uses only the bundle, no
# Python environment of the project, and no display (Qt offscreen):
#
#   1. `impress --version` and `--help` run;
#   2. the simulated motor answers (`impress motor --port sim status`, a short move);
#   3. the bundled `impress demo --no-gui` builds the sample project: a simulated shoe scan
#      (rendered in spawned worker processes), calibrated and processed (2-4 minutes);
#   4. `impress gui PROJECT --tab viewer --check --screenshot out.png` opens it offscreen on the
#      viewer tab, waits until the project and its reconstruction have loaded, and exits with
#      status 0 only if everything opened and no error message was shown (otherwise status 1,
#      the errors on stderr, which this script prints); no traceback, and a 1920x1080 picture
#      of the window (SCREENSHOT=out.png keeps it).
#
#   packaging/smoke_test.sh                 # all of it, in a temporary folder
#   packaging/smoke_test.sh PROJECT         # skip step 3: open this existing project
#   APP=/opt/impress/impress packaging/smoke_test.sh   # test an installed copy
set -euo pipefail
here="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
APP="${APP:-$here/dist/impress/impress}"
[ -x "$APP" ] || { echo "smoke_test: $APP not found: run packaging/build.sh first" >&2; exit 1; }
work="$(mktemp -d "${TMPDIR:-/tmp}/impress-smoke.XXXXXX")"
keep="${KEEP:-0}"
cleanup() { [ "$keep" = 1 ] || rm -rf "$work"; }
trap cleanup EXIT
export QT_QPA_PLATFORM=offscreen
# a settings file of its own, so the test neither reads nor changes the user's
settings="$work/settings.ini"
t0=$(date +%s)
fail() { echo "smoke_test: FAILED: $*" >&2; exit 1; }
step() { echo "== $*"; }

step "version and help ($APP)"
"$APP" --version | grep -q "^impress " || fail "--version"
"$APP" --help | grep -q "calibrate" || fail "--help lists no commands"

step "simulated motor"
"$APP" motor --port sim --sim-time-scale 50 status > "$work/motor.txt" || fail "motor status"
grep -q "emulator" "$work/motor.txt" || fail "motor status: $(cat "$work/motor.txt")"
"$APP" motor --port sim --sim-time-scale 50 move --by 5 --speed 10 > /dev/null || fail "motor move"

if [ $# -ge 1 ]; then
  project="$1"
else
  step "sample project (impress demo --no-gui)"
  t_demo=$(date +%s)
  "$APP" demo --no-gui --cache "$work/cache" > "$work/demo.txt" 2> "$work/demo-err.txt" || {
    tail -20 "$work/demo-err.txt" >&2; fail "impress demo"; }
  project="$(sed -n 's/^sample project: \(.*\) (ready in.*/\1/p' "$work/demo.txt")"
  echo "   built in $(( $(date +%s) - t_demo )) s: $project"
fi
[ -f "$project/project.json" ] || fail "$project is not a project folder"

step "window: open the project offscreen, check it loaded, screenshot, quit"
shot="$work/window.png"
t_gui=$(date +%s)
"$APP" gui --help | grep -q -- "--check" || fail "impress gui has no --check: an old build?"
set +e
# the viewer exercises pyqtgraph and the reconstruction readers in the frozen application;
# --check fails on any error the window shows (project, evidence video, reconstruction)
"$APP" gui "$project" --tab viewer --check --settings "$settings" --screenshot "$shot" \
  > "$work/gui.txt" 2> "$work/gui-err.txt"
rc=$?
set -e
cat "$work/gui.txt"
[ "$rc" = 0 ] || { cat "$work/gui-err.txt" >&2; fail "impress gui --check exited with status $rc"; }
grep -q "^check passed" "$work/gui.txt" || fail "impress gui --check did not report a passed check"
if grep -q "Traceback" "$work/gui-err.txt"; then cat "$work/gui-err.txt" >&2; fail "a traceback"; fi
[ -s "$shot" ] || fail "no screenshot"
size="$(od -An -tu1 -j16 -N8 "$shot" | awk '{printf "%dx%d", $1*16777216+$2*65536+$3*256+$4, $5*16777216+$6*65536+$7*256+$8}')"
[ "$size" = "1920x1080" ] || fail "the screenshot is $size, not 1920x1080"
bytes=$(wc -c < "$shot")
[ "$bytes" -gt 20000 ] || fail "the screenshot is nearly empty ($bytes bytes)"
echo "   window opened, loaded and closed in $(( $(date +%s) - t_gui )) s; screenshot $size"
if [ -n "${SCREENSHOT:-}" ]; then cp "$shot" "$SCREENSHOT"; echo "   copied to $SCREENSHOT"; fi

echo "smoke test passed in $(( $(date +%s) - t0 )) s"
