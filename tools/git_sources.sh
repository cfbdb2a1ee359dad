# Sourced by the scripts that fetch upstream sources (tools/reference/build.sh, tools/py_trees_ros.sh):
# where a repository comes from, GitHub or SM_BT_GIT_MIRRORS, a folder of git mirrors, one per
# repository, as <owner>+<name>/repo, <owner>/<name>.git or <owner>/<name>. Needs a die function.

source_url() {  # source_url <owner/name>
  local repo="$1" dir="${SM_BT_GIT_MIRRORS:-}" candidate
  if [[ -n "$dir" ]]; then
    for candidate in "$dir/${repo/\//+}/repo" "$dir/$repo.git" "$dir/$repo"; do
      if [[ -d "$candidate" ]]; then
        echo "$candidate"
        return
      fi
    done
    die "SM_BT_GIT_MIRRORS=$dir has no mirror of $repo" "Expected $dir/${repo/\//+}/repo, $dir/$repo.git or $dir/$repo."
  fi
  echo "https://github.com/$repo.git"
}

fetch_commit() {  # fetch_commit <owner/name> <commit> <folder>: that commit checked out in the folder
  local repo="$1" commit="$2" into="$3" url
  url="$(source_url "$repo")"
  git init --quiet "$into"
  git -C "$into" fetch --quiet --depth 1 "$url" "$commit" 2>/dev/null ||
    git -C "$into" fetch --quiet "$url" ||
    die "cannot fetch $repo from $url" "Without access to github.com, set SM_BT_GIT_MIRRORS to a folder of mirrors."
  git -C "$into" -c advice.detachedHead=false checkout --quiet "$commit"
}
