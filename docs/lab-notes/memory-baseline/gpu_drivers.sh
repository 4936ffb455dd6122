#!/usr/bin/env bash
# The memory baseline's six tasks on an offline machine with one NVIDIA GPU and 16 CPU cores, one driver per task side by side,
# after the simulator and lerobot calls of docs/lab-notes/2026-11-26-lerobot-baselines-gpu-runs.md
# (how it ran: docs/lab-notes/2026-12-07-memory-baseline-runs.md):
#
#   source docs/lab-notes/lerobot-baselines/gpu_bundle.sh env && \
#     bash docs/lab-notes/memory-baseline/gpu_drivers.sh LIMIT_S STAGES [DRIVER_ARGS...]
#
# STAGES: the drivers' --stages (collect first, in a call of its own: collect; then
# train,eval). ONLY=TASK[,TASK...] runs just those tasks' drivers; VARIANTS adds RememberColor3
# drivers with other arguments (below). Installs baselines/memory into the simulator's site, runs the drivers on
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
  RememberColor3-VLA-v0:3000:10 ShellGameTouch-VLA-v0:1000:3 BunchOfColors3-VLA-v0:200:2
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
# VARIANTS="ARGS_1;ARGS_2;...": RememberColor3 once more per entry, with that entry's driver
# arguments too, on the same demonstrations, in /tmp/lrb-v1, /tmp/lrb-v2, ... (not in the
# table; packed as pack-v1.tar.gz, ...). Each RememberColor3 training holds its 3,000
# episodes on the GPU (4.6 GB) besides the colour features' activations: seven trainings
# with all six tasks did not fit one 80 GB GPU; use it with ONLY.
IFS=';' read -r -a variants <<<"${VARIANTS:-}"
if [ "$stages" != collect ]; then
  for i in "${!variants[@]}"; do
    v=/tmp/lrb-v$((i + 1))
    mkdir -p "$v/records/RememberColor3-VLA-v0" && ln -sfn /tmp/lrb/data "$v/data"
    cp /tmp/lrb/records/RememberColor3-VLA-v0/collect.json "$v/records/RememberColor3-VLA-v0/"
    # shellcheck disable=SC2086
    driver "$v" RememberColor3-VLA-v0 3000 3 "$@" --records-from "" ${variants[$i]}
  done
fi
for p in "${pids[@]}"; do wait "$p"; echo "driver $p: exit $?"; done
tail -n 6 /tmp/lrb*-*.log
python3 baselines/lerobot/run_baselines.py --policies memory-gru --references "" --stages table \
  --out /tmp/lrb --doc /tmp/lrb/BASELINES.md --pack "${OUT:-/tmp}/pack.tar.gz" "$@" 2>&1 | tail -n 3
for i in "${!variants[@]}"; do
  v=/tmp/lrb-v$((i + 1))
  # shellcheck disable=SC2086
  python3 baselines/lerobot/run_baselines.py --tasks RememberColor3-VLA-v0 --policies memory-gru \
    --references "" --records-from "" --stages table --out "$v" --doc "$v/BASELINES.md" \
    --pack "${OUT:-/tmp}/pack-v$((i + 1)).tar.gz" "$@" ${variants[$i]} 2>&1 | tail -n 3
done
for run in /tmp/lrb /tmp/lrb-v*; do
  for t in RememberColor3-VLA-v0 ShellGameTouch-VLA-v0; do
    d=$run/train/$t/memory-gru/pretrained_model
    [ -d "$d" ] && tar -C "$d" -cf "${OUT:-/tmp}/${run#/tmp/}-$t.tar" .
  done
done
nvidia-smi --query-gpu=name,memory.used --format=csv
