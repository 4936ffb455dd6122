"""Plumbing shared by the PPO baselines (``legacy/rl/baselines/ppo/``): their flags, the
observation-mode rules, advantage estimation, the batched CPU envs and the run's logs and
checkpoint directory (``ppo_baselines.md`` §2-§3, §5.2, §7). The trainers keep the
algorithm; this module keeps what they share. Needs the ``train`` extra (tyro, TensorBoard).
"""

from __future__ import annotations

import os
import random
import time
from collections import defaultdict
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, TypeVar

import numpy as np
import torch
import tyro

from mikasa_robo_rl.agents import INITIAL_LOGSTD
from mikasa_robo_rl.manifest import trainable_horizon
from mikasa_robo_rl.vector_env import CpuVectorEnv, SubEnvSpec

__all__ = [
    "PPOArgs", "Run", "RunLog", "clipped_ppo_loss", "estimate_advantages", "evaluate", "log_iteration",
    "make_envs", "observation_mode", "parse_args", "run_directory", "start_run",
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
    """the actor's initial log std (an extension; upstream's -0.5 by default), for exploration studies"""
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
    resume: str | None = None
    """a run's resume.pt: go on with that run (networks, optimizer, step counters, RNG, run directory) at this --learning-rate"""
    resume_min_logstd: float | None = None
    """with --resume: raise the policy's log std to at least this in every action dimension (an
    extension: re-opens the exploration of a run whose action noise has collapsed; default: keep)"""
    time_limit: float | None = None
    """stop after the iteration that passes this many seconds since the trainer started (env workers' start
    included, so that a time-limited job can be sized), resume.pt saved (to chain time-limited jobs)"""


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


def estimate_advantages(
    rewards: torch.Tensor, values: torch.Tensor, dones: torch.Tensor, final_values: torch.Tensor,
    next_value: torch.Tensor, next_done: torch.Tensor, gamma: float, lam: float, finite_horizon: bool = True,
) -> torch.Tensor:
    """Advantages of a rollout (§5.2), ``(num_steps, num_envs)``; ``final_values`` holds
    V(final observation) where an episode ended. ``finite_horizon``: per step, the
    λ-weighted average of the n-step returns still inside the episode, normalised by the
    weights available; else standard GAE (``--no-finite-horizon-gae``)."""
    num_steps = rewards.shape[0]
    advantages = torch.zeros_like(rewards)
    last = lam_sum = rew_sum = val_sum = torch.zeros_like(next_value)
    for t in reversed(range(num_steps)):
        not_done = 1.0 - (next_done if t == num_steps - 1 else dones[t + 1])
        following = next_value if t == num_steps - 1 else values[t + 1]
        real_next_value = not_done * following + final_values[t]
        if finite_horizon:
            lam_sum, rew_sum, val_sum = lam_sum * not_done, rew_sum * not_done, val_sum * not_done
            lam_sum = 1 + lam * lam_sum
            rew_sum = lam * gamma * rew_sum + lam_sum * rewards[t]
            val_sum = lam * gamma * val_sum + gamma * real_next_value
            advantages[t] = (rew_sum + val_sum) / lam_sum - values[t]
        else:
            delta = rewards[t] + gamma * real_next_value - values[t]
            advantages[t] = last = delta + gamma * lam * not_done * last
    return advantages


def make_envs(
    args: PPOArgs, mode: str, num_envs: int, device: torch.device, save_dir: Path
) -> tuple[CpuVectorEnv, CpuVectorEnv]:
    """(training envs, eval envs): CPU sub-envs in worker processes, batched (§3.2). With
    ``--capture-video`` the first eval sub-env records its episodes: to ``save_dir/videos``,
    or with ``--evaluate`` (trajectories too) to ``test_videos`` beside the checkpoint."""

    def spec(reconfiguration_freq: int | None, partial_reset: bool, **video: Any) -> SubEnvSpec:
        return SubEnvSpec(
            args.env_id, mode, reward_mode=args.reward_mode, noop_steps=args.noop_steps,
            reconfiguration_freq=reconfiguration_freq, ignore_terminations=not partial_reset, **video,
        )

    video: dict[str, Any] = {}
    if args.capture_video:
        video_dir = Path(args.checkpoint).parent / "test_videos" if args.evaluate else save_dir / "videos"
        video = dict(video_dir=str(video_dir), save_trajectory=args.evaluate, render_mode=args.render_mode,
                     max_steps_per_video=args.num_eval_steps)
    envs = CpuVectorEnv(spec(args.reconfiguration_freq, args.partial_reset), num_envs, args.num_workers, device)
    try:
        eval_envs = CpuVectorEnv(
            spec(args.eval_reconfiguration_freq, args.eval_partial_reset, **video),
            args.num_eval_envs, args.num_workers, device,
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


def clipped_ppo_loss(
    args: PPOArgs,
    newlogprob: torch.Tensor,
    entropy: torch.Tensor,
    newvalue: torch.Tensor,
    logprobs: torch.Tensor,
    advantages: torch.Tensor,
    returns: torch.Tensor,
    values: torch.Tensor,
) -> tuple[torch.Tensor, dict[str, torch.Tensor]]:
    """PPO's minibatch loss (§5.3): clipped policy loss, (clipped) value loss, entropy bonus.

    Returns the loss and its parts: ``pg_loss``, ``v_loss``, ``entropy``, ``old_approx_kl``,
    ``approx_kl``, ``clipfrac`` (the last three without gradients).
    """
    logratio = newlogprob - logprobs
    ratio = logratio.exp()
    with torch.no_grad():
        stats = dict(
            old_approx_kl=(-logratio).mean(),
            approx_kl=((ratio - 1) - logratio).mean(),
            clipfrac=((ratio - 1.0).abs() > args.clip_coef).float().mean(),
        )
    if args.norm_adv:
        advantages = (advantages - advantages.mean()) / (advantages.std() + 1e-8)
    pg_loss = torch.max(
        -advantages * ratio, -advantages * torch.clamp(ratio, 1 - args.clip_coef, 1 + args.clip_coef)
    ).mean()
    newvalue = newvalue.view(-1)
    if args.clip_vloss:
        clipped = values + torch.clamp(newvalue - values, -args.clip_coef, args.clip_coef)
        v_loss = 0.5 * torch.max((newvalue - returns) ** 2, (clipped - returns) ** 2).mean()
    else:
        v_loss = 0.5 * ((newvalue - returns) ** 2).mean()
    loss = pg_loss - args.ent_coef * entropy.mean() + v_loss * args.vf_coef
    return loss, stats | dict(pg_loss=pg_loss, v_loss=v_loss, entropy=entropy.mean())


def log_iteration(
    log: RunLog, step: int, lr: float, stats: dict[str, torch.Tensor], clipfracs: list[float],
    values: torch.Tensor, returns: torch.Tensor, sps: int, rollout_time: float, update_time: float,
    rollout_steps: int,
) -> None:
    """The per-iteration scalars of §5.3 (losses from the last minibatch, as upstream)."""
    y_pred, y_true = values.cpu().numpy(), returns.cpu().numpy()
    var_y = np.var(y_true)
    scalars = {
        "charts/learning_rate": lr, "charts/global_step": step,
        "losses/value_loss": stats["v_loss"].item(), "losses/policy_loss": stats["pg_loss"].item(),
        "losses/entropy": stats["entropy"].item(), "losses/old_approx_kl": stats["old_approx_kl"].item(),
        "losses/approx_kl": stats["approx_kl"].item(),
        "losses/clipfrac": float(np.mean(clipfracs)) if clipfracs else 0.0,
        "losses/explained_variance": np.nan if var_y == 0 else 1 - np.var(y_true - y_pred) / var_y,
        "charts/SPS": sps, "time/step": step, "time/update_time": update_time,
        "time/rollout_time": rollout_time, "time/rollout_fps": rollout_steps / rollout_time,
    }
    # The gradient norms of the update's last stepped minibatch (none when --target-kl
    # stopped the update before its first step).
    for key in ("actor_grad_norm", "critic_grad_norm"):
        if key in stats:
            scalars[f"losses/{key}"] = stats[key].item()
    for name, value in scalars.items():
        log.scalar(name, value, step)


def evaluate(
    eval_envs: CpuVectorEnv,
    policy: Callable[[dict[str, torch.Tensor], torch.Tensor], torch.Tensor],
    num_eval_steps: int,
    log: RunLog,
    global_step: int,
) -> dict[str, float]:
    """One evaluation pass (§6): reset the eval envs, run ``num_eval_steps`` steps of
    ``policy(obs, done)`` (deterministic actions; ``done`` marks observations that start an
    episode), log the mean of each finished episode's metric as ``eval/<metric>``.
    Returns those means and ``episodes``, the number of finished episodes."""
    metrics: dict[str, list[torch.Tensor]] = defaultdict(list)
    obs, _ = eval_envs.reset()
    done = torch.ones(eval_envs.num_envs, device=eval_envs.device)
    for _ in range(num_eval_steps):
        with torch.no_grad():
            obs, _, terminated, truncated, info = eval_envs.step(policy(obs, done))
        done = torch.logical_or(terminated, truncated).float()
        if "final_info" in info:
            mask = info["_final_info"]
            for k, v in info["final_info"]["episode"].items():
                metrics[k].append(v[mask].float())
    means = {k: torch.cat(v).mean().item() for k, v in metrics.items()}
    episodes = len(torch.cat(metrics["success_once"])) if metrics else 0
    print(f"eval @ {global_step}: {episodes} episodes, " + ", ".join(f"{k} {v:.3f}" for k, v in means.items()))
    for k, v in means.items():
        log.scalar(f"eval/{k}", v, global_step)
    return means | {"episodes": episodes}


@dataclass
class Run:
    """What a trainer works with once set up by :func:`start_run`."""

    args: PPOArgs
    mode: str
    num_envs: int
    device: torch.device
    envs: CpuVectorEnv
    eval_envs: CpuVectorEnv
    log: RunLog
    save_dir: Path
    resumed: dict[str, Any] | None = None
    """the loaded resume.pt of a ``--resume`` run"""
    saves: int = 0
    start_time: float = field(default_factory=time.time)
    launched: float = field(default_factory=time.time)
    """when the trainer began starting its env workers (``--time-limit`` counts from here)"""
    start_step: int = 0
    agent: torch.nn.Module | None = None
    optimizer: torch.optim.Optimizer | None = None

    @property
    def env_seed(self) -> int:
        """Seed of the first env reset: ``--seed``, moved on by the iteration of a resumed
        run (so that it does not replay the first piece's episodes)."""
        return self.args.seed + (self.resumed["iteration"] if self.resumed else 0)

    def restore(self, agent: torch.nn.Module, optimizer: torch.optim.Optimizer) -> tuple[int, int]:
        """Keep ``agent`` and ``optimizer`` for the resume state; with ``--resume`` load
        theirs and the RNG. Returns (first iteration, global step) to go on from."""
        self.agent, self.optimizer = agent, optimizer
        if not self.resumed:
            return 1, 0
        state = self.resumed
        agent.load_state_dict(state["agent"])
        optimizer.load_state_dict(state["optimizer"])
        # The command's --learning-rate wins over the saved one (Adam's moments are kept unless the
        # reward scale, --vf-coef or --reward-mode changed, _adapt_to_new_units): a run can go on at a lower rate,
        # where a fresh optimizer from --checkpoint would first take full-size steps in every weight.
        for group in optimizer.param_groups:
            group["lr"] = self.args.learning_rate
        self._adapt_to_new_units(agent, optimizer, state)
        if self.args.resume_min_logstd is not None:
            agent.floor_logstd(self.args.resume_min_logstd)
            print(f"log std raised to at least {self.args.resume_min_logstd}: {[round(v, 3) for v in agent.actor_logstd.flatten().tolist()]}")
        torch.set_rng_state(state["torch_rng"])
        np.random.set_state(state["numpy_rng"])
        self.saves, self.start_step = state["saves"], state["global_step"]
        print(f"resumed {self.save_dir} after iteration {state['iteration']} (step {state['global_step']})")
        return state["iteration"] + 1, state["global_step"]

    def _adapt_to_new_units(self, agent: torch.nn.Module, optimizer: torch.optim.Optimizer, state: dict) -> None:
        """A run resumed at another ``--reward-scale``, ``--vf-coef`` or ``--reward-mode`` than the
        resume ``state`` was saved with (recorded since 2026-11-27, 2026-11-29 and later on
        2026-11-29; an older one counts as unchanged). Another reward scale: scale the critic's
        outputs to the new returns, or the first updates would fit values off by the ratio and
        their advantages would be noise. Another reward mode has no such ratio: the critic refits.
        Any of them: start the optimizer's moments afresh. They are all in the old units: the
        critic's directly, the actor's through the one gradient-norm clip over both networks,
        whose factor the critic's gradient sets; kept, they made the first steps of a run resumed
        at 1/100 of its scale ~100x too large (approx_kl 0.3-1.1 an iteration, not ~0.01), a
        critic whose loss weight fell 1,000-fold would barely move for the ~14,000 Adam steps its
        second moment (β2 0.999) takes to forget the old gradients' squares, and one whose
        gradients shrank ~80-fold going from dense to sparse rewards barely moved either (explained variance
        -2.7 after 30 updates, BunchOfColors3-v0 at 28.1 M)."""
        saved_scale, saved_vf_coef, saved_mode = (state.get(k) for k in ("reward_scale", "vf_coef", "reward_mode"))
        new_scale = saved_scale is not None and saved_scale != self.args.reward_scale
        new_vf_coef = saved_vf_coef is not None and saved_vf_coef != self.args.vf_coef
        new_mode = saved_mode is not None and saved_mode != self.args.reward_mode
        if new_scale:
            factor = self.args.reward_scale / saved_scale
            agent.scale_values(factor)
            print(f"--reward-scale {self.args.reward_scale} (saved with {saved_scale}): critic outputs scaled by {factor:g}")
        if new_vf_coef:
            print(f"--vf-coef {self.args.vf_coef} (saved with {saved_vf_coef})")
        if new_mode:
            print(f"--reward-mode {self.args.reward_mode} (saved with {saved_mode}): the critic refits")
        if new_scale or new_vf_coef or new_mode:
            optimizer.state.clear()
            print("optimizer moments reset")

    def save(self, agent: torch.nn.Module, name: str | None = None, iteration: int | None = None) -> None:
        """Checkpoint ``agent`` (with ``--save-model``): ``name``, or the next periodic
        ``ckpt_<k>_<iteration>.pt``."""
        if not self.args.save_model:
            return
        if name is None:
            name = f"ckpt_{self.saves}_{iteration}.pt"
            self.saves += 1
        _save_atomically(agent.state_dict(), self.save_dir / name)

    def end_iteration(
        self, iteration: int, global_step: int, lr: float, stats: dict[str, torch.Tensor], clipfracs: list[float],
        values: torch.Tensor, returns: torch.Tensor, rollout_time: float, update_time: float,
    ) -> bool:
        """Log an iteration's scalars (§5.3), print its progress line and write
        ``resume.pt``. True when ``--time-limit`` has passed: the trainer then stops."""
        sps = int((global_step - self.start_step) / (time.time() - self.start_time))
        log_iteration(self.log, global_step, lr, stats, clipfracs, values, returns, sps, rollout_time, update_time,
                      self.num_envs * self.args.num_steps)
        print(f"iteration {iteration}/{self.args.num_iterations}: step {global_step}, SPS {sps}, "
              f"rollout {rollout_time:.1f} s, update {update_time:.1f} s", flush=True)
        if self.args.save_model and self.agent is not None and self.optimizer is not None:
            _save_atomically(
                dict(agent=self.agent.state_dict(), optimizer=self.optimizer.state_dict(), iteration=iteration,
                     global_step=global_step, saves=self.saves, save_dir=str(self.save_dir),
                     env_id=self.args.env_id, mode=self.mode, reward_scale=self.args.reward_scale,
                     vf_coef=self.args.vf_coef, reward_mode=self.args.reward_mode,
                     torch_rng=torch.get_rng_state(),
                     numpy_rng=np.random.get_state()),
                self.save_dir / RESUME_FILE,
            )
        limit = self.args.time_limit
        return limit is not None and time.time() - self.launched >= limit and iteration < self.args.num_iterations

    def stop_early(self) -> dict[str, float]:
        """End a run cut by ``--time-limit`` (no final eval); says how to go on."""
        print(f"--time-limit reached; go on with: --resume {self.save_dir / RESUME_FILE} (and the same flags)")
        self.close()
        return {"stopped_early": 1.0}

    def finish(self, agent: torch.nn.Module, final_eval: dict[str, float]) -> dict[str, float]:
        """Save ``final_ckpt.pt``, close everything; returns ``final_eval``."""
        self.save(agent, "final_ckpt.pt")
        print(f"logs and checkpoints in {self.save_dir}")
        self.close()
        return final_eval

    def close(self) -> None:
        """Stop the env workers and close the logs."""
        self.envs.close()
        self.eval_envs.close()
        self.log.close()


RESUME_FILE = "resume.pt"


def _save_atomically(obj: Any, path: Path) -> None:
    """``torch.save`` to a temporary name, then rename: a run killed mid-write keeps the
    previous file."""
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.name + ".tmp")
    torch.save(obj, tmp)
    os.replace(tmp, path)


def _load_resume_state(path: str, args: PPOArgs, mode: str) -> dict[str, Any]:
    """The resume state at ``path``, checked against this run's id and mode."""
    if not Path(path).is_file():
        raise FileNotFoundError(f"--resume {path}: no such file (a run's {RESUME_FILE}, in its run directory)")
    state = torch.load(path, map_location="cpu", weights_only=False)
    for key, value in (("env_id", args.env_id), ("mode", mode)):
        if state.get(key) != value:
            raise ValueError(f"--resume {path} is a run with {key} {state.get(key)!r}, this run has {value!r}")
    return state


def start_run(args: PPOArgs, script: str, whole_env_minibatches: bool = False) -> Run:
    """Validate the flags and set a run up (§2-§3, §7): the derived sizes, seeding
    (python, numpy, torch), the device, the training and eval envs and the logs.
    ``whole_env_minibatches``: minibatches are whole envs (the LSTM), so ``num_envs`` must be
    a multiple of ``num_minibatches``."""
    mode = observation_mode(args)
    horizon = trainable_horizon(args.env_id)  # unknown ids fail here, naming close ones
    if args.evaluate and not args.checkpoint:
        raise ValueError("--evaluate needs --checkpoint")
    num_envs = 1 if args.evaluate else args.num_envs
    args.batch_size = num_envs * args.num_steps
    args.minibatch_size = args.batch_size // args.num_minibatches
    args.num_iterations = args.total_timesteps // args.batch_size
    # The batch sizes matter to training only: --evaluate runs no update, so it takes the
    # training run's flags as they are (its num_minibatches need not divide its one env).
    if not args.evaluate and whole_env_minibatches and num_envs % args.num_minibatches:
        raise ValueError(f"num_envs = {num_envs} must be a multiple of num_minibatches = {args.num_minibatches} "
                         "(a minibatch is whole envs' sequences)")
    if not args.evaluate and args.minibatch_size < 1:
        raise ValueError(f"num_envs * num_steps = {args.batch_size} is smaller than num_minibatches = {args.num_minibatches}")
    if args.save_train_video_freq is not None:
        print("note: --save-train-video-freq is not implemented for CPU envs; no training videos are written")
    run_name, save_dir = run_directory(args, mode, script)
    resumed = None
    if args.resume_min_logstd is not None and not args.resume:
        raise ValueError("--resume-min-logstd applies to a --resume run (a fresh run takes --initial-logstd)")
    if args.resume:
        if args.evaluate:
            raise ValueError("--resume continues training; --evaluate takes --checkpoint")
        resumed = _load_resume_state(args.resume, args, mode)
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

    # Timed because starting many workers costs every time-limited job (64+64 took minutes).
    launched = time.time()
    envs, eval_envs = make_envs(args, mode, num_envs, device, save_dir)
    print(f"{args.env_id}: MODE {mode}, horizon {horizon}, {num_envs} envs, {args.num_eval_envs} eval envs, "
          f"device {device}; env workers ready in {time.time() - launched:.0f} s")
    return Run(args, mode, num_envs, device, envs, eval_envs, RunLog(args, run_name, save_dir), save_dir, resumed,
               launched=launched)
