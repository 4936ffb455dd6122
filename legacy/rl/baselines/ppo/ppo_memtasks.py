"""PPO-MLP on the MIKASA-Robo RL tasks (``ppo_baselines.md``): the release's
``ppo_memtasks.py``, on CPU-simulated envs.

The recipe is ManiSkill3's / CleanRL's PPO (finite-horizon GAE, no termination, one batch
of ``num_envs`` envs). Upstream steps 1,024 GPU-simulated envs; here ``num_envs`` CPU envs
run in worker processes behind one batched env (``mikasa_robo_rl.vector_env``), and the
networks run on the GPU when there is one. This file holds the flags, the image agent and PPO
(rollout, advantages, update); the state agent, the envs, logs, evaluation pass and checkpoints
come from ``mikasa_robo_rl``.

    python legacy/rl/baselines/ppo/ppo_memtasks.py --env-id RememberColor3-v0 --include-state \\
        --num-envs 16 --num-steps 60 --total-timesteps 2_000_000
    python legacy/rl/baselines/ppo/ppo_memtasks.py --env_id=RememberColor3-v0 --include-rgb \\
        --include-joints
    python legacy/rl/baselines/ppo/ppo_memtasks.py --env-id RememberColor3-v0 --include-state \\
        --evaluate --checkpoint path/to/final_ckpt.pt

Needs ``pip install "mikasa-robo-rl[train]"`` (tyro, TensorBoard); ``--track`` also wandb.
"""

from __future__ import annotations

import math
import random
import sys
import time
from collections.abc import Mapping
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
import torch
from mikasa_robo_rl.agents import (
    INITIAL_LOGSTD,
    AgentStateOnly,
    GaussianActorCritic,
    NatureCNN,
    flatten_state_obs,
    layer_init,
)
from mikasa_robo_rl.manifest import trainable_horizon
from mikasa_robo_rl.ppo import (
    RESUME_FILE,
    RunLog,
    RunSettings,
    evaluate,
    load_resume_state,
    make_envs,
    observation_mode,
    parse_args,
    restore_from_resume,
    run_directory,
    save_atomically,
    save_resume_state,
)
from mikasa_robo_rl.vector_env import SubEnvSpec
from torch import nn, optim
from torch.distributions.normal import Normal


@dataclass
class Args:
    """The flags of ``ppo_baselines.md`` §2."""

    exp_name: str | None = None
    """the name of this experiment (part of the run name)"""
    seed: int = 123
    """seed of python, numpy, torch and the first env reset"""
    torch_deterministic: bool = True
    """torch.backends.cudnn.deterministic"""
    cuda: bool = True
    """run the networks on CUDA when available"""
    track: bool = False
    """log to Weights & Biases (needs wandb)"""
    wandb_project_name: str = "ManiSkill-MemoryBench"
    wandb_entity: str | None = None
    capture_video: bool = True
    """record eval videos (the first eval env's episodes, under the run's videos/)"""
    save_model: bool = True
    """write checkpoints"""
    evaluate: bool = False
    """only evaluate --checkpoint"""
    checkpoint: str | None = None
    """a state_dict to load before training or evaluation"""
    render_mode: str = "all"
    env_id: str = "ShellGamePush-v1"
    """the RL task id (the release's default is not an id: always pass one)"""
    include_state: bool = False
    """privileged state observation (MODE state)"""
    total_timesteps: int = 50_000_000
    learning_rate: float = 3e-4
    num_envs: int = 1024
    """parallel training envs (CPU sub-envs in worker processes; 1 with --evaluate)"""
    num_eval_envs: int = 16
    partial_reset: bool = False
    """reset training envs on termination (else only on the time limit)"""
    eval_partial_reset: bool = False
    num_steps: int = 90
    """rollout length per iteration, per env"""
    num_eval_steps: int = 270
    reconfiguration_freq: int | None = None
    eval_reconfiguration_freq: int | None = 1
    anneal_lr: bool = False
    gamma: float = 0.99
    gae_lambda: float = 0.95
    num_minibatches: int = 32
    update_epochs: int = 4
    norm_adv: bool = True
    clip_coef: float = 0.2
    clip_vloss: bool = False
    ent_coef: float = 0.0
    vf_coef: float = 0.5
    max_grad_norm: float = 0.5
    target_kl: float | None = 0.2
    reward_scale: float = 1.0
    initial_logstd: float = INITIAL_LOGSTD
    """the actor's initial log std (an extension; upstream's -0.5 by default), for exploration
    studies"""
    eval_freq: int = 25
    """evaluate and checkpoint when iteration % eval_freq == 1"""
    save_train_video_freq: int | None = None
    finite_horizon_gae: bool = True
    batch_size: int = 0
    """set at runtime: num_envs * num_steps"""
    minibatch_size: int = 0
    """set at runtime: batch_size // num_minibatches"""
    num_iterations: int = 0
    """set at runtime: total_timesteps // batch_size"""
    include_oracle: bool = False
    """add oracle_info to image observations"""
    noop_steps: int = 1
    """InitialZeroActionWrapper(n_initial_steps=noop_steps - 1); 1 = no no-op steps"""
    include_rgb: bool = False
    include_joints: bool = False
    """proprioception with the images (needs --include-rgb)"""
    reward_mode: str = "normalized_dense"
    num_workers: int | None = None
    """env worker processes (default: one per CPU core, at most one per env); 0 = in this process"""
    env_shared_memory: bool = False
    """env workers write observations into shared memory instead of pickling them"""
    env_render_together: bool = False
    """each env worker steps its envs in threads and renders their cameras in one GPU pass"""
    resume: str | None = None
    """a run's resume.pt: go on with that run (networks, optimizer, step counters, RNG, run
    directory) at this --learning-rate"""
    resume_min_logstd: float | None = None
    """with --resume: raise the policy's log std to at least this in every action dimension (an
    extension: re-opens the exploration of a run whose action noise has collapsed; default: keep)"""
    time_limit: float | None = None
    """stop after the iteration that passes this many seconds since the trainer started (env
    workers' start included, so that a time-limited job can be sized), resume.pt saved (to chain
    time-limited jobs)"""


