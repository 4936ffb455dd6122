"""The canonical MIKASA-Robo-VLA evaluation protocol: constants and the run configuration.

The names and values in this module are the published protocol (benchmark.md §1, §5);
anything that deviates from them is recorded as a deviation in every result file.
"""

from __future__ import annotations

import platform
import sys
from dataclasses import asdict, dataclass
from importlib import metadata
from typing import Any

__all__ = [
    "START_SEED",
    "NUM_EPISODES_PER_TASK",
    "OBS_MODE",
    "CONTROL_MODE",
    "REWARD_MODE",
    "WRAPPER_CHAIN",
    "SUPPORTED_SPLITS",
    "SUPPORTED_OBS_MODES",
    "NUM_ENVS",
    "EPISODES_PER_SCENE",
    "scene_start",
    "starts_scene",
    "RENDER_DEVICES",
    "BenchmarkConfig",
    "protocol_settings",
    "package_versions",
]

START_SEED: int = 4242424242
"""Seed of episode 0 of every task; episode i uses ``START_SEED + i``."""

NUM_EPISODES_PER_TASK: int = 50
"""Episodes per task (seeds 4242424242 ... 4242424291)."""

OBS_MODE: str = "rgb"
CONTROL_MODE: str = "pd_ee_delta_pose"
REWARD_MODE: str = "normalized_dense"
WRAPPER_CHAIN: str = "apply_mikasa_vla_wrappers(include_overlays=False)"
"""Literal string recorded in every result file."""

SUPPORTED_SPLITS: tuple[str, ...] = ("short", "medium", "long", "all")

SUPPORTED_OBS_MODES: tuple[str, ...] = ("rgb", "state")
"""``rgb`` is canonical; ``state`` is a fast, explicitly non-canonical override for testing."""

NUM_ENVS: int = 1
"""Each env instance simulates one episode at a time (canonical ``num_envs=1``)."""

EPISODES_PER_SCENE: int = 5
"""Episodes ``5k .. 5k+4`` of a task run in order on one scene, built fresh for episode
``5k``. PhysX keeps contact caches across resets, so an episode's numbers depend (in the
last bits) on the episodes run before it on its scene; fixing that history makes every
episode's result independent of the worker count and of how episodes are scheduled, at
the cost of one scene build per 5 episodes (~0.1 s on CPU). The reference runner plays all
50 episodes on one scene: its returns can differ from ours in the last bits."""


def scene_start(episode: int) -> int:
    """The first episode of the scene episode ``episode`` of a task plays on."""
    return episode - episode % EPISODES_PER_SCENE


def starts_scene(episode: int) -> bool:
    """Whether episode ``episode`` of a task starts on a freshly built scene."""
    return scene_start(episode) == episode

RENDER_DEVICES: tuple[str, ...] = ("auto", "cpu", "gpu")
"""Where a worker renders its cameras. ``auto``: ManiSkill's default (a CUDA GPU if there is
one, else the CPU); ``cpu``: Mesa's lavapipe, even on a machine with a GPU; ``gpu``: a CUDA GPU
(an error if there is none). Not part of the canonical protocol, but recorded with it:
renderers are not guaranteed to produce bit-identical pixels."""

STATE_WRAPPER_CHAIN: str = (
    "mikasa_bench state chain: StateOnlyTensorToDictWrapper -> curriculum wrapper -> "
    "proprio(tcp_pose, qpos, qvel) + state -> ConvertJointsToEEFXyzRpyGripperWrapper"
)
"""Recorded instead of `WRAPPER_CHAIN` for the non-canonical ``obs_mode="state"`` override."""


