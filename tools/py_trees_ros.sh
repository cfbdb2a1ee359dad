#!/usr/bin/env bash
# py_trees_ros's sources (no package index has it), for `make interop`'s hosting test: release 2.2.2
# and devel (the first with setup(**kwargs)), each exported once into
# ${SM_BT_CACHE:-${XDG_CACHE_HOME:-~/.cache}/sm_bt}/py_trees_ros/<version>. Prints "<version> <folder>"
# per line. Sources from GitHub or SM_BT_GIT_MIRRORS (see tools/git_sources.sh).
set -euo pipefail

here="$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)"
versions=(
  "2.2.2 64ee0b9fe75627338d29568f432afa22d9b2c4b3"
  "devel 247cf47d509f827bb24464be376e8ed2ddefc0fb"
)

die() {
  echo "py_trees_ros: ERROR: $1" >&2
  shift
  for line in "$@"; do echo "  $line" >&2; done
  exit 1
}
# shellcheck source=git_sources.sh
source "$here/git_sources.sh"
command -v git >/dev/null || die "git is not installed" "Install it (apt-get install git) and run again."

cache="${SM_BT_CACHE:-${XDG_CACHE_HOME:-$HOME/.cache}/sm_bt}/py_trees_ros"
for entry in "${versions[@]}"; do
  read -r version commit <<<"$entry"
  folder="$cache/$version-${commit:0:12}"
  if [[ ! -f "$folder/.complete" ]]; then
    rm -rf "$folder" "$folder.git"
    url="$(source_url splintered-reality/py_trees_ros)"
    if [[ -d "$url" ]]; then
      source="$url"  # a mirror may lack large files (images): only the package's folder is read
    else
      fetch_commit splintered-reality/py_trees_ros "$commit" "$folder.git"
      source="$folder.git"
    fi
    mkdir -p "$folder"
    git -C "$source" archive "$commit" py_trees_ros 2>/dev/null | tar -x -C "$folder" ||
      die "cannot export py_trees_ros $version ($commit) from $source"
    rm -rf "$folder.git"
    touch "$folder/.complete"
  fi
  echo "$version $folder"
done
