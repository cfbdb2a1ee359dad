#!/usr/bin/env bash
# What `make test` runs: the environment (Chromium installed meanwhile), then the suite in parallel
# workers, and alongside it ruff, mypy and the documentation's build (warnings are errors): the
# suite leaves a core idle now and then, its ROS tests waiting on other processes. At the end, the
# wall time of each step, whatever the outcome.
#
#   tools/run_tests.sh [PYTEST ARGS...]     (from the Makefile: MAKE, VENV, STAMP, PYTEST_WORKERS)
#
# Much of the suite's time is ROS tests waiting on other processes, so it runs in more workers
# than there are cores (pytest-xdist; each worker has a ROS domain of its own, see tests/conftest.py).
# Modules whose tests share a costly fixture (a recorded demo) run whole in one worker (tests/conftest.py).
set -euo pipefail
cd "$(dirname "$0")/.."

make="${MAKE:-make}"
venv="${VENV:-.venv}"
stamp="${STAMP:-$venv/.installed}"
workers="${PYTEST_WORKERS:-5}"
start=$SECONDS
declare -A took=([environment]=0 [tests]=0 [lint]=0 [docs]=0)
step="environment" since=$SECONDS
checks=""  # the pid of lint and docs, run alongside the tests

next_step() {  # next_step NAME: the step so far took its time
  took[$step]=$((SECONDS - since))
  step="$1" since=$SECONDS
}

report() {
  local status=$?
  local failed=""
  if [[ -n $checks ]]; then  # interrupted while lint or docs ran
    pkill -P "$checks" 2>/dev/null || true
    kill "$checks" 2>/dev/null || true
  fi
  [[ $status == 0 ]] || failed="; failed in the $step step"
  [[ $step == environment ]] && took[$step]=$((SECONDS - since))
  [[ -f build/logs/lint.took ]] && took[lint]=$(<build/logs/lint.took)
  [[ -f build/logs/docs.took ]] && took[docs]=$(<build/logs/docs.took)
  echo "make test: $((SECONDS - start)) s of wall time (environment ${took[environment]} s," \
       "tests ${took[tests]} s, lint ${took[lint]} s and docs ${took[docs]} s alongside them)$failed"
}
trap report EXIT

mkdir -p build/logs
rm -f build/logs/lint.took build/logs/docs.took build/logs/lint.log build/logs/docs.log
# Chromium (for the view's browser tests) comes from apt while pip fills the venv.
bash tools/ensure_chromium.sh >build/logs/chromium.log 2>&1 &
chromium=$!
"$make" --no-print-directory "$stamp"
if ! wait "$chromium"; then
  cat build/logs/chromium.log >&2
  exit 1
fi
cat build/logs/chromium.log

# Lint, then the documentation's build, in the background; their output is printed after the tests.
run_checks() {
  local begun=$SECONDS
  "$make" --no-print-directory lint >build/logs/lint.log 2>&1 || { echo "lint failed" >>build/logs/lint.log; return 1; }
  echo $((SECONDS - begun)) >build/logs/lint.took
  begun=$SECONDS
  "$make" --no-print-directory docs >build/logs/docs.log 2>&1 || { echo "docs failed" >>build/logs/docs.log; return 2; }
  echo $((SECONDS - begun)) >build/logs/docs.took
}
run_checks &
checks=$!

next_step tests
# Collected first by one process that may write bytecode, so that pytest keeps its rewritten test
# modules and every worker reads them: where PYTHONDONTWRITEBYTECODE=1 is set (CI machines) none would
# be kept, and each worker would rewrite them all (about 8 s of CPU each instead of 3).
env -u PYTHONDONTWRITEBYTECODE "$venv/bin/python" -m pytest --collect-only -q -p no:cacheprovider "$@" \
  >build/logs/collect.log 2>&1 || true  # a collection error is the run's to report
# Everything must run here: a test whose requirement (ROS, Chromium, root) is missing fails, not skips.
# A hung test fails on its own (pytest-timeout, pyproject.toml); should the run itself hang (a worker
# blocked where no signal reaches it), it is interrupted after 15 minutes rather than running into
# CI's limit with nothing said.
tests_status=0
SM_BT_TESTS_NEED_ALL=1 timeout --signal=INT --kill-after=30 900 \
  "$venv/bin/python" -m pytest -q -n "$workers" --durations=10 "$@" || tests_status=$?
took[tests]=$((SECONDS - since))

checks_status=0
wait "$checks" || checks_status=$?
checks=""
cat build/logs/lint.log
[[ ! -f build/logs/docs.log ]] || cat build/logs/docs.log  # not built when lint failed
if ((tests_status != 0)); then
  step=tests
  exit "$tests_status"
fi
if ((checks_status != 0)); then
  step=$([[ $checks_status == 1 ]] && echo lint || echo docs)
  exit "$checks_status"
fi
step=done
