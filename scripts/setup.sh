#!/usr/bin/env bash
# Create or update .venv from the locked requirements; safe to run again.
#   scripts/setup.sh          what the main job needs
#   scripts/setup.sh --test   also the test and lint tools
set -euo pipefail
cd "$(dirname "$0")/.."

lock=requirements.lock
if [ "${1:-}" = "--test" ]; then
  lock=requirements-dev.lock
fi

python=${PYTHON:-python3}
if [ ! -x .venv/bin/python ]; then
  "$python" -m venv .venv
fi
.venv/bin/python -m pip install --quiet --disable-pip-version-check -r "$lock"
.venv/bin/python -m pip install --quiet --disable-pip-version-check --no-deps -e .
