#!/usr/bin/env bash
# Build (once) and install the ROS 2 interface packages of interfaces/ into a venv. Idempotent.
#
#   tools/ensure_interfaces.sh [VENV]     VENV: default $VIRTUAL_ENV, else <repo>/.venv
#
# Packages: system_modes_msgs (the system_modes interface), sm_bt_msgs (sm_bt's own services:
# PreviewChange) and py_trees_ros_interfaces (the snapshot streams that py-trees-tree-watcher/-viewer
# read). None is on a package index.
# The venv must already hold the ROS 2 Jazzy runtime (pip install -c constraints.txt -e '.[ros]').
# Paths for each package, fastest first:
#   up to date  (~0.5 s)  the venv's stamp matches the source hash and every type imports and loads
#                         its C typesupport;
#   cached      (~1 s)    $cache/wheels/<package>-<hash>/ holds the wheel: install it (uv, or pip --no-deps);
#   build       (~40 s system_modes_msgs, ~20 s sm_bt_msgs, ~80 s py_trees_ros_interfaces) pip wheel --no-deps
#                         (scikit-build-core + the pinned Jazzy build wheels in pip's isolated build
#                         env; needs gcc/g++ and the package index; cmake comes from PyPI when missing).
# <hash> covers interfaces/<package> (package.xml, CMakeLists.txt, pyproject.toml,
# build-constraints.txt, msg/, srv/, action/), the venv's Python version (the wheel is cp3X-specific)
# and the machine (uname -m). $cache is outside the checkout, as pip keeps its wheels, so that every
# clone on a machine shares the builds: ${SM_BT_CACHE:-${XDG_CACHE_HOME:-~/.cache}/sm_bt}. An empty or
# unwritable cache only costs a build. The build log goes to build/logs/<package>-<hash>.log.
set -euo pipefail

root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
name="interfaces"  # for die() before a package is named
venv="${1:-${VIRTUAL_ENV:-$root/.venv}}"
venv="$(cd "$venv" 2>/dev/null && pwd)" || { echo "interfaces: ERROR: no venv at '${1:-${VIRTUAL_ENV:-$root/.venv}}' (create it first: make .venv/.installed)" >&2; exit 2; }
py="$venv/bin/python"
# Built wheels, shared by every clone on this machine; a cache that cannot be written falls back to
# build/wheels/ in the checkout.
wheels="${SM_BT_CACHE:-${XDG_CACHE_HOME:-$HOME/.cache}/sm_bt}/wheels"
if ! mkdir -p "$wheels" 2>/dev/null || [[ ! -w "$wheels" ]]; then
  wheels="$root/build/wheels"
fi
rel() { echo "${1#"$root"/}"; }

# A built wheel into the venv: with the venv's uv where tools/install_packages.sh put one (0.3 s
# against pip's 3 s of CPU each), byte-compiled as the other packages are; with pip where there is
# no uv, or it fails.
install_wheel() {
  if [[ -x $venv/bin/uv ]] && "$venv/bin/uv" pip install --quiet --python "$py" --no-deps --offline --reinstall \
      --compile-bytecode --link-mode=hardlink "$1"; then
    return 0
  fi
  "$py" -m pip install --no-deps --no-index --force-reinstall --disable-pip-version-check -q "$1"
}

# While a build runs, a line every 10 s: the time so far and the step the log shows (pip's phase,
# then CMake's [done/total] build steps), so that a minute-long build shows it is alive.
show_progress() {
  local pid=$1 log=$2 start=$3 next=$((SECONDS + 10)) step
  while kill -0 "$pid" 2>/dev/null; do
    sleep 1
    if ((SECONDS >= next)) && kill -0 "$pid" 2>/dev/null; then
      next=$((SECONDS + 10))
      step="$(grep -a -o -E "Installing build dependencies|Getting requirements to build wheel|Preparing metadata|Building wheel|-- Configuring|\[[0-9]+/[0-9]+\]" "$log" 2>/dev/null | tail -1 || true)"
      if [[ $step =~ ^\[([0-9]+)/([0-9]+)\]$ ]]; then step="compiling, step ${BASH_REMATCH[1]} of ${BASH_REMATCH[2]}"; fi
      echo "$name: ... $((SECONDS - start)) s${step:+: $step}"
    fi
  done
}

die() {  # die <what failed> <details...>
  {
    echo
    echo "$name: ERROR: $1"
    shift
    for line in "$@"; do echo "  $line"; done
    echo
  } >&2
  exit 1
}

[[ -x "$py" ]] || die "no Python at $py" "Create the venv first: make .venv/.installed"

