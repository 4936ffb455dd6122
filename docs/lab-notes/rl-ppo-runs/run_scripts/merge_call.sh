#!/usr/bin/env bash
# Merge what a side_by_side.sh command on an offline GPU machine returned into the run's directory here:
# the archive's files go in, its log_call.txt (that call's lines) is appended to log.txt (a
# machine's log holds only what that machine saw, so copying it over would lose the rest), and
# the newest resume.pt is named, and with COPY_RESUME_TO copied there (e.g. a committed resume).
#
#   bash docs/lab-notes/rl-ppo-runs/run_scripts/merge_call.sh ARCHIVE.tgz RUN_DIR [COPY_RESUME_TO]
set -eu
archive=${1:?ARCHIVE.tgz}; run=${2:?RUN_DIR}; copy_to=${3:-}
unpacked=$(mktemp -d); trap 'rm -rf "$unpacked"' EXIT
tar xzf "$archive" -C "$unpacked"
# an archive from before log_call.txt holds the machine's whole log: all of it is new here
[ -f "$unpacked/log_call.txt" ] || mv "$unpacked/log.txt" "$unpacked/log_call.txt"
mkdir -p "$run"
cat "$unpacked/log_call.txt" >>"$run/log.txt" && rm "$unpacked/log_call.txt"
cp -a "$unpacked/." "$run/"
# shellcheck source=newest.sh
source "$(dirname "$0")/newest.sh"
latest=$(cd "$run" && newest resume.pt 1)
[ -n "$latest" ] || { echo "no resume.pt under $run" >&2; exit 1; }
echo "newest resume.pt: $run/${latest#./}"
if [ -n "$copy_to" ]; then cp "$run/${latest#./}" "$copy_to" && echo "copied to $copy_to"; fi
