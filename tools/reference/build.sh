#!/usr/bin/env bash
# Build the reference mode manager (micro-ROS/system_modes 0.9.0, C++, with rclcpp built from source)
# against the same pinned ROS 2 Jazzy wheels as sm_bt, once per source hash. Used by `make interop`.
#
#   tools/reference/build.sh        progress on stderr; on stdout the prefix of the build, whose
#                                   bin/mode_manager runs the reference's manager in its environment
#
# About 10 minutes on a quiet 2-core machine (rclcpp is most of it); later runs reuse the cache:
# ${SM_BT_CACHE:-${XDG_CACHE_HOME:-~/.cache}/sm_bt}/reference/<hash>, where <hash> covers this script,
# fix_wheel_targets.cmake, the pinned wheels, the source commits, the Python version and the machine.
# Sources are the commits below, cloned from GitHub, or from SM_BT_GIT_MIRRORS: a folder of git
# mirrors, one per repository, as <owner>+<name>/repo, <owner>/<name>.git or <owner>/<name>.
# Needs gcc/g++, git, a Python built with --enable-shared (libpython3.X.so) and the package index.
# JOBS (default: the number of cores) sets the compile jobs. Logs: <prefix>/logs/<step>.log.
set -euo pipefail

here="$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)"
root="$(cd "$here/../.." && pwd)"
python="${PYTHON:-python3}"
jobs="${JOBS:-$(nproc)}"
# The wheels' own pins: the build tools (ament, rosidl, cmake, ninja) and the runtime (rcl, rmw, ...),
# the same file that pins the build of sm_bt's own system_modes_msgs.
pins="$root/interfaces/system_modes_msgs/build-constraints.txt"
hook="$here/fix_wheel_targets.cmake"

# name, repository, commit, package folders in build order. Commits as of the reference's last
# release line for Jazzy: rclcpp 28.1.6, statistics_msgs 2.0.2, libstatistics_collector 1.7.3,
# system_modes 0.9.0 (master; the repository is no longer maintained).
sources=(
  "rcl_interfaces ros2/rcl_interfaces 003987ecb81a32802ab27dd6d325b8c6b8b813cc"
  "libstatistics_collector ros-tooling/libstatistics_collector df4e05887517486ce8325a58d39fc25a5caa3000"
  "rclcpp ros2/rclcpp 985e320de3a3549d5bc674876c79a5531bf301c2"
  "system_modes micro-ROS/system_modes b8679e9781914c6bdb533750bbe7183d7661f63a"
)

# shellcheck source=../git_sources.sh
source "$here/../git_sources.sh"

say() { echo "reference: $*" >&2; }
die() {
  echo >&2
  echo "reference: ERROR: $1" >&2
  shift
  for line in "$@"; do echo "  $line" >&2; done
  exit 1
}

command -v git >/dev/null || die "git is not installed" "Install it (apt-get install git) and run again."
command -v g++ >/dev/null || die "g++ is not installed" "Install it (apt-get install g++) and run again."
libdir="$("$python" -c 'import sysconfig; print(sysconfig.get_config_var("LIBDIR"))')"
ldlib="$("$python" -c 'import sysconfig; print(sysconfig.get_config_var("LDLIBRARY"))')"
pyver="$("$python" -c 'import sys; print(f"{sys.version_info[0]}.{sys.version_info[1]}")')"
[[ "$ldlib" == *.so* && -e "$libdir/$ldlib" ]] ||
  die "$python has no shared libpython ($libdir/$ldlib)" \
    "The wheels' rcl libraries need Python's symbols, so the C++ executables link libpython." \
    "Use a Python built with --enable-shared (PYTHON=/path/to/python3 $0)."

cache="${SM_BT_CACHE:-${XDG_CACHE_HOME:-$HOME/.cache}/sm_bt}/reference"
hash="$( { cat "$0" "$hook" "$pins"; printf '%s\n' "${sources[@]}" "$pyver" "$(uname -m)"; } |
  sha256sum | cut -c1-16)"
prefix="$cache/$hash"
if [[ -f "$prefix/.complete" ]]; then
  echo "$prefix"
  exit 0
fi
mkdir -p "$cache"
exec 9>"$cache/.lock"
if ! flock -n 9; then
  say "another build is running; waiting for it"
  flock 9
fi
if [[ -f "$prefix/.complete" ]]; then
  echo "$prefix"
  exit 0
fi
# Paths are written into the installed files (rpath, CMake exports), so the build happens in place;
# a build that did not complete is started again.
rm -rf "$prefix"
mkdir -p "$prefix/logs" "$prefix/src" "$prefix/build"
venv="$prefix/venv" install="$prefix/install"
start=$SECONDS
say "building micro-ROS/system_modes and rclcpp into $prefix (about 10 minutes; logs in $prefix/logs)"

