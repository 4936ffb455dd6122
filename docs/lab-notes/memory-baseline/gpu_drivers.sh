#!/usr/bin/env bash
# The memory baseline's six tasks on an offline machine with one NVIDIA GPU and 16 CPU cores, one driver per task side by side,
# after the simulator and lerobot calls of docs/lab-notes/2026-11-26-lerobot-baselines-gpu-runs.md
# (how it ran: docs/lab-notes/2026-12-07-memory-baseline-runs.md):
#
#   source docs/lab-notes/lerobot-baselines/gpu_bundle.sh env && \
#     bash docs/lab-notes/memory-baseline/gpu_drivers.sh LIMIT_S STAGES [DRIVER_ARGS...]
#
# STAGES: the drivers' --stages (collect first, in a call of its own: collect; then
# train,eval). ONLY=TASK[,TASK...] runs just those tasks' drivers; VARIANT="DRIVER_ARGS" adds
# a second RememberColor3 driver (below). Installs baselines/memory into the simulator's site, runs the drivers on
# /tmp/lrb with --time-limit LIMIT_S (run it again to go on: the drivers resume), then
# writes the table and packs the records into $OUT/pack.tar.gz, with the shipped tasks'
# checkpoints as $OUT/lrb-<task>.tar. Demonstrations per task and worker processes per
# driver: TASKS below.
set -u
limit=${1:?time limit in seconds}; stages=${2:?driver stages}; shift 2
root=$(cd "$(dirname "$0")/../../.." && pwd); cd "$root"
python3 -m pip install -q --no-index --no-deps --no-build-isolation --upgrade --target /tmp/site2 \
  ./baselines/memory >/tmp/memory-install.log 2>&1 || { cat /tmp/memory-install.log; exit 1; }
TASKS=(  # task:demonstrations:workers
  RememberColor3-VLA-v0:3000:6 ShellGameTouch-VLA-v0:1000:3 BunchOfColors3-VLA-v0:200:2
  InterceptSlow-VLA-v0:200:2 BlinkCountButtonPressEasy-VLA-v0:200:2 TakeItBack-VLA-v0:200:2
)
pids=()
driver() {  # OUT TASK EPISODES WORKERS [DRIVER_ARGS...]
  local out=$1 task=$2 episodes=$3 workers=$4; shift 4
  python3 baselines/lerobot/run_baselines.py --tasks "$task" --policies memory-gru --references "" \
    --stages "$stages" --out "$out" --workers "$workers" --episodes "$episodes" \
    --time-limit "$limit" --doc "$out/BASELINES-$task.md" "$@" > "$out-$task.log" 2>&1 &
  pids+=($!)
}
for entry in "${TASKS[@]}"; do
  IFS=: read -r task episodes workers <<<"$entry"
  # ONLY="TASK[,TASK...]": just these tasks' drivers
  [ -z "${ONLY:-}" ] || [[ ",$ONLY," == *",$task,"* ]] || continue
  driver /tmp/lrb "$task" "$episodes" "$workers" "$@"
done
# VARIANT="DRIVER_ARGS": RememberColor3 once more with these arguments too, on the same
# demonstrations, in /tmp/lrb-variant (not in the table; packed as pack-variant.tar.gz).
# With all six tasks it did not fit one 80 GB GPU (each RememberColor3 training holds its
# 3,000 episodes there, 4.6 GB, besides the colour features' activations): use it with ONLY.
if [ -n "${VARIANT:-}" ] && [ "$stages" != collect ]; then
  mkdir -p /tmp/lrb-variant/records/RememberColor3-VLA-v0 && ln -sfn /tmp/lrb/data /tmp/lrb-variant/data
  cp /tmp/lrb/records/RememberColor3-VLA-v0/collect.json /tmp/lrb-variant/records/RememberColor3-VLA-v0/
  # shellcheck disable=SC2086
  driver /tmp/lrb-variant RememberColor3-VLA-v0 3000 3 "$@" $VARIANT
fi
for p in "${pids[@]}"; do wait "$p"; echo "driver $p: exit $?"; done
tail -n 6 /tmp/lrb*-*.log
python3 baselines/lerobot/run_baselines.py --policies memory-gru --references "" --stages table \
  --out /tmp/lrb --doc /tmp/lrb/BASELINES.md --pack "${OUT:-/tmp}/pack.tar.gz" "$@" 2>&1 | tail -n 3
if [ -d /tmp/lrb-variant/records ]; then
  python3 baselines/lerobot/run_baselines.py --tasks RememberColor3-VLA-v0 --policies memory-gru \
    --references "" --stages table --out /tmp/lrb-variant --doc /tmp/lrb-variant/BASELINES.md \
    --pack "${OUT:-/tmp}/pack-variant.tar.gz" "$@" ${VARIANT:-} 2>&1 | tail -n 3
fi
for run in /tmp/lrb /tmp/lrb-variant; do
  for t in RememberColor3-VLA-v0 ShellGameTouch-VLA-v0; do
    d=$run/train/$t/memory-gru/pretrained_model
    [ -d "$d" ] && tar -C "$d" -cf "${OUT:-/tmp}/${run#/tmp/}-$t.tar" .
  done
done
nvidia-smi --query-gpu=name,memory.used --format=csv
