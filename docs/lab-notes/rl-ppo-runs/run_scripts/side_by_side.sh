#!/usr/bin/env bash
# Train several PPO runs side by side on one machine, each in its own directory, each
# resumed from its latest resume.pt when there is one (so a machine available for a limited time
# can chain calls of this script), each stopped by --time-limit LIMIT_S, counted from the trainer's start
# (its env workers' start included): a command lasts about LIMIT_S plus the install of
# .gpu/run.sh (~55 s), the last iteration and the packing.
#
#   bash docs/lab-notes/rl-ppo-runs/run_scripts/side_by_side.sh LIMIT_S RUNS_FILE [WORK_DIR] [ARCHIVE_DIR]
#
# RUNS_FILE: one run per line, "<name> <trainer> <flags...>" with <trainer> ppo_memtasks.py or
# ppo_memtasks_lstm.py ('#' starts a comment);
# <name>/ under WORK_DIR (default /tmp/ppo_runs) holds its log.txt and checkpoints/. On a GPU
# machine, make WORK_DIR a git-ignored folder of the tree (e.g. runs/gpu_<name>) and carry each
# run's latest resume.pt at its path there: a call may land on a fresh machine even right after
# a warm one, and then only what it carries is there to resume from.
# With ARCHIVE_DIR, each run's directory is packed into ARCHIVE_DIR/<name>.tgz at the end (its log
# as log_call.txt, this call's lines alone: merge_call.sh appends them to the log here),
# with only the KEEP_CKPTS (default 3) latest periodic ckpt_*.pt (a state checkpoint is
# ~1.2 MB, an rgb one ~10 MB, and at most 16 MiB come back per file). Run from the repository root; PYTHON (default python3)
# is the interpreter that has mikasa-robo-rl[train]. NUM_WORKERS, when set, overrides each run's
# --num-workers (the last occurrence of a flag wins), so one run file serves one NVIDIA GPU with 16 CPU cores
# and, between its commands there, a 2-core CPU machine: NUM_WORKERS=2 bash side_by_side.sh ...
set -u
limit=${1:?LIMIT_S}; runs_file=${2:?RUNS_FILE}; work=${3:-/tmp/ppo_runs}; archive=${4:-}
root=$(pwd); python=${PYTHON:-python3}
[[ "$python" == */* && "$python" != /* ]] && python="$root/$python"  # each run starts in its own directory
export OMP_NUM_THREADS=1  # the env workers and trainers share the cores
# shellcheck source=newest.sh
source "$(dirname "${BASH_SOURCE[0]}")/newest.sh"
names=(); declare -A log_start  # each run's log size before this call
while read -r name trainer flags; do
  [[ -z "$name" || "$name" == \#* ]] && continue
  names+=("$name"); mkdir -p "$work/$name"
  log_start[$name]=$(stat -c %s "$work/$name/log.txt" 2>/dev/null || echo 0)
  # the newest by time: a resume.pt copied in by hand may sort after the run's own by name
  resume=$(cd "$work/$name" && newest resume.pt 1)
  # shellcheck disable=SC2086  # the flags are words
  (cd "$work/$name" && echo "== $(date '+%F %T') start ${resume:+--resume $resume}" >>log.txt &&
   exec "$python" "$root/legacy/rl/baselines/ppo/$trainer" $flags ${NUM_WORKERS:+--num-workers "$NUM_WORKERS"} ${resume:+--resume "$resume"} --time-limit "$limit" >>log.txt 2>&1) &
done <"$runs_file"
wait
for name in "${names[@]}"; do
  grep -h "eval @\|Error" "$work/$name/log.txt" | tail -2 | sed "s/^/$name: /"
  tail -1 "$work/$name/log.txt" | sed "s/^/$name: /"
  if [ -n "$archive" ]; then
    keep=$(cd "$work/$name" && newest 'ckpt_*.pt' "${KEEP_CKPTS:-3}")
    # shellcheck disable=SC2086  # the kept paths are words
    tail -c +$((log_start[$name] + 1)) "$work/$name/log.txt" >"$work/$name/log_call.txt"
    tar cf "$archive/$name.tar" -C "$work/$name" --exclude='ckpt_*' --exclude=./log.txt .
    rm "$work/$name/log_call.txt"
    [ -n "$keep" ] && tar rf "$archive/$name.tar" -C "$work/$name" $keep
    gzip -c "$archive/$name.tar" >"$archive/$name.tgz" && rm "$archive/$name.tar"
  fi
done
exit 0
