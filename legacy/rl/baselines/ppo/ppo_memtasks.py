"""PPO-MLP on the MIKASA-Robo RL tasks (``ppo_baselines.md``): the release's
``ppo_memtasks.py``, on CPU-simulated envs.

The recipe is ManiSkill3's / CleanRL's PPO (finite-horizon GAE, no termination, one batch
of ``num_envs`` envs). Upstream steps 1,024 GPU-simulated envs; here ``num_envs`` CPU envs
run in worker processes behind one batched env (``mikasa_robo_rl.vector_env``), and the
networks run on the GPU when there is one.

    python legacy/rl/baselines/ppo/ppo_memtasks.py --env-id RememberColor3-v0 --include-state \\
        --num-envs 16 --num-steps 60 --total-timesteps 2_000_000
    python legacy/rl/baselines/ppo/ppo_memtasks.py --env_id=RememberColor3-v0 --include-rgb --include-joints
    python legacy/rl/baselines/ppo/ppo_memtasks.py --env-id RememberColor3-v0 --include-state \\
        --evaluate --checkpoint path/to/final_ckpt.pt

Needs ``pip install "mikasa-robo-rl[train]"`` (tyro, TensorBoard); ``--track`` also wandb.
"""

from __future__ import annotations

import os
import random
import sys
import time
from collections import defaultdict
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
import tyro
from torch import nn, optim

from mikasa_robo_rl.agents import Agent, AgentStateOnly, flatten_state_obs
from mikasa_robo_rl.manifest import get_rl_task
from mikasa_robo_rl.vector_env import CpuVectorEnv, SubEnvSpec

if Path("wandb_config.yaml").exists():  # the release's way of passing the W&B key
    import yaml

    os.environ["WANDB_API_KEY"] = yaml.safe_load(Path("wandb_config.yaml").read_text())["wandb_api"]


@dataclass
class Args:
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
    """record eval videos (not yet implemented for CPU envs: ignored, with a notice)"""
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


def observation_mode(args: Args) -> str:
    """MODE of ``ppo_baselines.md`` §3.1 from the include flags (its errors included)."""
    if not (args.include_state or args.include_rgb):
        raise ValueError("at least one of --include-state / --include-rgb is needed")
    if args.include_joints and not args.include_rgb:
        raise ValueError("--include-joints needs --include-rgb")
    if args.include_state and args.include_rgb:
        raise NotImplementedError("state + rgb observations are not supported")
    if args.include_state:
        if args.include_oracle:
            raise NotImplementedError("the state already contains the oracle information")
        return "state"
    return "rgb" + ("_joints" if args.include_joints else "") + ("_oracle" if args.include_oracle else "")


def parse_args(argv: list[str]) -> Args:
    """tyro's parse, also accepting the run scripts' underscore spellings (``--env_id``)."""
    dashed = []
    for a in argv:
        if a.startswith("--"):
            name, eq, value = a.partition("=")
            a = name.replace("_", "-") + eq + value
        dashed.append(a)
    return tyro.cli(Args, args=dashed)


def finite_horizon_advantages(rewards, values, dones, final_values, next_value, next_done, gamma, lam):
    """``ppo_baselines.md`` §5.2, finite-horizon variant: per step, the λ-weighted average of
    the n-step returns still inside the episode, normalised by the weights available."""
    num_steps = rewards.shape[0]
    advantages = torch.zeros_like(rewards)
    lam_sum = rew_sum = val_sum = torch.zeros_like(next_value)
    for t in reversed(range(num_steps)):
        not_done = 1.0 - (next_done if t == num_steps - 1 else dones[t + 1])
        following = next_value if t == num_steps - 1 else values[t + 1]
        real_next_value = not_done * following + final_values[t]
        lam_sum, rew_sum, val_sum = lam_sum * not_done, rew_sum * not_done, val_sum * not_done
        lam_sum = 1 + lam * lam_sum
        rew_sum = lam * gamma * rew_sum + lam_sum * rewards[t]
        val_sum = lam * gamma * val_sum + gamma * real_next_value
        advantages[t] = (rew_sum + val_sum) / lam_sum - values[t]
    return advantages


def gae_advantages(rewards, values, dones, final_values, next_value, next_done, gamma, lam):
    """Standard GAE (``--no-finite-horizon-gae``)."""
    num_steps = rewards.shape[0]
    advantages = torch.zeros_like(rewards)
    last = torch.zeros_like(next_value)
    for t in reversed(range(num_steps)):
        not_done = 1.0 - (next_done if t == num_steps - 1 else dones[t + 1])
        following = next_value if t == num_steps - 1 else values[t + 1]
        delta = rewards[t] + gamma * (not_done * following + final_values[t]) - values[t]
        advantages[t] = last = delta + gamma * lam * not_done * last
    return advantages


