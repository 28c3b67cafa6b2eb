#!/usr/bin/env bash
# Installs what host-sim/tests/browser.rs needs when missing: Debian's Chromium (the
# browsers test tools download themselves are not reachable here), Node.js 20 or later
# with npm, and playwright-core from the npm registry, pinned by package-lock.json.
set -euo pipefail
cd "$(dirname "$0")"
chromium="${CHROMIUM:-/usr/bin/chromium}"
packages=()
[ -x "$chromium" ] || packages+=(chromium)
command -v node >/dev/null && command -v npm >/dev/null || packages+=(nodejs npm)
if [ ${#packages[@]} -gt 0 ]; then
  echo "browser/install.sh: installing ${packages[*]} (Debian)" >&2
  sudo=""
  [ "$(id -u)" -eq 0 ] || sudo=sudo
  $sudo apt-get update -q >&2
  DEBIAN_FRONTEND=noninteractive $sudo apt-get install -y -q --no-install-recommends "${packages[@]}" >&2
fi
[ -x "$chromium" ] || { echo "browser/install.sh: $chromium still missing (CHROMIUM names a browser that is not there?)" >&2; exit 1; }
major=$(node --version | sed 's/^v\([0-9]*\).*/\1/')
if [ "$major" -lt 20 ]; then
  echo "browser/install.sh: playwright-core needs Node.js 20 or later; this machine has $(node --version)" >&2
  exit 1
fi
if [ ! -d node_modules/playwright-core ]; then
  npm ci --no-audit --no-fund --loglevel=error >&2
fi