ensure() {  # ensure <package>: the package in interfaces/<package>, built and installed
  local name="$1"
  local pkg="$root/interfaces/$name"
  local stamp="$venv/.$name.stamp"
  local wheel="ros_$(echo "$name" | tr - _)"
  local expect=40
  [[ "$name" == py_trees_ros_interfaces ]] && expect=90
  local hash cache whl built log tmp start out err first rclpy_err f l
  local -a sources missing causes
  # --- source hash (cheap: no Python start) ------------------------------------------------------
  pyver="$(cd "$venv/lib" && ls -d python3.* 2>/dev/null | head -1)"
  [[ -n "$pyver" ]] || die "cannot tell the Python version of $venv (no lib/python3.*)" "Recreate the venv: make clean && make .venv/.installed"
  cd "$pkg"
  shopt -s nullglob
  sources=(package.xml CMakeLists.txt pyproject.toml build-constraints.txt msg/*.msg srv/*.srv action/*.action)
  shopt -u nullglob
  for f in package.xml CMakeLists.txt pyproject.toml build-constraints.txt; do
    [[ -f "$f" ]] || die "$(rel "$pkg")/$f is missing"
  done
  hash="$(
    { echo "$pyver $(uname -m)"; for f in "${sources[@]}"; do printf '%s\0' "$f"; cat "$f"; printf '\0'; done; } \
      | sha256sum | cut -c1-16
  )"
  cd "$root"

  check() {  # every type imports and loads its C typesupport (a plain import loads no .so)
    "$py" - "$name" "$pkg" <<'PY'
import importlib, pathlib, sys
name, pkg = sys.argv[1], pathlib.Path(sys.argv[2])
for kind in ("msg", "srv", "action"):
    for source in sorted((pkg / kind).glob(f"*.{kind}")):
        t = getattr(importlib.import_module(f"{name}.{kind}"), source.stem)
        t.__class__.__import_type_support__()
        assert t._TYPE_SUPPORT is not None, t
PY
  }

  # --- fast path ---------------------------------------------------------------------------------
  if [[ -f "$stamp" && "$(cat "$stamp")" == "$hash" ]] && check 2>/dev/null; then
    echo "$name: up to date ($hash)"
    return 0
  fi

  # Serialise concurrent runs (two `make` in parallel) on the wheel cache; re-check under the lock.
  mkdir -p "$wheels" "$root/build/logs"
  if command -v flock >/dev/null 2>&1; then
    exec 9>"$wheels/.lock-$name"
    flock 9
    if [[ -f "$stamp" && "$(cat "$stamp")" == "$hash" ]] && check 2>/dev/null; then
      echo "$name: up to date ($hash)"
      return 0
    fi
  fi

  # The runtime the wheel installs next to (and links against) must be there.
  if ! rclpy_err="$("$py" -c 'import rclpy, rosidl_generator_py' 2>&1)"; then
    die "the ROS 2 Jazzy runtime is missing or broken in $venv (import rclpy failed):" \
        "$(echo "$rclpy_err" | tail -1)" \
        "Install it first: $venv/bin/python -m pip install -c constraints.txt -e '.[test,ros]'" \
        "(make .venv/.installed does this)."
  fi

  cache="$wheels/$name-$hash"
  whl="$(ls "$cache"/$wheel-*.whl 2>/dev/null | head -1 || true)"

  # --- build path --------------------------------------------------------------------------------
  if [[ -z "$whl" ]]; then
    # Tools first: a failure deep inside pip/CMake is much harder to read.
    missing=()
    command -v cc >/dev/null 2>&1 || command -v gcc >/dev/null 2>&1 || missing+=("a C compiler (gcc)")
    command -v c++ >/dev/null 2>&1 || command -v g++ >/dev/null 2>&1 || missing+=("a C++ compiler (g++)")
    # cmake >= 3.20 and ninja need not be installed: scikit-build-core then takes them from PyPI
    # (pinned in build-constraints.txt). Verified with no usable cmake on PATH.
    if ((${#missing[@]})); then
      die "cannot build the $name wheel: missing build tools:" \
          "${missing[@]/#/- }" \
          "Install them (Debian/Ubuntu: sudo apt-get install build-essential), then re-run: make .venv/.installed"
    fi

    log="$root/build/logs/$name-$hash.log"
    tmp="$wheels/.tmp-$name-$hash-$$"
    rm -rf "$tmp"; mkdir -p "$tmp"
    echo "$name: building the wheel ($hash, ~$expect s on 2 cores; log: $(rel "$log")) ..."
    start=$SECONDS
    # Clean build environment: a sourced ROS install (/opt/ros/...) must not leak into the build.
    # PIP_CONSTRAINT reaches pip's isolated build env and pins its transitive dependencies.
    env -u AMENT_PREFIX_PATH -u CMAKE_PREFIX_PATH -u COLCON_PREFIX_PATH -u PYTHONPATH \
      PIP_CONSTRAINT="$pkg/build-constraints.txt" \
      CMAKE_BUILD_PARALLEL_LEVEL="${CMAKE_BUILD_PARALLEL_LEVEL:-$(nproc 2>/dev/null || echo 2)}" \
      "$py" -m pip wheel --no-deps --progress-bar off --disable-pip-version-check -v \
        -w "$tmp" "$pkg" >"$log" 2>&1 &
    builder=$!
    show_progress "$builder" "$log" "$start"
    if wait "$builder"; then
      built="$(ls "$tmp"/$wheel-*.whl 2>/dev/null | head -1 || true)"
    else
      built=""
    fi
    if [[ -z "$built" ]]; then
      rm -rf "$tmp"
      causes=()
      if grep -q -E "Installing build dependencies: finished with status 'error'|No matching distribution found" "$log"; then
        causes+=("- the pinned build wheels could not be installed into pip's isolated build env: the package index"
                 "  is unreachable (pip config / PIP_INDEX_URL), or a pin in $(rel "$pkg")/pyproject.toml"
                 "  [build-system] requires or build-constraints.txt is not on it, or two pins conflict.")
        first="$(grep -m1 -E "ERROR:|No matching distribution|Could not find a version" "$log" || true)"
        if [[ -n "$first" ]]; then causes+=("  First error: ${first#"${first%%[![:space:]]*}"}"); fi
      elif grep -q -E "^ *Error processing '" "$log"; then
        causes+=("- a .msg/.srv definition in $(rel "$pkg") does not parse (rosidl_adapter):")
        while IFS= read -r l; do causes+=("    ${l#"${l%%[![:space:]]*}"}"); done \
          < <(grep -m1 -A2 -E "^ *Error processing '" "$log" | grep -v -E "^ *$" || true)
      elif grep -q -E "CMake Error" "$log"; then
        causes+=("- CMake failed: an error in $(rel "$pkg") (CMakeLists.txt, package.xml, msg/, srv/),"
                 "  a missing build wheel (\"Could not find a package configuration file provided by X\":"
                 "  add the ros-X wheel, pinned, to [build-system] requires), or a broken compiler / cmake.")
        causes+=("  First CMake error:")
        while IFS= read -r l; do causes+=("    ${l#  }"); done < <(grep -m1 -A6 -E "CMake Error" "$log" || true)
      fi
      if ((${#causes[@]} == 0)); then
        causes+=("- unknown: read the log. Usual causes: no gcc/g++ or cmake >= 3.20, a build wheel missing"
                 "  from the index, or an error in $(rel "$pkg").")
      fi
      {
        echo
        echo "---- last 40 lines of $(rel "$log") ----"
        tail -n 40 "$log"
        echo "---- end of log tail ----"
      } >&2
      die "building the $name wheel failed after $((SECONDS - start)) s (pip wheel --no-deps $(rel "$pkg"))." \
          "Likely cause:" "${causes[@]}" \
          "Full log: $log" \
          "Fix it, then re-run: make .venv/.installed  (or: tools/ensure_$name.sh $venv)"
    fi
    rm -rf "$cache"; mkdir -p "$cache"
    mv "$built" "$cache/"
    rm -rf "$tmp"
    whl="$cache/$(basename "$built")"
    echo "$name: built $(rel "$whl") in $((SECONDS - start)) s"
  fi

  # --- install -----------------------------------------------------------------------------------
  rm -f "$stamp"
  if ! out="$(install_wheel "$whl" 2>&1)"; then
    echo "$out" >&2
    die "installing $(rel "$whl") into $venv failed (output above)." \
        "If the wheel is damaged, delete $(rel "$cache") and re-run."
  fi
  if ! err="$(check 2>&1)"; then
    echo "$err" >&2
    die "installed $(rel "$whl"), but the import/typesupport check failed (output above)." \
        "Likely cause: the venv's ROS runtime does not match the Jazzy pins (check: $py -m pip check)," \
        "or a stale wheel: delete $(rel "$cache") and re-run."
  fi
  echo "$hash" >"$stamp"
  echo "$name: installed $(rel "$whl") into $venv"
}

# All at once: a cold build is mostly pip setting up its build env and CMake's single-threaded steps,
# so the two overlap well on two cores. Each runs in a subshell of its own (its lock, its exit status).
pids=()
for package in system_modes_msgs sm_bt_msgs py_trees_ros_interfaces; do
  ensure "$package" &
  pids+=($!)
done
status=0
for pid in "${pids[@]}"; do
  wait "$pid" || status=1
done
exit "$status"
