#!/usr/bin/env bash
# Build the IMPREsS workstation for Linux from a clean clone. Outputs, all in dist/:
#
#   impress_gui-VERSION.tar.gz                 source distribution   (python -m build)
#   impress_gui-VERSION-py3-none-any.whl       wheel, built from that sdist
#   impress/                                   the self-contained application (PyInstaller,
#                                              one folder): dist/impress/impress is `impress`
#   impress-VERSION-linux-ARCH.tar.gz          that folder with the desktop entry, the icon and
#                                              install-desktop.sh, ready to unpack anywhere
#
# The build tools (packaging/requirements-build.txt) and the application's pinned dependencies
# (constraints.txt) go into their own virtual environment, packaging/.venv-build, never into
# .venv. Needs Python >= 3.10 with venv, and the system libraries scripts/bootstrap.sh lists.
#
#   packaging/build.sh                 # everything
#   packaging/build.sh --no-bundle     # only the sdist and the wheel
#   PYTHON=python3.11 packaging/build.sh
set -euo pipefail
here="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
cd "$here"

bundle=1
for arg in "$@"; do
  case "$arg" in
    --no-bundle) bundle=0 ;;
    -h|--help) sed -n '2,19p' "$0"; exit 0 ;;
    *) echo "build.sh: unknown option $arg" >&2; exit 2 ;;
  esac
done

t_start=$(date +%s)
PY="${PYTHON:-python3}"
VENV=packaging/.venv-build
BPY="$VENV/bin/python"
version="$(sed -n 's/^__version__ = "\(.*\)"/\1/p' impress_gui/__init__.py)"
arch="$(uname -m)"
[ -n "$version" ] || { echo "build.sh: cannot read the version from impress_gui/__init__.py" >&2; exit 1; }

# Timestamps inside the archives: the last commit's time, so a rebuild of the same commit gives
# the same wheel and the same bundle tarball listing.
SOURCE_DATE_EPOCH="$(git log -1 --format=%ct 2>/dev/null || echo 315532800)"
export SOURCE_DATE_EPOCH
export PYTHONHASHSEED=0
export PIP_DISABLE_PIP_VERSION_CHECK=1

echo "== build environment: $VENV"
if [ ! -x "$BPY" ]; then
  "$PY" -m venv "$VENV"
fi
stamp="$VENV/.impress-build-tools"
want="$(cat packaging/requirements-build.txt constraints.txt | sha256sum | cut -d' ' -f1)"
if [ ! -f "$stamp" ] || [ "$(cat "$stamp")" != "$want" ]; then
  "$BPY" -m pip install -q --upgrade "pip>=24"
  "$BPY" -m pip install -q -r packaging/requirements-build.txt
  echo "$want" > "$stamp"
fi

echo "== sdist and wheel (impress_gui $version)"
mkdir -p dist build
rm -f "dist/impress_gui-$version.tar.gz" "dist/impress_gui-$version-py3-none-any.whl"
# --no-isolation: the pinned setuptools/wheel of the build environment, no download
"$BPY" -m build --no-isolation --outdir dist . > build/python-build.log 2>&1 || {
  tail -30 build/python-build.log >&2; echo "build.sh: python -m build failed (build/python-build.log)" >&2; exit 1; }

wheel="dist/impress_gui-$version-py3-none-any.whl"
sdist="dist/impress_gui-$version.tar.gz"
for f in "$wheel" "$sdist"; do [ -f "$f" ] || { echo "build.sh: $f was not made" >&2; exit 1; }; done
# setuptools writes the sdist with the files' and the clock's times: repack it with the commit's
# time, sorted, without owners, so the same commit gives the same bytes (the wheel already does)
"$BPY" - "$sdist" <<'EOF'
import gzip, io, os, sys, tarfile
path, epoch = sys.argv[1], int(os.environ["SOURCE_DATE_EPOCH"])
with tarfile.open(path) as src:
    members = sorted(src.getmembers(), key=lambda m: m.name)
    data = {m.name: src.extractfile(m).read() for m in members if m.isfile()}
buf = io.BytesIO()
with tarfile.open(fileobj=buf, mode="w", format=tarfile.PAX_FORMAT) as dst:
    for m in members:
        m.mtime, m.uid, m.gid, m.uname, m.gname = epoch, 0, 0, "", ""
        m.pax_headers = {}
        dst.addfile(m, io.BytesIO(data[m.name]) if m.isfile() else None)
with open(path, "wb") as fh, gzip.GzipFile(fileobj=fh, mode="wb", mtime=epoch, filename="") as gz:
    gz.write(buf.getvalue())
EOF
"$BPY" - "$wheel" <<'EOF'
import sys, zipfile
names = zipfile.ZipFile(sys.argv[1]).namelist()
need = "impress_gui/resources/targets/l_target_v1.json"
if need not in names:
    sys.exit(f"build.sh: the wheel lacks {need}")
EOF
[ "$bundle" = 1 ] || { echo "built $sdist and $wheel"; exit 0; }

echo "== the application's dependencies (constraints.txt) and the wheel into $VENV"
"$BPY" -m pip install -q -c constraints.txt "$wheel"
"$BPY" -m pip install -q --no-deps --force-reinstall "$wheel"

echo "== PyInstaller one-folder bundle: dist/impress/"
t_bundle=$(date +%s)
rm -rf dist/impress build/pyinstaller
"$VENV/bin/pyinstaller" --noconfirm --clean --log-level WARN \
  --distpath dist --workpath build/pyinstaller packaging/impress.spec
app=dist/impress
install -m 644 packaging/impress.desktop "$app/impress.desktop"
install -m 644 packaging/impress.svg packaging/impress.png "$app/"
install -m 755 packaging/install-desktop.sh "$app/install-desktop.sh"
"$app/impress" --version
echo "== tarball"
tarball="dist/impress-$version-linux-$arch.tar.gz"
tar --sort=name --mtime="@$SOURCE_DATE_EPOCH" --owner=0 --group=0 --numeric-owner \
  -C dist -cf - impress | gzip -n -6 > "$tarball"

t_end=$(date +%s)
echo
echo "built in $((t_end - t_start)) s (bundle $((t_end - t_bundle)) s):"
du -sh "$app" | sed 's/^/  /'
ls -l "$tarball" "$wheel" "$sdist" | awk '{printf "  %8.1f MB  %s\n", $5 / 1e6, $9}'
echo "run it: $app/impress   (smoke test: packaging/smoke_test.sh)"
