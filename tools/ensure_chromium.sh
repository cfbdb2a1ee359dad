#!/usr/bin/env bash
# Make sure a headless Chromium is there for the browser tests of the web view (Debian's
# `chromium` package). Idempotent: does nothing when `chromium` is on PATH.
set -euo pipefail
if command -v chromium >/dev/null 2>&1; then
  exit 0
fi
if ! command -v apt-get >/dev/null 2>&1; then
  echo "chromium: not found and no apt-get here: install Chromium (a 'chromium' on PATH) for the view's browser tests" >&2
  exit 1
fi
sudo=""
if [[ "$(id -u)" != 0 ]]; then
  command -v sudo >/dev/null 2>&1 || { echo "chromium: not found; installing it needs root (apt-get install chromium)" >&2; exit 1; }
  sudo="sudo"
fi
echo "chromium: installing Debian's chromium for the view's browser tests (about a minute) ..."
start=$SECONDS
$sudo apt-get update -qq
DEBIAN_FRONTEND=noninteractive $sudo apt-get install -y -qq chromium >/dev/null
echo "chromium: installed in $((SECONDS - start)) s ($(chromium --version 2>/dev/null || echo '?'))"
