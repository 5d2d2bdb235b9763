#!/usr/bin/env bash
# Prepare a working environment from a fresh clone: system libraries the wheels need
# (installed with apt-get when run as root, otherwise listed), a virtual environment in
# .venv, and the package installed into it with the pinned versions of constraints.txt.
set -euo pipefail
here="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
cd "$here"

# open3d needs libusb and libgomp; Qt (offscreen and xcb) needs GL/EGL, fontconfig, xkbcommon, dbus
SYSTEM_PACKAGES=(libusb-1.0-0 libgomp1 libgl1 libegl1 libglib2.0-0 libfontconfig1 libxkbcommon0 libdbus-1-3)
# Qt 6's xcb platform plugin (a real X display): everything `ldd` lists for the wheel's
# plugins/platforms/libqxcb.so, lib/libQt6XcbQpa.so.6 and plugins/xcbglintegrations/*.so,
# plus libxcb-cursor0 (loaded at start-up; without it Qt refuses xcb and asks for it by name,
# even when the real gap is another library) and the X client libraries the wheels load
SYSTEM_PACKAGES+=(libx11-6 libx11-xcb1 libxcb1 libxcb-cursor0 libxcb-icccm4 libxcb-image0
  libxcb-keysyms1 libxcb-randr0 libxcb-render0 libxcb-render-util0 libxcb-shape0 libxcb-shm0
  libxcb-sync1 libxcb-util1 libxcb-xfixes0 libxcb-xinerama0 libxcb-xkb1 libxkbcommon-x11-0
  libxext6 libxrender1 libxi6 libsm6 libice6 libfreetype6)
# an OpenGL context on an X display (the GPU 3D view, also under Xvfb): Mesa's GLX and EGL
# vendor libraries and its DRI drivers (llvmpipe, the software rasteriser, when there is no GPU)
SYSTEM_PACKAGES+=(libglx0 libglx-mesa0 libegl-mesa0 libgl1-mesa-dri libxcb-glx0)
# Xvfb: the test suite starts the window on a virtual X display with the xcb platform
SYSTEM_PACKAGES+=(xvfb)
missing=()
if command -v dpkg >/dev/null 2>&1; then
  for p in "${SYSTEM_PACKAGES[@]}"; do
    dpkg -s "$p" >/dev/null 2>&1 || missing+=("$p")
  done
fi
if ((${#missing[@]})); then
  if [ "$(id -u)" = 0 ] && command -v apt-get >/dev/null 2>&1; then
    echo "bootstrap: installing system packages: ${missing[*]}"
    export DEBIAN_FRONTEND=noninteractive
    apt-get install -y -q "${missing[@]}" >/dev/null 2>&1 || {
      apt-get update -q >/dev/null && apt-get install -y -q "${missing[@]}" >/dev/null
    }
  else
    echo "bootstrap: please install these system packages first (as root):" >&2
    echo "    apt-get install ${missing[*]}" >&2
    exit 1
  fi
fi

PY="${PYTHON:-python3}"
if [ ! -x .venv/bin/python ]; then
  echo "bootstrap: creating .venv with $($PY --version)"
  "$PY" -m venv .venv
fi
stamp=".venv/.impress-installed"
want="$(cat pyproject.toml constraints.txt | sha256sum | cut -d' ' -f1)"
if [ ! -f "$stamp" ] || [ "$(cat "$stamp")" != "$want" ]; then
  echo "bootstrap: installing impress-gui and its pinned dependencies into .venv"
  .venv/bin/python -m pip install -q --upgrade "pip>=24"
  .venv/bin/python -m pip install -q -c constraints.txt -e ".[test,docs]"
  echo "$want" > "$stamp"
fi
