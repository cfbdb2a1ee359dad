#!/usr/bin/env bash
# Install the pinned packages (constraints.txt) into a venv:
#
#   tools/install_packages.sh VENV EXTRAS        e.g. tools/install_packages.sh .venv test,ros,docs
#
# With uv (pinned in constraints.txt): it downloads in parallel and byte-compiles on every core,
# about 20 s where pip takes about 70 s (docs/getting-started.md). The Makefile makes the venv
# without pip (ensurepip alone takes 5-7 s): uv comes from the base Python's pip, which installs
# into another environment (pip >= 22.3), and pip itself from uv (pinned: tools/ensure_interfaces.sh
# builds with it). Where the base Python has no such pip, ensurepip puts one in the venv first.
# Byte-compiled at install either way: where PYTHONDONTWRITEBYTECODE=1 is set, nothing compiled
# later is kept, and every process would compile its imports again. Where uv cannot install (an
# index that only pip is configured for), pip does it, after saying so.
set -euo pipefail
cd "$(dirname "$0")/.."
venv="$1"
extras="$2"
py="$venv/bin/python"
quiet=(--quiet --disable-pip-version-check)

has_pip() { "$py" -m pip --version >/dev/null 2>&1; }

uv_installed() {  # uv in the venv, from its own pip or else from the base Python's
  [[ -x $venv/bin/uv ]] && return 0
  if has_pip; then
    "$py" -m pip install "${quiet[@]}" -c constraints.txt uv
  else
    local base
    base="$("$py" -c 'import sys; print(sys._base_executable)')"
    "$base" -m pip --python "$py" install "${quiet[@]}" -c constraints.txt uv 2>/dev/null \
      || { "$py" -m ensurepip --default-pip >/dev/null && "$py" -m pip install "${quiet[@]}" -c constraints.txt uv; }
  fi
}

uv=("$venv/bin/uv" pip install --quiet --python "$py" --link-mode=hardlink -c constraints.txt)
# pip is a tool here, not imported by what runs: not byte-compiled (500 modules)
if uv_installed && "${uv[@]}" --compile-bytecode -e ".[$extras]" && "${uv[@]}" pip; then
  exit 0
fi
echo "sm_bt: uv could not install the packages (above); pip installs them instead (about a minute)" >&2
has_pip || "$py" -m ensurepip --default-pip >/dev/null
"$py" -m pip install "${quiet[@]}" -c constraints.txt -e ".[$extras]"
