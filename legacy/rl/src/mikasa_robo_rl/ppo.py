"""What the PPO baselines (``legacy/rl/baselines/ppo/``) share besides the algorithm: the flag
parser, the observation-mode rule, the batched CPU envs, the run's directory and logs, the
evaluation pass and the checkpoints (``ppo_baselines.md`` §2-§3, §6-§7). Each trainer holds its
own flags, its network and PPO itself (rollout, advantages, update). Needs the ``train`` extra
(tyro, TensorBoard).
"""

from __future__ import annotations

import os
import time
from collections import defaultdict
from collections.abc import Callable, Mapping
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any, TypeVar

import numpy as np
import torch
import tyro

from mikasa_robo_rl.agents import GaussianActorCritic
from mikasa_robo_rl.vector_env import CpuVectorEnv, SubEnvSpec

__all__ = [
    "RESUME_FILE", "RunLog", "RunSettings", "evaluate", "load_resume_state", "make_envs",
    "observation_mode", "parse_args", "restore_from_resume", "run_directory", "save_atomically",
    "save_resume_state",
]

T = TypeVar("T")

RESUME_FILE = "resume.pt"
"""What every iteration writes in the run directory, for ``--resume``."""


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


def observation_mode(
    *, include_state: bool, include_rgb: bool, include_joints: bool, include_oracle: bool
) -> str:
    """MODE of ``ppo_baselines.md`` §3.1 from the trainers' include flags (its errors included)."""
    if not (include_state or include_rgb):
        raise ValueError("at least one of --include-state / --include-rgb is needed")
    if include_joints and not include_rgb:
        raise ValueError("--include-joints needs --include-rgb")
    if include_state and include_rgb:
        raise NotImplementedError("state + rgb observations are not supported")
    if include_state:
        if include_oracle:
            raise NotImplementedError("the state already contains the oracle information")
        return "state"
    return "rgb" + ("_joints" if include_joints else "") + ("_oracle" if include_oracle else "")


def run_directory(
    *, script: str, env_id: str, mode: str, reward_mode: str, seed: int, exp_name: str | None = None
) -> tuple[str, Path]:
    """(run name, run directory) of §7: ``checkpoints/ppo_memtasks/<MODE>/<reward_mode>/
    <env_id>/<run_name>/<TIME>`` under the working directory."""
    stamp = time.strftime("%Y%m%d_%H%M%S")
    run_name = (exp_name or f"{env_id}__{script}") + f"__{seed}__{mode}__{stamp}"
    root = Path("checkpoints/ppo_memtasks")
    return run_name, root / mode / reward_mode / env_id / run_name / stamp


def make_envs(
    train_spec: SubEnvSpec, eval_spec: SubEnvSpec, *, num_envs: int, num_eval_envs: int,
    workers: int | None, device: torch.device, shared_memory: bool = False, render_together: bool = False,
) -> tuple[CpuVectorEnv, CpuVectorEnv]:
    """(training envs, eval envs): ``num_envs`` / ``num_eval_envs`` CPU sub-envs of each spec in
    ``workers`` processes (None: one per core), batched (§3.2), their tensors on ``device``;
    ``shared_memory`` / ``render_together`` as ``CpuVectorEnv`` takes them."""
    options = dict(shared_memory=shared_memory, render_together=render_together)
    envs = CpuVectorEnv(train_spec, num_envs, workers, device, **options)
    try:
        eval_envs = CpuVectorEnv(eval_spec, num_eval_envs, workers, device, **options)
    except BaseException:
        envs.close()
        raise
    return envs, eval_envs


