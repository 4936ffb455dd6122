#!/usr/bin/env bash
# The memory baseline's six tasks on an offline GPU machine, as three drivers side by side
# (two tasks each), after the simulator and lerobot calls of
# docs/lab-notes/2026-11-26-lerobot-baselines-gpu-runs.md (how it ran:
# docs/lab-notes/2026-12-07-memory-baseline-runs.md):
#
#   source docs/lab-notes/lerobot-baselines/gpu_bundle.sh env && \
#     bash docs/lab-notes/memory-baseline/gpu_drivers.sh LIMIT_S [DRIVER_ARGS...]
#
# installs baselines/memory into the simulator's site, runs the drivers on /tmp/lrb with
# --time-limit LIMIT_S (EPISODES_FIRST: the first driver's --episodes, default 200) (run it again to go on: the drivers resume), then writes the table and
# packs the records into $OUT/pack.tar.gz, with each shipped task's checkpoint as
# $OUT/<task>.tar.
set -u
limit=${1:?time limit in seconds}; shift
root=$(cd "$(dirname "$0")/../../.." && pwd); cd "$root"
python3 -m pip install -q --no-index --no-deps --no-build-isolation --upgrade --target /tmp/site2 \
  ./baselines/memory >/tmp/memory-install.log 2>&1 || { cat /tmp/memory-install.log; exit 1; }
common=(--policies memory-gru --references "" --stages collect,train,eval,table --out /tmp/lrb
  --workers 5 --time-limit "$limit" "$@")
pids=()
for tasks in RememberColor3-VLA-v0,ShellGameTouch-VLA-v0 BunchOfColors3-VLA-v0,InterceptSlow-VLA-v0 \
  BlinkCountButtonPressEasy-VLA-v0,TakeItBack-VLA-v0; do
  episodes=200; [ "$tasks" = "${tasks#RememberColor3}" ] || episodes=${EPISODES_FIRST:-200}
  python3 baselines/lerobot/run_baselines.py --tasks "$tasks" "${common[@]}" --episodes "$episodes" \
    --doc "/tmp/lrb/BASELINES-${tasks%%-*}.md" > "/tmp/lrb-${tasks%%-*}.log" 2>&1 &
  pids+=($!)
done
for p in "${pids[@]}"; do wait "$p"; echo "driver $p: exit $?"; done
tail -n 12 /tmp/lrb-*.log
python3 baselines/lerobot/run_baselines.py --policies memory-gru --references "" --stages table \
  --out /tmp/lrb --doc /tmp/lrb/BASELINES.md --pack "${OUT:-/tmp}/pack.tar.gz" "$@" 2>&1 | tail -n 3
for t in RememberColor3-VLA-v0 ShellGameTouch-VLA-v0; do
  d=/tmp/lrb/train/$t/memory-gru/pretrained_model
  [ -d "$d" ] && tar -C "$d" -cf "${OUT:-/tmp}/$t.tar" .
done
nvidia-smi --query-gpu=name,memory.used --format=csv
