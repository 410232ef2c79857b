#!/usr/bin/env bash
# Idempotent set-up on Debian 12: install what is missing (QGIS, GDAL, scipy from Debian's
# packages; pytest, laspy and ruff into a venv that sees them), link the plugin under its own name
# in .build/plugins, and enable it for qgis_process. Safe to run any number of times.
#   scripts/setup.sh          system packages + plugin link + enable
#   scripts/setup.sh --venv   also the test venv (.venv with pytest, laspy, lazrs, ruff)
set -euo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
PY=/usr/bin/python3
PKGS="qgis python3-qgis qgis-providers gdal-bin python3-gdal python3-scipy python3-numpy python3-venv python3-pip zip"

missing=""
for p in $PKGS; do
  dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing="$missing $p"
done
if [ -n "$missing" ]; then
  echo "Installing Debian packages:$missing"
  SUDO=""
  if [ "$(id -u)" != 0 ]; then
    command -v sudo >/dev/null || { echo "Need root (or sudo) to install:$missing" >&2; exit 1; }
    SUDO=sudo
  fi
  $SUDO apt-get update -qq
  DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq --no-install-recommends $missing
fi
$PY -c "import qgis.core, osgeo.gdal, scipy, numpy" || { echo "QGIS/GDAL/scipy Python modules do not import in $PY" >&2; exit 1; }

# The plugin under its own name, whatever the clone's folder is called.
mkdir -p "$ROOT/.build/plugins"
ln -sfn ../.. "$ROOT/.build/plugins/bare_earth"

export QT_QPA_PLATFORM=offscreen QGIS_PLUGINPATH="$ROOT/.build/plugins"
export XDG_RUNTIME_DIR="${XDG_RUNTIME_DIR:-/tmp/runtime-$(id -u)}"
mkdir -p "$XDG_RUNTIME_DIR" && chmod 700 "$XDG_RUNTIME_DIR"
if ! qgis_process.bin plugins 2>/dev/null | grep -q '^\* bare_earth'; then
  qgis_process.bin plugins enable bare_earth >/dev/null 2>&1 || true
fi
qgis_process.bin plugins 2>/dev/null | grep -q '^\* bare_earth' || {
  echo "Could not enable the bare_earth plugin for qgis_process" >&2; exit 1; }

if [ "${1:-}" = "--venv" ]; then
  if [ ! -x "$ROOT/.venv/bin/python" ]; then
    $PY -m venv --system-site-packages "$ROOT/.venv"
  fi
  { "$ROOT/.venv/bin/python" -c "import pytest, laspy, lazrs" 2>/dev/null && [ -x "$ROOT/.venv/bin/ruff" ]; } || \
    "$ROOT/.venv/bin/python" -m pip install -q --disable-pip-version-check "pytest>=7" "laspy>=2" lazrs "ruff>=0.4"
fi
echo "Set-up OK: plugin linked at .build/plugins/bare_earth and enabled for qgis_process."
