"""PPO-MLP on the MIKASA-Robo RL tasks (``ppo_baselines.md``): the release's
``ppo_memtasks.py``, on CPU-simulated envs.

The recipe is ManiSkill3's / CleanRL's PPO (finite-horizon GAE, no termination, one batch
of ``num_envs`` envs). Upstream steps 1,024 GPU-simulated envs; here ``num_envs`` CPU envs
run in worker processes behind one batched env (``mikasa_robo_rl.vector_env``), and the
networks run on the GPU when there is one. Flags, mode rules, advantages, envs and logs:
``mikasa_robo_rl.ppo``; this file is the algorithm.

    python legacy/rl/baselines/ppo/ppo_memtasks.py --env-id RememberColor3-v0 --include-state \\
        --num-envs 16 --num-steps 60 --total-timesteps 2_000_000
    python legacy/rl/baselines/ppo/ppo_memtasks.py --env_id=RememberColor3-v0 --include-rgb --include-joints
    python legacy/rl/baselines/ppo/ppo_memtasks.py --env-id RememberColor3-v0 --include-state \\
        --evaluate --checkpoint path/to/final_ckpt.pt

Needs ``pip install "mikasa-robo-rl[train]"`` (tyro, TensorBoard); ``--track`` also wandb.
"""

from __future__ import annotations

import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
from mikasa_robo_rl.agents import Agent, AgentStateOnly, flatten_state_obs
from mikasa_robo_rl.ppo import (
    PPOArgs,
    clipped_ppo_loss,
    estimate_advantages,
    parse_args,
    start_run,
)
from mikasa_robo_rl.ppo import evaluate as ppo_evaluate
from torch import nn, optim


@dataclass
class Args(PPOArgs):
    """Every flag of ``ppo_baselines.md`` §2 (see ``mikasa_robo_rl.ppo.PPOArgs``)."""