def main(argv: list[str] | None = None) -> dict[str, float]:
    args = parse_args(sys.argv[1:] if argv is None else argv)
    mode = observation_mode(args)
    horizon = get_rl_task(args.env_id).max_episode_steps  # unknown ids fail here, naming close ones
    if args.evaluate and not args.checkpoint:
        raise ValueError("--evaluate needs --checkpoint")
    num_envs = 1 if args.evaluate else args.num_envs
    args.batch_size = num_envs * args.num_steps
    args.minibatch_size = args.batch_size // args.num_minibatches
    args.num_iterations = args.total_timesteps // args.batch_size
    if args.minibatch_size < 1:
        raise ValueError(f"num_envs * num_steps = {args.batch_size} is smaller than num_minibatches = {args.num_minibatches}")
    if args.capture_video:
        print("note: --capture-video is not implemented for CPU envs yet; no videos are written")
    stamp = time.strftime("%Y%m%d_%H%M%S")
    script = Path(__file__).stem
    run_name = (f"{args.exp_name}" if args.exp_name else f"{args.env_id}__{script}") + f"__{args.seed}__{mode}__{stamp}"
    save_dir = Path("checkpoints/ppo_memtasks") / mode / args.reward_mode / args.env_id / run_name / stamp

    # Seeding, device.
    random.seed(args.seed)
    np.random.seed(args.seed)
    torch.manual_seed(args.seed)
    torch.backends.cudnn.deterministic = args.torch_deterministic
    device = torch.device("cuda" if torch.cuda.is_available() and args.cuda else "cpu")

    # Envs: CPU sub-envs in worker processes, batched (ManiSkillVectorEnv's interface).
    def spec(reconfiguration_freq, partial_reset):
        return SubEnvSpec(
            args.env_id, mode, reward_mode=args.reward_mode, noop_steps=args.noop_steps,
            reconfiguration_freq=reconfiguration_freq, ignore_terminations=not partial_reset,
        )

    envs = CpuVectorEnv(spec(args.reconfiguration_freq, args.partial_reset), num_envs, args.num_workers, device)
    eval_envs = CpuVectorEnv(
        spec(args.eval_reconfiguration_freq, args.eval_partial_reset), args.num_eval_envs, args.num_workers, device
    )
    print(f"{args.env_id}: MODE {mode}, horizon {horizon}, {num_envs} envs, {args.num_eval_envs} eval envs, device {device}")

    # Logging.
    from torch.utils.tensorboard import SummaryWriter

    writer = SummaryWriter(str(save_dir))
    writer.add_text(
        "hyperparameters", "|param|value|\n|-|-|\n" + "\n".join(f"|{k}|{v}|" for k, v in vars(args).items())
    )
    if args.track:
        import wandb

        wandb.init(project=args.wandb_project_name, entity=args.wandb_entity, config=vars(args), name=run_name,
                   group="PPO", tags=["ppo", "walltime_efficient"], save_code=True)

    def log(name: str, value: float, step: int) -> None:
        writer.add_scalar(name, value, step)
        if args.track:
            wandb.log({name: value}, step=step)

    # Agent.
    next_obs, _ = envs.reset(seed=args.seed)
    eval_obs, _ = eval_envs.reset(seed=args.seed)
    action_dim = int(np.prod(envs.single_action_space.shape))
    if mode == "state":
        agent = AgentStateOnly(flatten_state_obs(next_obs).shape[1], action_dim).to(device)
        agent_input = flatten_state_obs
    else:
        agent = Agent(next_obs, action_dim).to(device)
        agent_input = lambda obs: obs  # noqa: E731
    if args.checkpoint:
        agent.load_state_dict(torch.load(args.checkpoint, map_location=device, weights_only=True))
    optimizer = optim.Adam(agent.parameters(), lr=args.learning_rate, eps=1e-5)

    # Rollout storage.
    obs = {k: torch.zeros((args.num_steps, *v.shape), dtype=v.dtype, device=device) for k, v in next_obs.items()}
    actions = torch.zeros((args.num_steps, num_envs, action_dim), device=device)
    logprobs = torch.zeros((args.num_steps, num_envs), device=device)
    rewards = torch.zeros((args.num_steps, num_envs), device=device)
    dones = torch.zeros((args.num_steps, num_envs), device=device)
    values = torch.zeros((args.num_steps, num_envs), device=device)

    def evaluate(global_step: int) -> dict[str, float]:
        """One pass of num_eval_steps deterministic steps; mean of each finished-episode metric."""
        nonlocal eval_obs
        metrics = defaultdict(list)
        eval_obs, _ = eval_envs.reset()
        agent.eval()
        for _ in range(args.num_eval_steps):
            with torch.no_grad():
                eval_obs, _, _, _, info = eval_envs.step(agent.get_action(agent_input(eval_obs), deterministic=True))
            if "final_info" in info:
                mask = info["_final_info"]
                for k, v in info["final_info"]["episode"].items():
                    metrics[k].append(v[mask].float())
        agent.train()
        means = {k: torch.cat(v).mean().item() for k, v in metrics.items()}
        episodes = len(torch.cat(metrics["success_once"])) if metrics else 0
        print(f"eval @ {global_step}: {episodes} episodes, " + ", ".join(f"{k} {v:.3f}" for k, v in means.items()))
        for k, v in means.items():
            log(f"eval/{k}", v, global_step)
        return means | {"episodes": episodes}

    if args.evaluate:
        result = evaluate(0)
        envs.close(), eval_envs.close(), writer.close()
        return result

    global_step, start_time, saves, last_eval = 0, time.time(), 0, {}
    next_done = torch.zeros(num_envs, device=device)
    for iteration in range(1, args.num_iterations + 1):
        final_values = torch.zeros((args.num_steps, num_envs), device=device)
        if iteration % args.eval_freq == 1:
            last_eval = evaluate(global_step)
            if args.save_model:
                save_dir.mkdir(parents=True, exist_ok=True)
                torch.save(agent.state_dict(), save_dir / f"ckpt_{saves}_{iteration}.pt")
                saves += 1
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
            estimate = finite_horizon_advantages if args.finite_horizon_gae else gae_advantages
            advantages = estimate(rewards, values, dones, final_values, next_value, next_done,
                                  args.gamma, args.gae_lambda)
            returns = advantages + values

        # PPO update over shuffled minibatches of the flattened batch.
        b_obs = {k: v.reshape(-1, *v.shape[2:]) for k, v in obs.items()}
        b_logprobs, b_actions = logprobs.reshape(-1), actions.reshape(-1, action_dim)
        b_advantages, b_returns, b_values = advantages.reshape(-1), returns.reshape(-1), values.reshape(-1)
        update_start = time.time()
        clipfracs = []
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
                    clipfracs.append(((ratio - 1.0).abs() > args.clip_coef).float().mean().item())
                if args.target_kl is not None and approx_kl > args.target_kl:
                    stop = True  # upstream checks before stepping: this minibatch is skipped
                    break
                mb_advantages = b_advantages[mb]
                if args.norm_adv:
                    mb_advantages = (mb_advantages - mb_advantages.mean()) / (mb_advantages.std() + 1e-8)
                pg_loss = torch.max(
                    -mb_advantages * ratio, -mb_advantages * torch.clamp(ratio, 1 - args.clip_coef, 1 + args.clip_coef)
                ).mean()
                newvalue = newvalue.view(-1)
                if args.clip_vloss:
                    clipped = b_values[mb] + torch.clamp(newvalue - b_values[mb], -args.clip_coef, args.clip_coef)
                    v_loss = 0.5 * torch.max((newvalue - b_returns[mb]) ** 2, (clipped - b_returns[mb]) ** 2).mean()
                else:
                    v_loss = 0.5 * ((newvalue - b_returns[mb]) ** 2).mean()
                loss = pg_loss - args.ent_coef * entropy.mean() + v_loss * args.vf_coef
                optimizer.zero_grad()
                loss.backward()
                nn.utils.clip_grad_norm_(agent.parameters(), args.max_grad_norm)
                optimizer.step()
            if stop:
                break
        update_time = time.time() - update_start

        y_pred, y_true = b_values.cpu().numpy(), b_returns.cpu().numpy()
        var_y = np.var(y_true)
        explained_var = np.nan if var_y == 0 else 1 - np.var(y_true - y_pred) / var_y
        sps = int(global_step / (time.time() - start_time))
        for name, value in {
            "charts/learning_rate": optimizer.param_groups[0]["lr"], "charts/global_step": global_step,
            "losses/value_loss": v_loss.item(), "losses/policy_loss": pg_loss.item(),
            "losses/entropy": entropy.mean().item(), "losses/old_approx_kl": old_approx_kl.item(),
            "losses/approx_kl": approx_kl.item(), "losses/clipfrac": float(np.mean(clipfracs)) if clipfracs else 0.0,
            "losses/explained_variance": explained_var, "charts/SPS": sps,
            "time/step": global_step, "time/update_time": update_time, "time/rollout_time": rollout_time,
            "time/rollout_fps": num_envs * args.num_steps / rollout_time,
        }.items():
            log(name, value, global_step)
        print(f"iteration {iteration}/{args.num_iterations}: step {global_step}, SPS {sps}, "
              f"rollout {rollout_time:.1f} s, update {update_time:.1f} s", flush=True)

    last_eval = evaluate(global_step)
    if args.save_model:
        save_dir.mkdir(parents=True, exist_ok=True)
        torch.save(agent.state_dict(), save_dir / "final_ckpt.pt")
        print(f"checkpoints in {save_dir}")
    envs.close(), eval_envs.close(), writer.close()
    return last_eval


if __name__ == "__main__":
    main()
