"""Validity of the 32 RL tasks: does each need memory? (the validity check, for the RL release)

Four policies over the canonical seeds: the scripted oracle
(``mikasa_robo_rl.oracles.make_rl_oracle``: the VLA family oracle acting in
``pd_joint_delta_pos``), its memoryless variant (``memoryless=True``: the same controller,
the remembered answer wiped every step, guesses seeded by the episode seed), seeded uniform
random actions and zero actions. A task is valid when the oracle reaches ``success_once`` on
>= 95 % of the seeds, zero actions on none, and neither the memoryless oracle nor random
actions do significantly better than chance (the lower end of their Wilson 95 % interval
above it). Chance is the VLA twin's (``mikasa_bench.results.chance``: the RL tasks are the same
families with other timing, so the candidates are the same). State observations, CPU
PhysX, one env per worker process; jobs are (env id, policy, block of seeds).

Every policy stops at its first success. Seeds the oracle fails within the published
horizon are run again with the step limit raised to ``--horizon-factor`` x the horizon: a
success there says the horizon, not the oracle, was short (a rerun, not a longer first run,
because some oracles plan with the time left).

    python benchmarks/rl_oracle_validity.py                        # 50 seeds, every RL id
    python benchmarks/rl_oracle_validity.py --seeds 10 --env-ids RememberColor3-v0,TakeItBack-v0
    python benchmarks/rl_oracle_validity.py --workers 16 --out results/rl_validity
    python benchmarks/rl_oracle_validity.py --env-ids InterceptSlow-v0 --env-kwargs '{"ball_shown_steps": 10}'

Writes ``<out>/rl_oracle_validity.json`` and ``.md`` (a table) and prints the table.
"""

from __future__ import annotations

import argparse
import json
import multiprocessing as mp
import os
import time
from concurrent.futures import ProcessPoolExecutor, as_completed
from pathlib import Path

FIRST_SEED = 4242424242
SEEDS_PER_JOB = 10
TARGET = 0.95
POLICIES = ("oracle", "oracle-memoryless", "random", "zero")


def run_job(
    env_id: str, policy: str, seeds: list[int], horizon_factor: float, env_kwargs: dict
) -> tuple[str, str, dict[int, tuple[int, bool]]]:
    """Roll ``policy`` (one of ``POLICIES``) out on ``seeds``: {seed: (step of first success,
    within the horizon)} for the seeds that succeeded (oracle failures rerun with
    ``horizon_factor`` x the horizon as the step limit). ``env_kwargs`` go to ``gym.make``."""
    os.environ.setdefault("OMP_NUM_THREADS", "1")
    import gymnasium as gym
    import torch
    from mikasa_bench.policies import RandomPolicy
    from mikasa_oracles import ZeroActions, rollout
    from mikasa_robo_rl import get_rl_task
    from mikasa_robo_rl.oracles import make_rl_oracle

    torch.set_num_threads(1)

    def make(limit: int | None = None) -> tuple[gym.Env, object]:
        env = gym.make(env_id, obs_mode="state", control_mode="pd_joint_delta_pos",
                       reward_mode="normalized_dense", max_episode_steps=limit, **env_kwargs)
        agents = {
            "oracle": lambda: make_rl_oracle(env),
            "oracle-memoryless": lambda: make_rl_oracle(env, memoryless=True),
            "random": lambda: RandomPolicy(action_shape=(8,)),
            "zero": lambda: ZeroActions(8),
        }
        return env, agents[policy]()

    env, agent = make()
    won = {}
    for seed in seeds:
        # success_once is latched: every policy may stop at its first success.
        result = rollout(env, agent, seed, stop_on_success=True)
        if result.success_once:
            won[seed] = (result.steps, True)
    env.close()
    failed = [s for s in seeds if s not in won]
    if policy == "oracle" and failed and horizon_factor > 1:
        env, agent = make(round(get_rl_task(env_id).max_episode_steps * horizon_factor))
        for seed in failed:
            result = rollout(env, agent, seed, stop_on_success=True)
            if result.success_once:
                won[seed] = (result.steps, False)
        env.close()
    return env_id, policy, won