run_step() {  # run_step <name> <command...>: the command's output goes to logs/<name>.log
  local name="$1" t0=$SECONDS
  shift
  # In the background, not in the if: bash ignores `set -e` inside a condition.
  ("$@") >"$prefix/logs/$name.log" 2>&1 &
  if ! wait $!; then
    tail -n 25 "$prefix/logs/$name.log" >&2
    die "step '$name' failed after $((SECONDS - t0)) s" "Its whole log: $prefix/logs/$name.log"
  fi
  say "$name: $((SECONDS - t0)) s"
}

make_venv() {
  "$python" -m venv "$venv"
  "$venv/bin/python" -m pip install --disable-pip-version-check -r "$pins"
}

get_sources() {
  local entry name repo commit
  for entry in "${sources[@]}"; do
    read -r name repo commit <<<"$entry"
    fetch_commit "$repo" "$commit" "$prefix/src/$name"
  done
}

# The build and run environment: the wheels install their share/, lib/ and include/ at the venv's
# prefix, so the venv is a ROS prefix; their vendored libraries (tinyxml2, OpenSSL 1.1, yaml, spdlog,
# lttng) live in site-packages/ros_*.libs, which the linker and the executables both need to find.
set_env() {
  local libs
  libs="$(find "$venv/lib/python$pyver/site-packages" -maxdepth 1 -type d -name 'ros_*.libs' | sort | paste -sd:)"
  export PATH="$venv/bin:$PATH"
  export CMAKE_PREFIX_PATH="$install:$venv" AMENT_PREFIX_PATH="$install:$venv"
  export LD_LIBRARY_PATH="$install/lib:$venv/lib${libs:+:$libs}"
  export RMW_IMPLEMENTATION=rmw_fastrtps_cpp
}

cmake_package() {  # cmake_package <source folder> <jobs> [cmake args...]
  local src="$1" jobs="$2" name
  shift 2
  name="$(basename "$src")"
  cmake -S "$src" -B "$prefix/build/$name" -G Ninja \
    -DCMAKE_INSTALL_PREFIX="$install" -DCMAKE_BUILD_TYPE=Release -DBUILD_TESTING=OFF \
    -DCMAKE_PROJECT_INCLUDE="$hook" -DPython3_EXECUTABLE="$venv/bin/python" \
    -DCMAKE_EXE_LINKER_FLAGS="-Wl,--no-as-needed $libdir/$ldlib -Wl,-rpath,$libdir -Wl,-rpath,$install/lib" \
    "$@"
  nice -n 10 cmake --build "$prefix/build/$name" -j "$jobs"
  cmake --install "$prefix/build/$name"
}

run_step venv make_venv
run_step sources get_sources
set_env
src="$prefix/src"
# system_modes_msgs needs only the wheels: it compiles next to the rclcpp chain, on one job.
run_step system_modes_msgs cmake_package "$src/system_modes/system_modes_msgs" 1 &
msgs=$!
run_step statistics_msgs cmake_package "$src/rcl_interfaces/statistics_msgs" "$jobs"
run_step libstatistics_collector cmake_package "$src/libstatistics_collector" "$jobs"
run_step rclcpp cmake_package "$src/rclcpp/rclcpp" "$jobs"
run_step rclcpp_lifecycle cmake_package "$src/rclcpp/rclcpp_lifecycle" "$jobs"
wait "$msgs" || die "system_modes_msgs did not build" "Its log: $prefix/logs/system_modes_msgs.log"
# Its CMakeLists defaults to C++14; rclcpp for Jazzy needs C++17.
run_step system_modes cmake_package "$src/system_modes/system_modes" "$jobs" -DCMAKE_CXX_STANDARD=17

# Launchers that run the reference's executables in the environment they were built in.
mkdir -p "$prefix/bin"
for exe in mode_manager mode_monitor; do
  [[ -x "$install/lib/system_modes/$exe" ]] || die "the build made no $exe" "See $prefix/logs/system_modes.log"
  cat >"$prefix/bin/$exe" <<LAUNCHER
#!/usr/bin/env bash
# The reference's $exe, with the environment it was built in (tools/reference/build.sh).
export AMENT_PREFIX_PATH="$AMENT_PREFIX_PATH" LD_LIBRARY_PATH="$LD_LIBRARY_PATH\${LD_LIBRARY_PATH:+:\$LD_LIBRARY_PATH}"
export RMW_IMPLEMENTATION=rmw_fastrtps_cpp
exec "$install/lib/system_modes/$exe" "\$@"
LAUNCHER
  chmod +x "$prefix/bin/$exe"
done
# The reference's own model files (its launch tests and examples), which `make interop` runs through
# both managers; named by their path in the repository, "/" written "__".
mkdir -p "$prefix/models"
(cd "$src/system_modes" && for model in system_modes/test/launchtest/*_modes.yaml system_modes/test/test_modes.yaml \
  system_modes/test/test_modes_rules.yaml system_modes_examples/example_modes.yaml; do
  cp "$model" "$prefix/models/${model//\//__}"
done)
rm -rf "$prefix/build" "$prefix/src"
touch "$prefix/.complete"
say "built in $((SECONDS - start)) s"
echo "$prefix"
