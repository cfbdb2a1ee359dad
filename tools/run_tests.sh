#!/usr/bin/env bash
# What `make test` runs: the environment (Chromium installed meanwhile), the suite in parallel
# workers, then ruff and mypy, then the documentation's build (warnings are errors); at the end,
# the wall time of each step, whatever the outcome.
#
#   tools/run_tests.sh [PYTEST ARGS...]     (from the Makefile: MAKE, VENV, STAMP, PYTEST_WORKERS)
#
# Most of the suite's time is ROS tests waiting on other processes, so it runs in more workers
# than there are cores (pytest-xdist; each worker has a ROS domain of its own, see tests/conftest.py).
# Modules whose tests share a costly fixture (a recorded demo) run whole in one worker (tests/conftest.py).
set -euo pipefail
cd "$(dirname "$0")/.."

make="${MAKE:-make}"
venv="${VENV:-.venv}"
stamp="${STAMP:-$venv/.installed}"
workers="${PYTEST_WORKERS:-4}"
start=$SECONDS
declare -A took=([environment]=0 [tests]=0 [lint]=0 [docs]=0)
step="environment" since=$SECONDS

next_step() {  # next_step NAME: the step so far took its time
  took[$step]=$((SECONDS - since))
  step="$1" since=$SECONDS
}

report() {
  local status=$?
  local failed=""
  [[ $status == 0 ]] || failed="; failed in the $step step"
  took[$step]=$((SECONDS - since))
  echo "make test: $((SECONDS - start)) s of wall time (environment ${took[environment]} s," \
       "tests ${took[tests]} s, lint ${took[lint]} s, docs ${took[docs]} s)$failed"
}
trap report EXIT

mkdir -p build/logs
# Chromium (for the view's browser tests) comes from apt while pip fills the venv.
bash tools/ensure_chromium.sh >build/logs/chromium.log 2>&1 &
chromium=$!
"$make" --no-print-directory "$stamp"
if ! wait "$chromium"; then
  cat build/logs/chromium.log >&2
  exit 1
fi
cat build/logs/chromium.log

next_step tests
# Everything must run here: a test whose requirement (ROS, Chromium, root) is missing fails, not skips.
# A hung test fails on its own (pytest-timeout, pyproject.toml); should the run itself hang (a worker
# blocked where no signal reaches it), it is interrupted after 15 minutes rather than running into
# CI's limit with nothing said.
SM_BT_TESTS_NEED_ALL=1 timeout --signal=INT --kill-after=30 900 \
  "$venv/bin/python" -m pytest -q -n "$workers" --durations=10 "$@"

next_step lint
"$make" --no-print-directory lint

next_step docs
"$make" --no-print-directory docs
