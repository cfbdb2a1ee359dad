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

# uv's pinned binary, kept outside the checkout as the interface wheels are (tools/ensure_interfaces.sh):
# the next venv of this machine copies it instead of asking pip (3 s).
uv_pin="$(grep -m1 '^uv==' constraints.txt)"
uv_kept="${SM_BT_CACHE:-${XDG_CACHE_HOME:-$HOME/.cache}/sm_bt}/tools/${uv_pin/==/-}/uv"

uv_installed() {  # uv in the venv: kept from an earlier venv, else from its own pip or the base Python's
  [[ -x $venv/bin/uv ]] && return 0
  if [[ -x $uv_kept ]] && cp "$uv_kept" "$venv/bin/uv" 2>/dev/null && "$venv/bin/uv" --version >/dev/null 2>&1; then
    return 0
  fi
  if has_pip; then
    "$py" -m pip install "${quiet[@]}" -c constraints.txt uv
  else
    local base
    base="$("$py" -c 'import sys; print(sys._base_executable)')"
    "$base" -m pip --python "$py" install "${quiet[@]}" -c constraints.txt uv 2>/dev/null \
      || { "$py" -m ensurepip --default-pip >/dev/null && "$py" -m pip install "${quiet[@]}" -c constraints.txt uv; }
  fi
  # Kept for the next venv (an unwritable cache only costs the next one these 3 s).
  { mkdir -p "${uv_kept%/uv}" && cp "$venv/bin/uv" "$uv_kept.$$" && mv "$uv_kept.$$" "$uv_kept"; } 2>/dev/null || true
}

uv=("$venv/bin/uv" pip install --quiet --python "$py" --link-mode=hardlink -c constraints.txt)
# pip is a tool here, not imported by what runs: not byte-compiled (500 modules)
if uv_installed && "${uv[@]}" --compile-bytecode -e ".[$extras]" && "${uv[@]}" pip; then
  exit 0
fi
echo "sm_bt: uv could not install the packages (above); pip installs them instead (about a minute)" >&2
has_pip || "$py" -m ensurepip --default-pip >/dev/null
"$py" -m pip install "${quiet[@]}" -c constraints.txt -e ".[$extras]"
