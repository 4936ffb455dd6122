#!/usr/bin/env bash
# The validity sweep: the oracle, the memoryless oracle, the seeded random
# policy and zero actions on every task (state observations, the canonical seeds), then
# docs/VALIDITY.md (or $VALIDITY_OUT) from the four run directories.
#
#   bash benchmarks/validity_sweep.sh [OUT] [EPISODES] [WORKERS] [-- extra `mikasa-bench run` args]
#
# OUT (default results/validity) gets one run directory per policy; EPISODES defaults to 50
# (the canonical count), WORKERS to the CPU count; TASKS="ID ID ..." limits the sweep to those
# tasks (default: --split all); VALIDITY_UPDATE=docs/VALIDITY.json keeps that table's rows for the
# other tasks (`mikasa-bench validity --update`); BENCH is the mikasa-bench to use. Interrupted (a time limit,
# kill -9): run the same command again; each policy's run resumes where it stopped.
# Cost: ~2 M env steps per policy over the 90 tasks (the oracle stops at its first success).
# Measured: oracle 321 s and memoryless 491 s with 32 workers on a machine with 32 CPU cores (both end
# on a tail of long episodes); zero 2,627 s with 2 workers on a 2-core CPU machine (774 steps/s);
# random is the slowest (a flailing arm makes contact-rich physics: ~200 steps/s on 2 cores).
set -euo pipefail
out=${1:-results/validity}; episodes=${2:-50}; workers=${3:-$(nproc)}
shift $(( $# < 3 ? $# : 3 )); [ "${1:-}" = "--" ] && shift
bench=${BENCH:-mikasa-bench}
select=(--split all)
if [ -n "${TASKS:-}" ]; then select=(); for t in $TASKS; do select+=(--task "$t"); done; fi
for policy in oracle oracle-memoryless random zero; do
  dir="$out/$policy"
  if [ -f "$dir/meta/run.json" ]; then  # a run directory exists: finish it
    "$bench" run --resume "$dir" --workers "$workers" --no-report "$@"
  else
    "$bench" run "${select[@]}" --policy "$policy" --obs-mode state --num-episodes "$episodes" \
      --out "$dir" --workers "$workers" --no-report "$@"
  fi
done
update=(); [ -n "${VALIDITY_UPDATE:-}" ] && update=(--update "$VALIDITY_UPDATE")
"$bench" validity "$out"/oracle "$out"/oracle-memoryless "$out"/random "$out"/zero --out "${VALIDITY_OUT:-docs/VALIDITY.md}" "${update[@]}"
