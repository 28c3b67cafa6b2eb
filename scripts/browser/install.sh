#!/usr/bin/env bash
# Installs what host-sim/tests/browser.rs needs when missing: Debian's Chromium (the
# browsers test tools download themselves are not reachable here) and playwright-core
# from the npm registry, pinned by package-lock.json.
set -euo pipefail
cd "$(dirname "$0")"
if [ ! -x "${CHROMIUM:-/usr/bin/chromium}" ]; then
  echo "browser/install.sh: installing Debian's chromium" >&2
  sudo=""
  [ "$(id -u)" -eq 0 ] || sudo=sudo
  $sudo apt-get update -q >&2
  DEBIAN_FRONTEND=noninteractive $sudo apt-get install -y -q --no-install-recommends chromium >&2
fi
if [ ! -d node_modules/playwright-core ]; then
  npm ci --no-audit --no-fund --loglevel=error >&2
fi
