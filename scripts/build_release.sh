#!/usr/bin/env bash
# Build the wheel and the sdist of each package of the monorepo into DIST/<package>/, check
# them with `twine check --strict` and print a table of what was built.
#
# Usage: scripts/build_release.sh [--out DIST] [PACKAGE ...]
#   PACKAGE   a distribution name: mikasa-envs, mikasa-wrappers, mikasa-oracles,
#             mikasa-datasets, mikasa-bench, mikasa-robo-rl (default: all six)
#   --out     where the per-package folders go (default: dist/ at the repository root;
#             a package's folder is emptied before its build)
# PYTHON picks the interpreter that has `build` and `twine` (requirements/dev.txt);
# default .venv/bin/python. The wheel is built from the sdist (`python -m build`), as pip
# builds one from a source download: a file the sdist leaves out is missing from both.
# Releasing: docs/contributing/releasing.md.
set -euo pipefail
root=$(cd "$(dirname "$0")/.." && pwd)
PYTHON=${PYTHON:-$root/.venv/bin/python}
dist=$root/dist

# Distribution name -> source folder, in dependency order.
all_packages=(mikasa-envs mikasa-wrappers mikasa-datasets mikasa-oracles mikasa-bench mikasa-robo-rl)
declare -A source_dir=(
  [mikasa-envs]=packages/mikasa-envs
  [mikasa-wrappers]=packages/mikasa-wrappers
  [mikasa-datasets]=packages/mikasa-datasets
  [mikasa-oracles]=packages/mikasa-oracles
  [mikasa-bench]=packages/mikasa-bench
  [mikasa-robo-rl]=legacy/rl
)

packages=()
while [ $# -gt 0 ]; do
  case "$1" in
    --out)
      [ $# -ge 2 ] || { echo "--out needs a folder" >&2; exit 2; }
      dist=$(realpath -m "$2"); shift 2 ;;
    -h|--help) sed -n '2,13p' "$0" | sed 's/^# \{0,1\}//'; exit 0 ;;
    -*) echo "unknown option $1 (see --help)" >&2; exit 2 ;;
    *)
      if [ -z "${source_dir[$1]+x}" ]; then
        echo "unknown package $1; expected one of: ${all_packages[*]}" >&2; exit 2
      fi
      packages+=("$1"); shift ;;
  esac
done
[ ${#packages[@]} -gt 0 ] || packages=("${all_packages[@]}")

for tool in build twine; do
  if ! "$PYTHON" -c "import $tool" 2>/dev/null; then
    echo "$PYTHON lacks '$tool': pip install -r requirements/dev.txt (or 'build>=1.2' 'twine>=5')" >&2
    exit 1
  fi
done

log=$(mktemp)
trap 'rm -f "$log"' EXIT
for pkg in "${packages[@]}"; do
  out=$dist/$pkg
  rm -rf "$out"
  mkdir -p "$out"
  start=$SECONDS
  if ! "$PYTHON" -m build --outdir "$out" "$root/${source_dir[$pkg]}" >"$log" 2>&1; then
    cat "$log" >&2
    echo "build of $pkg failed" >&2
    exit 1
  fi
  if ! "$PYTHON" -m twine check --strict "$out"/* >"$log" 2>&1; then
    cat "$log" >&2
    echo "twine check of $pkg failed" >&2
    exit 1
  fi
  echo "built $pkg in $((SECONDS - start)) s"
done

printf '\n%-16s %-8s %-45s %9s\n' PACKAGE VERSION FILE SIZE
for pkg in "${packages[@]}"; do
  version=$(sed -n 's/^version = "\(.*\)"$/\1/p' "$root/${source_dir[$pkg]}/pyproject.toml")
  for file in "$dist/$pkg"/*; do
    printf '%-16s %-8s %-45s %9s\n' "$pkg" "$version" "$(basename "$file")" \
      "$(du -h "$file" | cut -f1)"
  done
done
echo
echo "twine check passed; files in ${dist#"$root"/}/<package>/"