def main() -> None:
    """Parse arguments, run the jobs in parallel, print and write the table."""
    import mikasa_robo_rl

    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--env-ids", default=None, help="comma-separated RL ids (default: all 32)")
    parser.add_argument("--seeds", type=int, default=50, help="seeds per id (from 4242424242)")
    parser.add_argument("--workers", type=int, default=os.cpu_count(), help="worker processes")
    parser.add_argument("--out", default="results/rl_oracle_validity", help="output directory")
    parser.add_argument("--horizon-factor", type=float, default=3.0,
                        help="the oracle's step limit as a multiple of the horizon (>= 1)")
    parser.add_argument("--env-kwargs", default="{}",
                        help='a JSON object of gym.make keyword arguments, e.g. \'{"ball_shown_steps": 10}\'')
    args = parser.parse_args()
    if args.horizon_factor < 1:
        parser.error(f"--horizon-factor must be >= 1, got {args.horizon_factor}")
    try:
        env_kwargs = json.loads(args.env_kwargs)
    except json.JSONDecodeError as err:
        parser.error(f"--env-kwargs is not JSON ({err}); give an object such as '{{\"ball_shown_steps\": 10}}'")
    if not isinstance(env_kwargs, dict):
        parser.error(f"--env-kwargs must be a JSON object of keyword arguments, got {args.env_kwargs!r}")
    env_ids = args.env_ids.split(",") if args.env_ids else list(mikasa_robo_rl.rl_env_ids())
    for env_id in env_ids:
        mikasa_robo_rl.get_rl_task(env_id)  # unknown ids fail here, before any work
    seeds = list(range(FIRST_SEED, FIRST_SEED + args.seeds))
    blocks = [seeds[i : i + SEEDS_PER_JOB] for i in range(0, len(seeds), SEEDS_PER_JOB)]
    jobs = [(e, p, b) for e in env_ids for p in POLICIES for b in blocks]

    wins: dict[tuple[str, str], dict[int, tuple[int, bool]]] = {(e, p): {} for e in env_ids for p in POLICIES}
    start = time.perf_counter()
    with ProcessPoolExecutor(args.workers, mp_context=mp.get_context("spawn")) as pool:
        futures = [pool.submit(run_job, *job, args.horizon_factor, env_kwargs) for job in jobs]
        for done, future in enumerate(as_completed(futures), 1):
            env_id, policy, won = future.result()
            wins[(env_id, policy)].update(won)
            print(f"[{done}/{len(jobs)}] {env_id} {policy}: {len(won)} successes", flush=True)
    wall = time.perf_counter() - start

    import numpy as np
    from mikasa_bench.results.chance import task_chance
    from mikasa_bench.results.metrics import wilson_interval
    from mikasa_robo_rl import get_rl_task

    rows = []
    for env_id in env_ids:
        horizon = get_rl_task(env_id).max_episode_steps
        steps = wins[(env_id, "oracle")]
        in_time = [s for s, (_, within) in steps.items() if within]
        rate = {p: len(wins[(env_id, p)]) / len(seeds) for p in POLICIES}
        rate["oracle"] = len(in_time) / len(seeds)
        # The RL task is its VLA twin's family with other timing: the same candidates.
        chance = task_chance(env_id.removesuffix("-v0") + "-VLA-v0").rate
        above_chance = [p for p in ("oracle-memoryless", "random")
                        if wilson_interval(len(wins[(env_id, p)]), len(seeds))[0] > chance]
        needed = np.array(sorted(n for n, _ in steps.values())) if steps else np.array([np.nan])
        rows.append(dict(env_id=env_id, horizon=horizon, oracle_success=rate["oracle"],
                         memoryless_success=rate["oracle-memoryless"], random_success=rate["random"],
                         zero_success=rate["zero"], chance=chance,
                         above_chance=above_chance,
                         valid=rate["oracle"] >= TARGET and rate["zero"] == 0.0 and not above_chance,
                         oracle_success_extended=len(steps) / len(seeds),
                         steps_to_success_p50=float(np.percentile(needed, 50)),
                         steps_to_success_p95=float(np.percentile(needed, 95)),
                         oracle_failed_seeds=sorted(set(seeds) - set(in_time)),
                         zero_succeeded_seeds=sorted(wins[(env_id, "zero")])))
    limit = f"{args.horizon_factor:g}x horizon"
    lines = [f"| env id | horizon | oracle | memoryless | random | zero | chance | valid "
             f"| oracle within {limit} | steps to success p50 / p95 |", "|---|---|---|---|---|---|---|---|---|---|"]
    lines += [f"| {r['env_id']} | {r['horizon']} | {r['oracle_success']:.2f} | {r['memoryless_success']:.2f} "
              f"| {r['random_success']:.2f} | {r['zero_success']:.2f} | {r['chance']:.3f} "
              f"| {'yes' if r['valid'] else 'NO' + ''.join(f' ({p}>chance)' for p in r['above_chance'])} "
              f"| {r['oracle_success_extended']:.2f} "
              f"| {r['steps_to_success_p50']:.0f} / {r['steps_to_success_p95']:.0f} |" for r in rows]
    summary = f"{sum(r['valid'] for r in rows)}/{len(rows)} ids valid over {len(seeds)} seeds; {wall:.0f} s with {args.workers} workers"
    if env_kwargs:
        summary += f"; gym.make keyword arguments {json.dumps(env_kwargs)}"
    print("\n".join(lines) + "\n\n" + summary)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    for name, text in (
        ("rl_oracle_validity.json", json.dumps(dict(seeds=len(seeds), first_seed=FIRST_SEED, wall_s=wall,
                                                    workers=args.workers, horizon_factor=args.horizon_factor,
                                                    env_kwargs=env_kwargs,
                                                    rows=rows), indent=2)),
        ("rl_oracle_validity.md", "\n".join(lines) + f"\n\n{summary}\n"),
    ):
        tmp = out / (name + ".tmp")
        tmp.write_text(text)
        tmp.replace(out / name)


if __name__ == "__main__":
    main()
