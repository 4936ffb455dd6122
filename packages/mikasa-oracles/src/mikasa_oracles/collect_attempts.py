"""One attempt of ``mikasa-collect``: the per-worker episode loop (:mod:`mikasa_oracles.collect`).

An attempt rolls out one seed of a task's oracle through the recording env (the canonical
VLA wrapper chain, ``obs_mode="rgb"``, ``pd_ee_delta_pose``, ``normalized_dense``, CPU
simulation) and stages a kept episode as ``seed_<s>.npz`` in the staging directory.
:class:`AttemptRunner` is what every pool of :mod:`mikasa_oracles.collect_pools` runs.
"""

from __future__ import annotations

import random
import time
import traceback
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

CONTROL_MODE = "pd_ee_delta_pose"
REWARD_MODE = "normalized_dense"
SIM_BACKEND = "cpu"
STAGED_PREFIX = "seed_"


# --------------------------------------------------------------------------- one attempt
@dataclass(frozen=True)
class AttemptResult:
    """Outcome of one seed. ``staged`` is the staged episode file when ``saved``."""

    seed: int
    saved: bool
    reason: str
    length: int
    reward_sum: float
    wall_s: float
    staged: str | None = None
    error: str | None = None


def _first(value: Any) -> Any:
    """Element 0 of a batched tensor/array/list, else the value."""
    if hasattr(value, "reshape"):
        return value.reshape(-1)[0]
    if isinstance(value, (list, tuple)):
        return value[0] if value else None
    return value


def _language(info: Any) -> str:
    """The ``language_instruction`` an env reports in ``info`` ("" if none)."""
    if not isinstance(info, dict):
        return ""
    value = info.get("language_instruction")
    if isinstance(value, (list, tuple, np.ndarray)):
        value = value[0] if len(value) else ""
    return value if isinstance(value, str) else ""


def seed_global_rngs(seed: int) -> None:
    """So an oracle drawing from global RNGs still depends only on the episode seed."""
    import torch

    random.seed(seed)
    np.random.seed(seed % 2**32)
    torch.manual_seed(seed)


def make_collection_env(env_id: str) -> Any:
    """The recording env: ``gym.make`` with the dataset's settings + the canonical chain."""
    import gymnasium as gym
    import mikasa_envs  # noqa: F401  (registers the envs)
    from mikasa_wrappers import apply_mikasa_vla_wrappers

    env = gym.make(
        env_id,
        num_envs=1,
        obs_mode="rgb",
        control_mode=CONTROL_MODE,
        reward_mode=REWARD_MODE,
        sim_backend=SIM_BACKEND,
    )
    try:
        return apply_mikasa_vla_wrappers(env)
    except BaseException:
        env.close()
        raise


class AttemptRunner:
    """Runs attempts of one task: owns one env and its oracle (built on first use)."""

    def __init__(
        self, env_id: str, staging_dir: str, min_length: int, fallback_language: str
    ) -> None:
        self.env_id = env_id
        self.staging_dir = Path(staging_dir)
        self.min_length = min_length
        self.fallback_language = fallback_language
        self.env: Any = None
        self.oracle: Any = None

    def _ensure_env(self) -> None:
        if self.env is None:
            from mikasa_oracles import make_oracle

            self.env = make_collection_env(self.env_id)
            self.oracle = make_oracle(self.env)

    def run(self, seed: int) -> AttemptResult:
        """Roll out ``seed``; stage the episode if it is kept. Errors become ``error``."""
        t0 = time.perf_counter()
        try:
            return self._run(seed, t0)
        except Exception:
            # The env may be mid-episode or broken: rebuild it for the next attempt.
            self.close()
            return AttemptResult(
                seed, False, "error", 0, 0.0, time.perf_counter() - t0, error=traceback.format_exc()
            )

    def _run(self, seed: int, t0: float) -> AttemptResult:
        from mikasa_datasets.npz import make_episode, write_episode
        from mikasa_envs.render_batcher import participating

        self._ensure_env()
        max_steps = int(self.env.max_episode_steps)
        # The rollout (not the env build or the file write) takes part in shared render
        # passes when this process runs several envs in threads; else a no-op.
        with participating():
            frames, language, success, finished = self._rollout(seed, max_steps)
        length = len(frames["reward"])
        reward_sum = float(np.sum(np.asarray(frames["reward"], dtype=np.float32), dtype=np.float64))
        if not success:
            reason = "unsuccessful" if finished else "timeout"
            return AttemptResult(seed, False, reason, length, reward_sum, time.perf_counter() - t0)
        if length < self.min_length:
            return AttemptResult(
                seed, False, "too_short", length, reward_sum, time.perf_counter() - t0
            )
        episode = make_episode(
            rgb=np.stack(frames["rgb"]),
            proprio=np.stack(frames["proprio"]),
            action=np.stack(frames["action"]),
            reward=frames["reward"],
            success=frames["success"],
            done=frames["done"],
            language_instruction=language or self.fallback_language,
            episode_seed=seed,
        )
        staged = self.staging_dir / f"{STAGED_PREFIX}{seed}.npz"
        write_episode(staged, episode, max_episode_steps=max_steps, min_length=self.min_length)
        return AttemptResult(
            seed, True, "saved", length, reward_sum, time.perf_counter() - t0, str(staged)
        )

    def _rollout(
        self, seed: int, max_steps: int
    ) -> tuple[dict[str, list[Any]], str | None, bool, bool]:
        """Play the attempt: (per-step records, language, success, finished)."""
        from mikasa_envs.render_batcher import global_rng_section

        env, oracle = self.env, self.oracle
        # Inside the section: a thread beside this one may be resetting its env, whose
        # layout is drawn from the (reseeded) global torch RNG.
        with global_rng_section():
            seed_global_rngs(seed)
        # A fresh scene: after a plain reset the episode would depend, in the last bits, on
        # the attempts this worker ran before (PhysX contact caches).
        obs, info = env.reset(seed=seed, options={"reconfigure": True})
        oracle.reset()
        language = _language(info)
        frames: dict[str, list[Any]] = {
            k: [] for k in ("rgb", "proprio", "action", "reward", "success", "done")
        }
        success = finished = False
        for _ in range(max_steps):
            # Observation o_t before the step (copied: the env may reuse its buffers).
            frames["rgb"].append(obs["rgb"][0].cpu().numpy().copy())
            frames["proprio"].append(obs["proprio"][0].cpu().numpy().copy())
            # Stored and executed action are the same clipped float32 vector.
            action = np.clip(
                np.asarray(oracle.forward(obs), dtype=np.float32).reshape(-1), -1.0, 1.0
            )
            obs, reward, terminated, truncated, info = env.step(action)
            language = language or _language(info)
            success = bool(_first(info["success"]))
            finished = success or bool(_first(terminated)) or bool(_first(truncated))
            frames["action"].append(action)
            frames["reward"].append(float(_first(reward)))
            frames["success"].append(int(success))
            frames["done"].append(int(finished))
            if finished:
                break
        return frames, language, success, finished

    def close(self) -> None:
        """Close the env (the next attempt builds a fresh one)."""
        if self.env is not None:
            try:
                self.env.close()
            except Exception:
                pass
        self.env = self.oracle = None

