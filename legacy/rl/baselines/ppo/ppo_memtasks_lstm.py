"""PPO-LSTM on the MIKASA-Robo RL tasks (``ppo_baselines.md`` §4.3): the release's
``ppo_memtasks_lstm.py``, on CPU-simulated envs. Image modes only (the state is an MDP).

The recipe is ManiSkill3's / CleanRL's PPO (finite-horizon GAE, no termination, one batch
of ``num_envs`` envs). Upstream steps 1,024 GPU-simulated envs; here ``num_envs`` CPU envs
run in worker processes behind one batched env (``mikasa_robo_rl.vector_env``), and the
networks run on the GPU when there is one. Flags, mode rules, advantages, envs and logs:
``mikasa_robo_rl.ppo``; this file is the algorithm.

    python legacy/rl/baselines/ppo/ppo_memtasks_lstm.py --env_id=RememberColor3-v0 --include-rgb \\
        --include-joints --num-envs 128 --num-minibatches 8 --num-steps 60 --anneal-lr

Needs ``pip install "mikasa-robo-rl[train]"`` (tyro, TensorBoard); ``--track`` also wandb.
"""

from __future__ import annotations

import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
from mikasa_robo_rl.agents import AgentLSTM
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
    """Every flag of ``ppo_baselines.md`` §2 (see ``mikasa_robo_rl.ppo.PPOArgs``), and the LSTM's."""

    lstm_hidden_size: int = 512
    lstm_num_layers: int = 1
    lstm_dropout: float = 0.0


def main(argv: list[str] | None = None) -> dict[str, float]:
    args = parse_args(Args, sys.argv[1:] if argv is None else argv)
    if args.include_state:
        raise NotImplementedError("PPO-LSTM takes image observations: pass --include-rgb, not --include-state")
    run = start_run(args, Path(__file__).stem, whole_env_minibatches=True)
    num_envs, device, envs, eval_envs = run.num_envs, run.device, run.envs, run.eval_envs
    log = run.log.scalar

    # Agent.
    next_obs, _ = envs.reset(seed=run.env_seed)
    eval_envs.reset(seed=run.env_seed)
    action_dim = int(np.prod(envs.single_action_space.shape))
    agent = AgentLSTM(
        next_obs, action_dim, args.lstm_hidden_size, args.lstm_num_layers, args.lstm_dropout, args.initial_logstd
    ).to(device)
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
        state = agent.initial_state(args.num_eval_envs, device)  # zeroed for each pass

        def policy(obs, done):
            nonlocal state
            action, state = agent.get_action(obs, state, done, deterministic=True)
            return action

        agent.eval()
        result = ppo_evaluate(eval_envs, policy, args.num_eval_steps, run.log, global_step)
        agent.train()
        return result

    if args.evaluate:
        result = evaluate(0)
        run.close()
        return result

    next_done = torch.ones(num_envs, device=device)  # the first observation starts an episode
    for iteration in range(start_iteration, args.num_iterations + 1):
        final_values = torch.zeros((args.num_steps, num_envs), device=device)
        # The recurrent state is not carried across iterations (upstream); the update
        # re-runs each env's sequence from this state.
        lstm_state = initial_lstm_state = agent.initial_state(num_envs, device)
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
                action, logprob, _, value, lstm_state = agent.get_action_and_value(next_obs, lstm_state, next_done)
                values[step] = value.flatten()
            actions[step], logprobs[step] = action, logprob
            next_obs, reward, terminations, truncations, infos = envs.step(action)
            next_done = torch.logical_or(terminations, truncations).float()
            rewards[step] = reward.view(-1) * args.reward_scale
            if "final_info" in infos:
                mask = infos["_final_info"]
                for k, v in infos["final_info"]["episode"].items():
                    log(f"train/{k}", v[mask].float().mean().item(), global_step)
                # V(final observation) continues each env's sequence: every env's, then the
                # finished ones kept (upstream fed only those with the whole batch's state).
                with torch.no_grad():
                    final_value = agent.get_value(infos["final_observation"], lstm_state, torch.zeros_like(next_done))
                final_values[step, mask] = final_value.view(-1)[mask]
        rollout_time = time.time() - rollout_start

        # Advantages and returns.
        with torch.no_grad():
            next_value = agent.get_value(next_obs, lstm_state, next_done).reshape(1, -1)[0]
            advantages = estimate_advantages(rewards, values, dones, final_values, next_value, next_done,
                                             args.gamma, args.gae_lambda, args.finite_horizon_gae)
            returns = advantages + values

        # PPO update: each minibatch is whole envs' sequences, re-run through the LSTM from
        # the iteration's initial state (upstream used the end-of-rollout state, §9.2).
        b_obs = {k: v.reshape(-1, *v.shape[2:]) for k, v in obs.items()}
        b_logprobs, b_actions, b_dones = logprobs.reshape(-1), actions.reshape(-1, action_dim), dones.reshape(-1)
        b_advantages, b_returns, b_values = advantages.reshape(-1), returns.reshape(-1), values.reshape(-1)
        envs_per_batch = num_envs // args.num_minibatches
        flat_index = torch.arange(args.batch_size, device=device).reshape(args.num_steps, num_envs)
        update_start = time.time()
        clipfracs = []
        grad_norms = {}  # of the last minibatch that stepped
        stop = False
        for _ in range(args.update_epochs):
            env_order = torch.randperm(num_envs, device=device)
            for start in range(0, num_envs, envs_per_batch):
                mb_envs = env_order[start : start + envs_per_batch]
                mb = flat_index[:, mb_envs].reshape(-1)  # time-major
                _, newlogprob, entropy, newvalue, _ = agent.get_action_and_value(
                    {k: v[mb] for k, v in b_obs.items()},
                    (initial_lstm_state[0][:, mb_envs], initial_lstm_state[1][:, mb_envs]),
                    b_dones[mb],
                    b_actions[mb],
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