class Agent(GaussianActorCritic):
    """PPO actor-critic for image observations (``ppo_baselines.md`` §4.2): ``NatureCNN``
    features, then critic ``Linear(F, 512)-ReLU-Linear(512, 1)`` and actor mean ``Linear(F, 512)-
    ReLU-Linear(512, action_dim)``; a diagonal Gaussian with the state-independent
    ``actor_logstd``. (The ``state`` mode's agent is ``AgentStateOnly``, which the data collector
    also loads.)"""

    def __init__(
        self, sample_obs: Mapping[str, torch.Tensor], action_dim: int,
        initial_logstd: float = INITIAL_LOGSTD,
    ) -> None:
        super().__init__()
        self.feature_net = NatureCNN(sample_obs)
        width = self.feature_net.out_features
        self.critic = nn.Sequential(
            layer_init(nn.Linear(width, 512)), nn.ReLU(), layer_init(nn.Linear(512, 1))
        )
        self.actor_mean = nn.Sequential(
            layer_init(nn.Linear(width, 512)), nn.ReLU(),
            layer_init(nn.Linear(512, action_dim), std=0.01 * math.sqrt(2)),
        )
        self.actor_logstd = nn.Parameter(torch.ones(1, action_dim) * initial_logstd)

    def get_value(self, obs: Mapping[str, torch.Tensor]) -> torch.Tensor:
        """V(obs), shape ``(B, 1)``."""
        return self.critic(self.feature_net(obs))

    def get_action(
        self, obs: Mapping[str, torch.Tensor], deterministic: bool = False
    ) -> torch.Tensor:
        """The mean action if ``deterministic``, else a Gaussian sample."""
        action_mean = self.actor_mean(self.feature_net(obs))
        if deterministic:
            return action_mean
        return Normal(action_mean, torch.exp(self.actor_logstd.expand_as(action_mean))).sample()

    def get_action_and_value(
        self, obs: Mapping[str, torch.Tensor], action: torch.Tensor | None = None
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
        """``(action, log_prob, entropy, value)`` as PPO's update needs them."""
        features = self.feature_net(obs)
        action_mean = self.actor_mean(features)
        probs = Normal(action_mean, torch.exp(self.actor_logstd.expand_as(action_mean)))
        if action is None:
            action = probs.sample()
        return action, probs.log_prob(action).sum(1), probs.entropy().sum(1), self.critic(features)


def main(argv: list[str] | None = None) -> dict[str, float]:
    """Train (with ``--evaluate``: evaluate ``--checkpoint``) as the flags say. Returns the last
    evaluation's means, or ``{"stopped_early": 1.0}`` when ``--time-limit`` cut the run."""
    args = parse_args(Args, sys.argv[1:] if argv is None else argv)
    mode = observation_mode(include_state=args.include_state, include_rgb=args.include_rgb,
                            include_joints=args.include_joints, include_oracle=args.include_oracle)
    horizon = trainable_horizon(args.env_id)  # unknown ids fail here, naming close ones
    if args.evaluate and not args.checkpoint:
        raise ValueError("--evaluate needs --checkpoint")
    num_envs = 1 if args.evaluate else args.num_envs
    args.batch_size = num_envs * args.num_steps
    args.minibatch_size = args.batch_size // args.num_minibatches
    args.num_iterations = args.total_timesteps // args.batch_size
    # The batch sizes matter to training only: --evaluate takes the training run's flags as
    # they are.
    if not args.evaluate and args.minibatch_size < 1:
        raise ValueError(f"num_envs * num_steps = {args.batch_size} is smaller than "
                         f"num_minibatches = {args.num_minibatches}")
    if args.save_train_video_freq is not None:
        print("note: --save-train-video-freq is not implemented for CPU envs; "
              "no training videos are written")
    run_name, save_dir = run_directory(
        script=Path(__file__).stem, env_id=args.env_id, mode=mode, reward_mode=args.reward_mode,
        seed=args.seed, exp_name=args.exp_name,
    )
    settings = RunSettings(args.env_id, mode, args.reward_scale, args.vf_coef, args.reward_mode)
    if args.resume_min_logstd is not None and not args.resume:
        raise ValueError("--resume-min-logstd applies to a --resume run "
                         "(a fresh run takes --initial-logstd)")
    resumed = None
    if args.resume:
        if args.evaluate:
            raise ValueError("--resume continues training; --evaluate takes --checkpoint")
        resumed = load_resume_state(args.resume, settings=settings)
        save_dir = Path(resumed["save_dir"])
        # Iterations count on from the saved one; the run still stops at --total-timesteps when
        # it goes on with another batch size (--num-envs, --num-steps) than it was saved with.
        steps_left = max(0, args.total_timesteps - resumed["global_step"])
        args.num_iterations = resumed["iteration"] + steps_left // args.batch_size

    random.seed(args.seed)
    np.random.seed(args.seed)
    torch.manual_seed(args.seed)
    torch.backends.cudnn.deterministic = args.torch_deterministic
    device = torch.device("cuda" if torch.cuda.is_available() and args.cuda else "cpu")

    # Envs: CPU sub-envs in worker processes, batched. With --capture-video the first eval env
    # records its episodes: under the run's videos/, or with --evaluate (trajectories too) in
    # test_videos/ beside the checkpoint.
    launched = time.time()  # --time-limit counts from here: starting many env workers takes minutes
    env_spec = SubEnvSpec(
        args.env_id, mode, reward_mode=args.reward_mode, noop_steps=args.noop_steps,
        reconfiguration_freq=args.reconfiguration_freq, ignore_terminations=not args.partial_reset,
    )
    eval_spec = replace(env_spec, reconfiguration_freq=args.eval_reconfiguration_freq,
                        ignore_terminations=not args.eval_partial_reset)
    if args.capture_video:
        video_dir = (Path(args.checkpoint).parent / "test_videos" if args.evaluate
                     else save_dir / "videos")
        eval_spec = replace(eval_spec, video_dir=str(video_dir), save_trajectory=args.evaluate,
                            render_mode=args.render_mode, max_steps_per_video=args.num_eval_steps)
    envs, eval_envs = make_envs(env_spec, eval_spec, num_envs=num_envs,
                                num_eval_envs=args.num_eval_envs, workers=args.num_workers,
                                device=device, shared_memory=args.env_shared_memory,
                                render_together=args.env_render_together)
    print(f"{args.env_id}: MODE {mode}, horizon {horizon}, {num_envs} envs, "
          f"{args.num_eval_envs} eval envs, device {device}; "
          f"env workers ready in {time.time() - launched:.0f} s")
    log = RunLog(save_dir, run_name=run_name, config=vars(args), track=args.track,
                 wandb_project=args.wandb_project_name, wandb_entity=args.wandb_entity)
    start_time = time.time()

    def close_run() -> None:
        envs.close()
        eval_envs.close()
        log.close()

    # Agent. A resumed run's envs start from another seed, so as not to replay the first
    # piece's episodes.
    env_seed = args.seed + (resumed["iteration"] if resumed else 0)
    next_obs, _ = envs.reset(seed=env_seed)
    eval_envs.reset(seed=env_seed)
    action_dim = int(np.prod(envs.single_action_space.shape))
    if mode == "state":
        obs_dim = flatten_state_obs(next_obs).shape[1]
        agent = AgentStateOnly(obs_dim, action_dim, args.initial_logstd).to(device)
        agent_input = flatten_state_obs
    else:
        agent = Agent(next_obs, action_dim, args.initial_logstd).to(device)
        agent_input = lambda obs: obs  # noqa: E731
    if args.checkpoint:
        agent.load_state_dict(torch.load(args.checkpoint, map_location=device, weights_only=True))
    optimizer = optim.Adam(agent.parameters(), lr=args.learning_rate, eps=1e-5)
    start_iteration, global_step, saves = 1, 0, 0
    if resumed:
        start_iteration, global_step, saves = restore_from_resume(
            resumed, agent=agent, optimizer=optimizer, settings=settings,
            learning_rate=args.learning_rate, min_logstd=args.resume_min_logstd,
        )
    start_step = global_step

    # Rollout storage.
    obs = {k: torch.zeros((args.num_steps, *v.shape), dtype=v.dtype, device=device)
           for k, v in next_obs.items()}
    actions = torch.zeros((args.num_steps, num_envs, action_dim), device=device)
    logprobs = torch.zeros((args.num_steps, num_envs), device=device)
    rewards = torch.zeros((args.num_steps, num_envs), device=device)
    dones = torch.zeros((args.num_steps, num_envs), device=device)
    values = torch.zeros((args.num_steps, num_envs), device=device)

    def evaluate_agent(global_step: int) -> dict[str, float]:
        agent.eval()
        result = evaluate(
            eval_envs, lambda obs, done: agent.get_action(agent_input(obs), deterministic=True),
            num_steps=args.num_eval_steps, log=log, global_step=global_step,
        )
        agent.train()
        return result

    if args.evaluate:
        result = evaluate_agent(0)
        close_run()
        return result

    next_done = torch.zeros(num_envs, device=device)
    for iteration in range(start_iteration, args.num_iterations + 1):
        final_values = torch.zeros((args.num_steps, num_envs), device=device)
        if iteration % args.eval_freq == 1:
            evaluate_agent(global_step)
            if args.save_model:
                save_atomically(agent.state_dict(), save_dir / f"ckpt_{saves}_{iteration}.pt")
                saves += 1
        if args.anneal_lr:
            frac = 1.0 - (iteration - 1.0) / args.num_iterations
            optimizer.param_groups[0]["lr"] = args.learning_rate * frac

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
                    log.scalar(f"train/{k}", v[mask].float().mean().item(), global_step)
                final_obs = {k: v[mask] for k, v in infos["final_observation"].items()}
                with torch.no_grad():
                    finished = torch.arange(num_envs, device=device)[mask]
                    final_values[step, finished] = agent.get_value(agent_input(final_obs)).view(-1)
        rollout_time = time.time() - rollout_start

        # Advantages (§5.2). Finite-horizon GAE: per step, the λ-weighted average of the n-step
        # returns still inside the episode, normalised by the weights available; else standard
        # GAE (--no-finite-horizon-gae). final_values holds V(final observation) where an
        # episode ended.
        with torch.no_grad():
            next_value = agent.get_value(agent_input(next_obs)).reshape(1, -1)[0]
            advantages = torch.zeros_like(rewards)
            gamma, lam = args.gamma, args.gae_lambda
            last_advantage = lam_sum = reward_sum = value_sum = torch.zeros_like(next_value)
            for t in reversed(range(args.num_steps)):
                not_done = 1.0 - (next_done if t == args.num_steps - 1 else dones[t + 1])
                following_value = next_value if t == args.num_steps - 1 else values[t + 1]
                real_next_value = not_done * following_value + final_values[t]
                if args.finite_horizon_gae:
                    lam_sum = lam_sum * not_done  # the sums restart where an episode ended
                    reward_sum = reward_sum * not_done
                    value_sum = value_sum * not_done
                    lam_sum = 1 + lam * lam_sum
                    reward_sum = lam * gamma * reward_sum + lam_sum * rewards[t]
                    value_sum = lam * gamma * value_sum + gamma * real_next_value
                    advantages[t] = (reward_sum + value_sum) / lam_sum - values[t]
                else:
                    delta = rewards[t] + gamma * real_next_value - values[t]
                    advantages[t] = last_advantage = delta + gamma * lam * not_done * last_advantage
            returns = advantages + values

        # PPO update over shuffled minibatches of the flattened batch (§5.3).
        b_obs = {k: v.reshape(-1, *v.shape[2:]) for k, v in obs.items()}
        b_logprobs, b_actions = logprobs.reshape(-1), actions.reshape(-1, action_dim)
        b_advantages, b_returns = advantages.reshape(-1), returns.reshape(-1)
        b_values = values.reshape(-1)
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
                logratio = newlogprob - b_logprobs[mb]
                ratio = logratio.exp()
                with torch.no_grad():
                    old_approx_kl = (-logratio).mean()
                    approx_kl = ((ratio - 1) - logratio).mean()
                    clipfrac = ((ratio - 1.0).abs() > args.clip_coef).float().mean()
                mb_advantages = b_advantages[mb]
                if args.norm_adv:
                    mb_advantages = ((mb_advantages - mb_advantages.mean())
                                     / (mb_advantages.std() + 1e-8))
                pg_loss = torch.max(
                    -mb_advantages * ratio,
                    -mb_advantages * torch.clamp(ratio, 1 - args.clip_coef, 1 + args.clip_coef),
                ).mean()
                newvalue, mb_values, mb_returns = newvalue.view(-1), b_values[mb], b_returns[mb]
                if args.clip_vloss:
                    v_clipped = mb_values + torch.clamp(newvalue - mb_values, -args.clip_coef,
                                                        args.clip_coef)
                    v_loss = 0.5 * torch.max((newvalue - mb_returns) ** 2,
                                             (v_clipped - mb_returns) ** 2).mean()
                else:
                    v_loss = 0.5 * ((newvalue - mb_returns) ** 2).mean()
                entropy_loss = entropy.mean()
                loss = pg_loss - args.ent_coef * entropy_loss + v_loss * args.vf_coef
                clipfracs.append(clipfrac.item())
                if args.target_kl is not None and approx_kl > args.target_kl:
                    stop = True  # upstream checks before stepping: this minibatch is skipped
                    break
                optimizer.zero_grad()
                loss.backward()
                # Before the clip: what each network's loss asked for.
                grad_norms = agent.head_grad_norms()
                nn.utils.clip_grad_norm_(agent.parameters(), args.max_grad_norm)
                optimizer.step()
            if stop:
                break
        update_time = time.time() - update_start

        # Log the iteration (losses of its last minibatch, as upstream; the gradient norms of the
        # last one that stepped), write resume.pt, stop if --time-limit has passed.
        y_pred, y_true = b_values.cpu().numpy(), b_returns.cpu().numpy()
        var_y = np.var(y_true)
        sps = int((global_step - start_step) / (time.time() - start_time))
        explained_var = np.nan if var_y == 0 else 1 - np.var(y_true - y_pred) / var_y
        log.scalars({
            "charts/learning_rate": optimizer.param_groups[0]["lr"],
            "charts/global_step": global_step,
            "losses/value_loss": v_loss.item(),
            "losses/policy_loss": pg_loss.item(),
            "losses/entropy": entropy_loss.item(),
            "losses/old_approx_kl": old_approx_kl.item(),
            "losses/approx_kl": approx_kl.item(),
            "losses/clipfrac": float(np.mean(clipfracs)),
            "losses/explained_variance": explained_var,
            **{f"losses/{name}": norm.item() for name, norm in grad_norms.items()},
            "charts/SPS": sps,
            "time/step": global_step,
            "time/update_time": update_time,
            "time/rollout_time": rollout_time,
            "time/rollout_fps": num_envs * args.num_steps / rollout_time,
        }, global_step)
        print(f"iteration {iteration}/{args.num_iterations}: step {global_step}, SPS {sps}, "
              f"rollout {rollout_time:.1f} s, update {update_time:.1f} s", flush=True)
        if args.save_model:
            save_resume_state(save_dir, agent=agent, optimizer=optimizer, iteration=iteration,
                              global_step=global_step, saves=saves, settings=settings)
        if (args.time_limit is not None and time.time() - launched >= args.time_limit
                and iteration < args.num_iterations):
            print(f"--time-limit reached; go on with: --resume {save_dir / RESUME_FILE} "
                  "(and the same flags)")
            close_run()
            return {"stopped_early": 1.0}

    result = evaluate_agent(global_step)
    if args.save_model:
        save_atomically(agent.state_dict(), save_dir / "final_ckpt.pt")
    print(f"logs and checkpoints in {save_dir}")
    close_run()
    return result


if __name__ == "__main__":
    main()
