#!/usr/bin/env bash
# The test command: make sure .venv exists with the package installed (editable, dev extras), then run
# pytest with any arguments given. Exits with pytest's status; "no tests collected" (5) is a failure too.
# Redis tests use REDIS_URL if set, else start a throwaway redis-server (tests/conftest.py); never skipped.
# The browser test needs Debian's chromium: scripts/install_browser.sh installs it when it is missing.
set -euo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")/.."

VENV=.venv
STAMP="$VENV/.sensedispatch-installed"

find_python() {
    local candidate
    for candidate in "${PYTHON:-}" python3.11 python3; do
        [ -n "$candidate" ] || continue
        if command -v "$candidate" >/dev/null 2>&1 &&
            "$candidate" -c 'import sys; sys.exit(sys.version_info[:2] != (3, 11))' 2>/dev/null; then
            echo "$candidate"
            return 0
        fi
    done
    echo "scripts/test.sh: Python 3.11 not found (tried \$PYTHON, python3.11, python3)" >&2
    return 1
}

if [ ! -x "$VENV/bin/python" ]; then
    python="$(find_python)"
    echo "scripts/test.sh: creating $VENV with $python" >&2
    "$python" -m venv "$VENV"
fi
# (Re)install when never done here or when pyproject.toml changed since.
if [ ! -f "$STAMP" ] || [ pyproject.toml -nt "$STAMP" ]; then
    echo "scripts/test.sh: installing the package into $VENV" >&2
    "$VENV/bin/python" -m pip install --quiet --disable-pip-version-check -e '.[dev,research,cluster]'
    touch "$STAMP"
fi
# Debian's chromium for the dashboard's browser test (installed with apt-get when missing; never skipped).
bash scripts/install_browser.sh

set +e
"$VENV/bin/python" -m pytest -q "$@"
status=$?
set -e
if [ "$status" -eq 5 ]; then
    echo "scripts/test.sh: no tests were collected; treating that as a failure" >&2
    exit 1
fi
exit "$status"
