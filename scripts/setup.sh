#!/usr/bin/env bash
# Bring a fresh Debian bookworm machine with Python 3.11 to a working MIKASA-Robo
# development state: CPU Vulkan (Mesa lavapipe >= 24.3 from bookworm-backports, which
# SAPIEN needs even for state observations) and a virtual environment (.venv) holding
# every package of the monorepo installed editable with its dev/test dependencies.
#
# Idempotent: re-running skips what is already done.
# Usage: scripts/setup.sh            (from anywhere; acts on the repository root)
set -euo pipefail
root=$(cd "$(dirname "$0")/.." && pwd)
cd "$root"
PYTHON=${PYTHON:-python3.11}
VENV=${VENV:-$root/.venv}
SUDO=""; [ "$(id -u)" -eq 0 ] || SUDO="sudo"

# 1. CPU Vulkan. bookworm's own Mesa (22.x) lavapipe crashes SAPIEN; 24.3+ works.
need_vulkan=1
if dpkg-query -W -f='${Version}' mesa-vulkan-drivers 2>/dev/null | grep -qE '^(2[4-9]|[3-9][0-9])\.'; then
  need_vulkan=0
fi
if [ "$need_vulkan" -eq 1 ]; then
  echo "[setup] installing Mesa lavapipe (Vulkan on CPU) from bookworm-backports"
  src=/etc/apt/sources.list.d/bookworm-backports.sources
  if ! grep -rqs bookworm-backports /etc/apt/sources.list /etc/apt/sources.list.d/; then
    # Reuse the mirror URI of the existing Debian source so it works behind local mirrors.
    uri=$(grep -hE '^URIs:' /etc/apt/sources.list.d/debian.sources 2>/dev/null | head -n1 | awk '{print $2}')
    [ -n "$uri" ] || uri=http://deb.debian.org/debian
    printf 'Types: deb\nURIs: %s\nSuites: bookworm-backports\nComponents: main\nSigned-By: /usr/share/keyrings/debian-archive-keyring.gpg\n' "$uri" | $SUDO tee "$src" >/dev/null
  fi
  $SUDO apt-get update -qq
  DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq -t bookworm-backports \
    mesa-vulkan-drivers libvulkan1 >/dev/null
fi

# 2. Headless Chromium (Debian's): the gallery test looks at the page in a real browser.
if ! command -v chromium >/dev/null 2>&1; then
  echo "[setup] installing Chromium (the headless browser of the gallery test)"
  $SUDO apt-get update -qq
  DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq --no-install-recommends chromium >/dev/null
fi

# 3. Virtual environment with every package editable.
if [ ! -x "$VENV/bin/python" ]; then
  echo "[setup] creating $VENV"
  "$PYTHON" -m venv "$VENV"
fi
"$VENV/bin/python" -m pip install -q --upgrade pip
# torch: the CPU build 2.13.0 (pinned in requirements/dev.txt; see README "Dependency pins").
echo "[setup] installing packages (editable) and dev tools"
# (the grep drops pip's report that openpi-client's numpy<2 pin is unmet: see below)
"$VENV/bin/python" -m pip install -q -r requirements/dev.txt \
  2> >(grep -v -e "^openpi-client [0-9.]* requires numpy" \
    -e "^ERROR: pip's dependency resolver does not currently take" >&2)
# openpi's server and client (the interoperability tests), without their numpy<2 pin.
"$VENV/bin/python" -m pip install -q --no-deps -r requirements/openpi.txt
"$VENV/bin/python" -m mikasa_envs.setup_assets
echo "[setup] done: activate with 'source $VENV/bin/activate'"