class RunLog:
    """TensorBoard scalars (and W&B with ``track``), with the run's flags as a table."""

    def __init__(
        self, directory: Path, *, run_name: str, config: Mapping[str, Any], track: bool = False,
        wandb_project: str | None = None, wandb_entity: str | None = None,
    ) -> None:
        from torch.utils.tensorboard import SummaryWriter

        if Path("wandb_config.yaml").exists():  # the release's way of passing the W&B key
            import yaml

            wandb_config = yaml.safe_load(Path("wandb_config.yaml").read_text())
            os.environ["WANDB_API_KEY"] = wandb_config["wandb_api"]
        self.writer = SummaryWriter(str(directory))
        table = "\n".join(f"|{k}|{v}|" for k, v in config.items())
        self.writer.add_text("hyperparameters", "|param|value|\n|-|-|\n" + table)
        self.wandb: Any = None
        if track:
            import wandb

            wandb.init(project=wandb_project, entity=wandb_entity, config=dict(config),
                       name=run_name, group="PPO", tags=["ppo", "walltime_efficient"],
                       save_code=True)
            self.wandb = wandb

    def scalar(self, name: str, value: float, step: int) -> None:
        """Log ``value`` under ``name`` at ``step``."""
        self.writer.add_scalar(name, value, step)
        if self.wandb is not None:
            self.wandb.log({name: value}, step=step)

    def scalars(self, values: Mapping[str, float], step: int) -> None:
        """Log each of ``values`` under its name at ``step``."""
        for name, value in values.items():
            self.scalar(name, value, step)

    def close(self) -> None:
        """Flush and close the logs."""
        self.writer.close()
        if self.wandb is not None:
            self.wandb.finish()


def evaluate(
    eval_envs: CpuVectorEnv,
    policy: Callable[[dict[str, torch.Tensor], torch.Tensor], torch.Tensor],
    *,
    num_steps: int,
    log: RunLog,
    global_step: int,
) -> dict[str, float]:
    """One evaluation pass (§6): reset the eval envs, run ``num_steps`` steps of
    ``policy(obs, done)`` (deterministic actions; ``done`` marks observations that start an
    episode), log the mean of each finished episode's metric as ``eval/<metric>``.
    Returns those means and ``episodes``, the number of finished episodes."""
    metrics: dict[str, list[torch.Tensor]] = defaultdict(list)
    obs, _ = eval_envs.reset()
    done = torch.ones(eval_envs.num_envs, device=eval_envs.device)
    for _ in range(num_steps):
        with torch.no_grad():
            obs, _, terminated, truncated, info = eval_envs.step(policy(obs, done))
        done = torch.logical_or(terminated, truncated).float()
        if "final_info" in info:
            mask = info["_final_info"]
            for k, v in info["final_info"]["episode"].items():
                metrics[k].append(v[mask].float())
    means = {k: torch.cat(v).mean().item() for k, v in metrics.items()}
    episodes = len(torch.cat(metrics["success_once"])) if metrics else 0
    print(f"eval @ {global_step}: {episodes} episodes, "
          + ", ".join(f"{k} {v:.3f}" for k, v in means.items()))
    for k, v in means.items():
        log.scalar(f"eval/{k}", v, global_step)
    return means | {"episodes": episodes}


def save_atomically(obj: Any, path: Path) -> None:
    """``torch.save`` to a temporary name, then rename: a run killed mid-write keeps the
    previous file."""
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.name + ".tmp")
    torch.save(obj, tmp)
    os.replace(tmp, path)


@dataclass(frozen=True)
class RunSettings:
    """The flags a ``resume.pt`` records: a resumed run must have its ``env_id`` and ``mode``,
    and adapts to another ``reward_scale``, ``vf_coef`` or ``reward_mode``
    (:func:`restore_from_resume`)."""

    env_id: str
    mode: str
    reward_scale: float
    vf_coef: float
    reward_mode: str


