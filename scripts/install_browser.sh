#!/usr/bin/env bash
# Debian's Chromium for the dashboard's browser test (tests/e2e/test_dashboard_browser.py drives it with
# Playwright for Python; no browser is ever downloaded by a test tool). Installs with apt-get when
# /usr/bin/chromium is missing; needs root (CI runs as root) or passwordless sudo. Idempotent.
set -euo pipefail

CHROMIUM=/usr/bin/chromium
if [ -x "$CHROMIUM" ]; then
    exit 0
fi
if [ "$(id -u)" -eq 0 ]; then
    as_root=()
elif command -v sudo >/dev/null 2>&1 && sudo -n true 2>/dev/null; then
    as_root=(sudo -n)
else
    echo "scripts/install_browser.sh: $CHROMIUM is missing and installing it needs root:" \
        "run 'apt-get install chromium' as root" >&2
    exit 1
fi
echo "scripts/install_browser.sh: installing Debian's chromium" >&2
export DEBIAN_FRONTEND=noninteractive
"${as_root[@]}" apt-get update -q
"${as_root[@]}" apt-get install -y -q --no-install-recommends chromium
"$CHROMIUM" --version