@dataclass(frozen=True)
class BenchmarkConfig:
    """Settings of one evaluation (benchmark.md §5); the defaults are the canonical protocol.

    ``sim_backend`` defaults to ``"gpu"`` as upstream; the CLI's local executor passes
    ``"cpu"`` because each of its workers simulates a single env on the CPU.

    Extensions: ``render_device`` (one of `RENDER_DEVICES`) and ``gpu_render_workers``
    (with ``render_device="cpu"``: the first N workers of the pool render on the GPU
    instead, a mixed pool for machines where one GPU cannot keep up with every worker).
    ``save_videos`` records one mp4 per episode (scene view with the task's overlays beside
    the two cameras); it only changes ``render()`` frames, never observations or results.
    ``policy_batch`` > 1 plays that many episodes in lockstep with one policy call per step
    for all (`mikasa_bench.runners.lockstep`): a stochastic policy's draws then depend on it.
    """

    start_seed: int = START_SEED
    n_episodes: int = NUM_EPISODES_PER_TASK
    obs_mode: str = OBS_MODE
    control_mode: str = CONTROL_MODE
    reward_mode: str = REWARD_MODE
    sim_backend: str = "gpu"
    include_overlays: bool = False
    save_videos: bool = False
    render_device: str = "auto"
    gpu_render_workers: int = 0
    policy_batch: int = 1

    def __post_init__(self) -> None:
        if self.n_episodes <= 0:
            raise ValueError(f"n_episodes must be > 0, got {self.n_episodes}")
        if self.start_seed < 0:
            raise ValueError(f"start_seed must be >= 0, got {self.start_seed}")
        if self.obs_mode not in SUPPORTED_OBS_MODES:
            raise ValueError(
                f"unsupported obs_mode {self.obs_mode!r}; expected one of "
                f"{', '.join(SUPPORTED_OBS_MODES)} ('rgb' is the canonical protocol)"
            )
        if self.render_device not in RENDER_DEVICES:
            raise ValueError(
                f"unsupported render_device {self.render_device!r}; expected one of "
                f"{', '.join(RENDER_DEVICES)}"
            )
        if self.policy_batch < 1:
            raise ValueError(f"policy_batch must be >= 1, got {self.policy_batch}")
        if self.policy_batch > 1 and self.save_videos:
            raise ValueError(
                "videos are recorded one episode at a time: use policy_batch 1 (no "
                "--policy-batch) with --video"
            )
        if self.gpu_render_workers < 0:
            raise ValueError(f"gpu_render_workers must be >= 0, got {self.gpu_render_workers}")
        if self.gpu_render_workers and self.render_device != "cpu":
            # A mixed pool is "CPU rendering, except N workers": with auto/gpu every worker
            # already renders on the GPU when there is one, so N would mean nothing.
            raise ValueError(
                "gpu_render_workers (a mixed pool) needs render_device='cpu': the first N "
                "workers render on the GPU, the others on the CPU"
            )

    def render_device_for(self, worker_index: int) -> str:
        """The render device (``auto``, ``cpu`` or ``gpu``) of worker ``worker_index``."""
        if self.gpu_render_workers and worker_index < self.gpu_render_workers:
            return "gpu"
        return self.render_device

    def render_description(self) -> str:
        """Human-readable render setting, e.g. ``cpu`` or ``mixed: 2 workers gpu, rest cpu``."""
        if self.gpu_render_workers:
            return f"mixed: {self.gpu_render_workers} worker(s) gpu, the rest cpu"
        return self.render_device

    def episode_seeds(self) -> list[int]:
        """The seed of every episode, in episode order."""
        return [self.start_seed + i for i in range(self.n_episodes)]

    @property
    def wrapper_chain(self) -> str:
        """The wrapper chain string recorded in result files for this configuration."""
        return WRAPPER_CHAIN if self.obs_mode == OBS_MODE else STATE_WRAPPER_CHAIN

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready field mapping (round-trips through ``BenchmarkConfig(**d)``)."""
        return asdict(self)


def deviations(config: BenchmarkConfig) -> list[str]:
    """Human-readable list of the ways ``config`` departs from the canonical protocol."""
    canonical = {
        "start_seed": START_SEED,
        "n_episodes": NUM_EPISODES_PER_TASK,
        "obs_mode": OBS_MODE,
        "control_mode": CONTROL_MODE,
        "reward_mode": REWARD_MODE,
        "include_overlays": False,
    }
    out = []
    for key, value in canonical.items():
        actual = getattr(config, key)
        if actual != value:
            out.append(f"{key}={actual!r} (canonical {value!r})")
    return out


def protocol_settings(config: BenchmarkConfig) -> dict[str, Any]:
    """The protocol record written into every result file (settings + canonical flag)."""
    devs = deviations(config)
    return {
        "start_seed": config.start_seed,
        "n_episodes": config.n_episodes,
        "episode_seeds": f"start_seed + i, i = 0 .. {config.n_episodes - 1}",
        "obs_mode": config.obs_mode,
        "control_mode": config.control_mode,
        "reward_mode": config.reward_mode,
        "wrapper_chain": config.wrapper_chain,
        "include_overlays": config.include_overlays,
        "num_envs": NUM_ENVS,
        "episodes_per_scene": f"{EPISODES_PER_SCENE} (episodes 5k..5k+4 in order on a scene built fresh for 5k)",
        "sim_backend": config.sim_backend,
        "render_device": config.render_description(),
        "save_videos": config.save_videos,
        **_policy_calls(config.policy_batch),
        "canonical": not devs,
        "deviations": devs,
    }


def _policy_calls(batch: int) -> dict[str, Any]:
    """How the policy was called: one episode at a time, or ``batch`` in lockstep."""
    if batch == 1:
        return {
            "policy_batch": 1,
            "policy_reset": "policy.reset() (if defined) at every episode start",
            "policy_rng_seed": "python/numpy/torch global RNGs seeded with the episode seed",
        }
    return {
        "policy_batch": batch,
        "policy_reset": (
            f"policy.reset() (if defined) at the start of every round of up to {batch} "
            f"episodes played in lockstep (episode r of {batch} consecutive scenes), one "
            f"policy.forward_batch call per step for all"
        ),
        "policy_rng_seed": "python/numpy/torch global RNGs seeded with the round's first episode seed",
    }


_VERSIONED_PACKAGES = (
    "mikasa-bench",
    "mikasa-envs",
    "mikasa-wrappers",
    "mikasa-oracles",
    "mani-skill",
    "sapien",
    "gymnasium",
    "torch",
    "numpy",
)


def package_versions() -> dict[str, str | None]:
    """Installed versions of the packages that determine results (None if not installed)."""
    out: dict[str, str | None] = {"python": sys.version.split()[0], "platform": platform.platform()}
    for name in _VERSIONED_PACKAGES:
        try:
            out[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            out[name] = None
    return out
