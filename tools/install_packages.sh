#!/usr/bin/env bash
# Install the pinned packages (constraints.txt) into a venv that has pip:
#
#   tools/install_packages.sh VENV EXTRAS        e.g. tools/install_packages.sh .venv test,ros,docs
#
# With uv (pinned in constraints.txt, installed by pip first): it downloads in parallel and
# byte-compiles on every core, about 20 s where pip takes about 70 s (docs/getting-started.md).
# Byte-compiled at install either way: where PYTHONDONTWRITEBYTECODE=1 is set, nothing compiled
# later is kept, and every process would compile its imports again. Where uv cannot install (an
# index that only pip is configured for), pip does it, after saying so.
set -euo pipefail
cd "$(dirname "$0")/.."
venv="$1"
extras="$2"
py="$venv/bin/python"
pip=("$py" -m pip install --quiet --disable-pip-version-check)
if "${pip[@]}" -c constraints.txt uv \
    && "$venv/bin/uv" pip install --quiet --python "$py" --compile-bytecode --link-mode=copy \
         -c constraints.txt -e ".[$extras]"; then
  exit 0
fi
echo "sm_bt: uv could not install the packages (above); pip installs them instead (about a minute)" >&2
"${pip[@]}" -c constraints.txt -e ".[$extras]"
