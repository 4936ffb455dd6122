"""Plumbing shared by the PPO baselines (``legacy/rl/baselines/ppo/``): their flags, the
observation-mode rules, advantage estimation, the batched CPU envs and the run's logs and
checkpoint directory (``ppo_baselines.md`` §2-§3, §5.2, §7). The trainers keep the
algorithm; this module keeps what they share. Needs the ``train`` extra (tyro, TensorBoard).
"""

from __future__ import annotations

import os
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, TypeVar

import torch
import tyro

from mikasa_robo_rl.vector_env import CpuVectorEnv, SubEnvSpec

__all__ = [
    "PPOArgs", "RunLog", "finite_horizon_advantages", "gae_advantages", "make_envs", "observation_mode",
    "parse_args", "run_directory",
]

T = TypeVar("T")


@dataclass
class PPOArgs:
    """The flags of both trainers (``ppo_baselines.md`` §2)."""

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


def observation_mode(args: PPOArgs) -> str:
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


def parse_args(args_class: type[T], argv: list[str]) -> T:
    """tyro's parse of ``args_class``, also accepting the run scripts' underscore spellings
    (``--env_id``)."""
    dashed = []
    for a in argv:
        if a.startswith("--"):
            name, eq, value = a.partition("=")
            a = name.replace("_", "-") + eq + value
        dashed.append(a)
    return tyro.cli(args_class, args=dashed)


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


def make_envs(args: PPOArgs, mode: str, num_envs: int, device: torch.device) -> tuple[CpuVectorEnv, CpuVectorEnv]:
    """(training envs, eval envs): CPU sub-envs in worker processes, batched (§3.2)."""

    def spec(reconfiguration_freq: int | None, partial_reset: bool) -> SubEnvSpec:
        return SubEnvSpec(
            args.env_id, mode, reward_mode=args.reward_mode, noop_steps=args.noop_steps,
            reconfiguration_freq=reconfiguration_freq, ignore_terminations=not partial_reset,
        )

    envs = CpuVectorEnv(spec(args.reconfiguration_freq, args.partial_reset), num_envs, args.num_workers, device)
    try:
        eval_envs = CpuVectorEnv(
            spec(args.eval_reconfiguration_freq, args.eval_partial_reset), args.num_eval_envs, args.num_workers, device
        )
    except BaseException:
        envs.close()
        raise
    return envs, eval_envs


def run_directory(args: PPOArgs, mode: str, script: str) -> tuple[str, Path]:
    """(run name, run directory) of §7: ``checkpoints/ppo_memtasks/<MODE>/<reward_mode>/
    <env_id>/<run_name>/<TIME>`` under the working directory."""
    stamp = time.strftime("%Y%m%d_%H%M%S")
    run_name = (args.exp_name or f"{args.env_id}__{script}") + f"__{args.seed}__{mode}__{stamp}"
    return run_name, Path("checkpoints/ppo_memtasks") / mode / args.reward_mode / args.env_id / run_name / stamp


class RunLog:
    """TensorBoard scalars (and W&B with ``--track``), with the hyper-parameter table."""

    def __init__(self, args: PPOArgs, run_name: str, directory: Path) -> None:
        from torch.utils.tensorboard import SummaryWriter

        if Path("wandb_config.yaml").exists():  # the release's way of passing the W&B key
            import yaml

            os.environ["WANDB_API_KEY"] = yaml.safe_load(Path("wandb_config.yaml").read_text())["wandb_api"]
        self.writer = SummaryWriter(str(directory))
        self.writer.add_text(
            "hyperparameters", "|param|value|\n|-|-|\n" + "\n".join(f"|{k}|{v}|" for k, v in vars(args).items())
        )
        self.wandb: Any = None
        if args.track:
            import wandb

            wandb.init(project=args.wandb_project_name, entity=args.wandb_entity, config=vars(args), name=run_name,
                       group="PPO", tags=["ppo", "walltime_efficient"], save_code=True)
            self.wandb = wandb

    def scalar(self, name: str, value: float, step: int) -> None:
        """Log ``value`` under ``name`` at ``step``."""
        self.writer.add_scalar(name, value, step)
        if self.wandb is not None:
            self.wandb.log({name: value}, step=step)

    def close(self) -> None:
        """Flush and close the logs."""
        self.writer.close()
        if self.wandb is not None:
            self.wandb.finish()
