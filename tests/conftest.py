"""Shared test helpers: env construction with cleanup, the registered ids by episode length."""

from __future__ import annotations

import os

# Keep every test process single-threaded in torch: tiny tensors, 2 cores shared by xdist.
os.environ.setdefault("OMP_NUM_THREADS", "1")

import gymnasium as gym  # noqa: E402
import mikasa_envs  # noqa: E402
import pytest  # noqa: E402
import torch  # noqa: E402

torch.set_num_threads(1)

REGISTERED_IDS: list[str] = mikasa_envs.registered_env_ids()
# Ids whose episodes run long (the -Long- variants, and any horizon of 1000+ steps): the
# generic oracle / zero-action tests roll out fewer seeds of these.
LONG_HORIZON_STEPS = 1000
LONG_IDS = [
    i for i in REGISTERED_IDS if "-Long-" in i or mikasa_envs.get_task(i).max_episode_steps >= LONG_HORIZON_STEPS
]
SHORT_IDS = [i for i in REGISTERED_IDS if i not in LONG_IDS]
CANONICAL_IDS = [i for i in REGISTERED_IDS if mikasa_envs.get_task(i).canonical]


@pytest.fixture
def make_env():
    """``make_env(env_id, **kwargs)`` -> env made with CPU sim, closed after the test."""
    made: list[gym.Env] = []

    def _make(env_id: str, **kwargs) -> gym.Env:
        kwargs.setdefault("obs_mode", "state")
        kwargs.setdefault("control_mode", "pd_ee_delta_pose")
        kwargs.setdefault("sim_backend", "cpu")
        env = gym.make(env_id, **kwargs)
        made.append(env)
        return env

    yield _make
    for env in made:
        env.close()