def main(argv: list[str] | None = None) -> dict[str, float]:
    args = parse_args(Args, sys.argv[1:] if argv is None else argv)
    run = start_run(args, Path(__file__).stem)
    mode, num_envs, device, envs, eval_envs = run.mode, run.num_envs, run.device, run.envs, run.eval_envs
    log = run.log.scalar

    # Agent.
    next_obs, _ = envs.reset(seed=run.env_seed)
    eval_envs.reset(seed=run.env_seed)
    action_dim = int(np.prod(envs.single_action_space.shape))
    if mode == "state":
        agent = AgentStateOnly(flatten_state_obs(next_obs).shape[1], action_dim, args.initial_logstd).to(device)
        agent_input = flatten_state_obs
    else:
        agent = Agent(next_obs, action_dim, args.initial_logstd).to(device)
        agent_input = lambda obs: obs  # noqa: E731
    if args.checkpoint:
        agent.load_state_dict(torch.load(args.checkpoint, map_location=device, weights_only=True))
    optimizer = optim.Adam(agent.parameters(), lr=args.learning_rate, eps=1e-5)
    start_iteration, global_step = run.restore(agent, optimizer)  # (1, 0) unless --resume

    # Rollout storage.
    obs = {k: torch.zeros((args.num_steps, *v.shape), dtype=v.dtype, device=device) for k, v in next_obs.items()}
    actions = torch.zeros((args.num_steps, num_envs, action_dim), device=device)
    logprobs = torch.zeros((args.num_steps, num_envs), device=device)
    rewards = torch.zeros((args.num_steps, num_envs), device=device)
    dones = torch.zeros((args.num_steps, num_envs), device=device)
    values = torch.zeros((args.num_steps, num_envs), device=device)

    def evaluate(global_step: int) -> dict[str, float]:
        agent.eval()
        result = ppo_evaluate(eval_envs, lambda obs, done: agent.get_action(agent_input(obs), deterministic=True),
                              args.num_eval_steps, run.log, global_step)
        agent.train()
        return result

    if args.evaluate:
        result = evaluate(0)
        run.close()
        return result

    next_done = torch.zeros(num_envs, device=device)
    for iteration in range(start_iteration, args.num_iterations + 1):
        final_values = torch.zeros((args.num_steps, num_envs), device=device)
        if iteration % args.eval_freq == 1:
            evaluate(global_step)
            run.save(agent, iteration=iteration)
        if args.anneal_lr:
            optimizer.param_groups[0]["lr"] = args.learning_rate * (1.0 - (iteration - 1.0) / args.num_iterations)

        # Rollout.
        rollout_start = time.time()
        for step in range(args.num_steps):
            global_step += num_envs
            for k in obs:
                obs[k][step] = next_obs[k]
            dones[step] = next_done
            with torch.no_grad():
                action, logprob, _, value = agent.get_action_and_value(agent_input(next_obs))
                values[step] = value.flatten()
            actions[step], logprobs[step] = action, logprob
            next_obs, reward, terminations, truncations, infos = envs.step(action)
            next_done = torch.logical_or(terminations, truncations).float()
            rewards[step] = reward.view(-1) * args.reward_scale
            if "final_info" in infos:
                mask = infos["_final_info"]
                for k, v in infos["final_info"]["episode"].items():
                    log(f"train/{k}", v[mask].float().mean().item(), global_step)
                final_obs = {k: v[mask] for k, v in infos["final_observation"].items()}
                with torch.no_grad():
                    final_values[step, torch.arange(num_envs, device=device)[mask]] = agent.get_value(
                        agent_input(final_obs)
                    ).view(-1)
        rollout_time = time.time() - rollout_start

        # Advantages and returns.
        with torch.no_grad():
            next_value = agent.get_value(agent_input(next_obs)).reshape(1, -1)[0]
            advantages = estimate_advantages(rewards, values, dones, final_values, next_value, next_done,
                                             args.gamma, args.gae_lambda, args.finite_horizon_gae)
            returns = advantages + values

        # PPO update over shuffled minibatches of the flattened batch.
        b_obs = {k: v.reshape(-1, *v.shape[2:]) for k, v in obs.items()}
        b_logprobs, b_actions = logprobs.reshape(-1), actions.reshape(-1, action_dim)
        b_advantages, b_returns, b_values = advantages.reshape(-1), returns.reshape(-1), values.reshape(-1)
        update_start = time.time()
        clipfracs = []
        grad_norms = {}  # of the last minibatch that stepped
        stop = False
        for _ in range(args.update_epochs):
            order = torch.randperm(args.batch_size, device=device)
            for start in range(0, args.batch_size, args.minibatch_size):
                mb = order[start : start + args.minibatch_size]
                _, newlogprob, entropy, newvalue = agent.get_action_and_value(
                    agent_input({k: v[mb] for k, v in b_obs.items()}), b_actions[mb]
                )
                loss, stats = clipped_ppo_loss(args, newlogprob, entropy, newvalue, b_logprobs[mb],
                                               b_advantages[mb], b_returns[mb], b_values[mb])
                clipfracs.append(stats["clipfrac"].item())
                if args.target_kl is not None and stats["approx_kl"] > args.target_kl:
                    stop = True  # upstream checks before stepping: this minibatch is skipped
                    break
                optimizer.zero_grad()
                loss.backward()
                grad_norms = agent.head_grad_norms()  # before the clip: what each network's loss asked for
                nn.utils.clip_grad_norm_(agent.parameters(), args.max_grad_norm)
                optimizer.step()
            if stop:
                break
        update_time = time.time() - update_start

        if run.end_iteration(iteration, global_step, optimizer.param_groups[0]["lr"], stats | grad_norms, clipfracs, b_values,
                          b_returns, rollout_time, update_time):
            return run.stop_early()

    return run.finish(agent, evaluate(global_step))


if __name__ == "__main__":
    main()