def save_resume_state(
    save_dir: Path, *, agent: torch.nn.Module, optimizer: torch.optim.Optimizer, iteration: int,
    global_step: int, saves: int, settings: RunSettings,
) -> None:
    """Write ``save_dir/resume.pt``: networks, optimizer, the step counters (``saves``: the
    periodic checkpoints written so far), the run's settings and the torch and numpy RNGs."""
    save_atomically(
        dict(agent=agent.state_dict(), optimizer=optimizer.state_dict(), iteration=iteration,
             global_step=global_step, saves=saves, save_dir=str(save_dir), **asdict(settings),
             torch_rng=torch.get_rng_state(), numpy_rng=np.random.get_state()),
        save_dir / RESUME_FILE,
    )


def load_resume_state(path: str, *, settings: RunSettings) -> dict[str, Any]:
    """The resume state at ``path``, checked against this run's id and mode."""
    if not Path(path).is_file():
        raise FileNotFoundError(
            f"--resume {path}: no such file (a run's {RESUME_FILE}, in its run directory)")
    state = torch.load(path, map_location="cpu", weights_only=False)
    for key, value in (("env_id", settings.env_id), ("mode", settings.mode)):
        if state.get(key) != value:
            raise ValueError(f"--resume {path} is a run with {key} {state.get(key)!r}, "
                             f"this run has {value!r}")
    return state


def restore_from_resume(
    state: Mapping[str, Any], *, agent: GaussianActorCritic, optimizer: torch.optim.Optimizer,
    settings: RunSettings, learning_rate: float, min_logstd: float | None = None,
) -> tuple[int, int, int]:
    """Load a resume ``state`` into ``agent`` and ``optimizer`` (at ``learning_rate``), adapt
    them to this run's ``settings``, raise the policy's log std to ``min_logstd`` (if given) and
    restore the RNGs. Returns (first iteration, global step, periodic checkpoints written)."""
    agent.load_state_dict(state["agent"])
    optimizer.load_state_dict(state["optimizer"])
    # The command's --learning-rate wins over the saved one (Adam's moments are kept unless the
    # units changed, _adapt_to_new_units): a run can go on at a lower rate, where a fresh optimizer
    # from --checkpoint would first take full-size steps in every weight.
    for group in optimizer.param_groups:
        group["lr"] = learning_rate
    _adapt_to_new_units(state, agent, optimizer, settings)
    if min_logstd is not None:
        agent.floor_logstd(min_logstd)
        logstd = [round(v, 3) for v in agent.actor_logstd.flatten().tolist()]
        print(f"log std raised to at least {min_logstd}: {logstd}")
    torch.set_rng_state(state["torch_rng"])
    np.random.set_state(state["numpy_rng"])
    print(f"resumed {state['save_dir']} after iteration {state['iteration']} "
          f"(step {state['global_step']})")
    return state["iteration"] + 1, state["global_step"], state["saves"]


def _adapt_to_new_units(
    state: Mapping[str, Any], agent: GaussianActorCritic, optimizer: torch.optim.Optimizer,
    settings: RunSettings,
) -> None:
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
    gradients shrank ~80-fold going from dense to sparse rewards barely moved either (explained
    variance -2.7 after 30 updates, BunchOfColors3-v0 at 28.1 M)."""
    saved_scale, saved_vf_coef, saved_mode = (
        state.get(k) for k in ("reward_scale", "vf_coef", "reward_mode"))
    new_scale = saved_scale is not None and saved_scale != settings.reward_scale
    new_vf_coef = saved_vf_coef is not None and saved_vf_coef != settings.vf_coef
    new_mode = saved_mode is not None and saved_mode != settings.reward_mode
    if new_scale:
        factor = settings.reward_scale / saved_scale
        agent.scale_values(factor)
        print(f"--reward-scale {settings.reward_scale} (saved with {saved_scale}): "
              f"critic outputs scaled by {factor:g}")
    if new_vf_coef:
        print(f"--vf-coef {settings.vf_coef} (saved with {saved_vf_coef})")
    if new_mode:
        print(f"--reward-mode {settings.reward_mode} (saved with {saved_mode}): the critic refits")
    if new_scale or new_vf_coef or new_mode:
        optimizer.state.clear()
        print("optimizer moments reset")
