#!/usr/bin/env sh
# Put the unpacked IMPREsS workstation on the desktop menu and on PATH, for this user
# (or for everyone with --system, as root). Run it from the unpacked folder:
#     tar xzf impress-VERSION-linux-x86_64.tar.gz -C /opt && /opt/impress/install-desktop.sh
# --uninstall removes what it installed.
set -eu
app="$(cd "$(dirname "$0")" && pwd)"
if [ "${1:-}" = "--system" ]; then
  share=/usr/local/share; bin=/usr/local/bin; shift
else
  share="${XDG_DATA_HOME:-$HOME/.local/share}"; bin="$HOME/.local/bin"
fi
desktop="$share/applications/impress.desktop"
png="$share/icons/hicolor/256x256/apps/impress.png"
svg="$share/icons/hicolor/scalable/apps/impress.svg"
if [ "${1:-}" = "--uninstall" ]; then
  rm -f "$desktop" "$png" "$svg"
  [ -L "$bin/impress" ] && rm -f "$bin/impress"
  echo "removed the IMPREsS menu entry, icon and $bin/impress"
  exit 0
fi
[ -x "$app/impress" ] || { echo "install-desktop.sh: $app/impress is missing" >&2; exit 1; }
mkdir -p "$(dirname "$desktop")" "$(dirname "$png")" "$(dirname "$svg")" "$bin"
# the menu entry runs this folder's executable by its absolute path
sed -e "s|^Exec=impress |Exec=\"$app/impress\" |" -e "s|^TryExec=impress$|TryExec=$app/impress|" \
  "$app/impress.desktop" > "$desktop"
cp "$app/impress.png" "$png"
cp "$app/impress.svg" "$svg"
ln -sf "$app/impress" "$bin/impress"
command -v update-desktop-database >/dev/null 2>&1 && update-desktop-database -q "$share/applications" || true
command -v gtk-update-icon-cache >/dev/null 2>&1 && gtk-update-icon-cache -q "$share/icons/hicolor" || true
echo "installed: $desktop, the icon, and $bin/impress -> $app/impress"
