"""Environment construction and the episode loop (benchmark.md §5, §6).

`run_episode` is the single place where a policy meets an env; the in-process API
(`evaluate_task`) and the worker processes of the executors both use it, so every path
produces the same numbers.
"""

from __future__ import annotations

import contextlib
import random
from collections import deque
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from mikasa_bench.errors import PolicyOutputError, UnknownTaskError
from mikasa_bench.media.render import gym_render_kwargs
from mikasa_bench.media.video import compose_frame
from mikasa_bench.policies.base import reset_policy
from mikasa_bench.protocol import NUM_ENVS, OBS_MODE, BenchmarkConfig

__all__ = [
    "EpisodeResult",
    "EpisodeRngs",
    "RecordedActions",
    "first_value",
    "make_benchmark_env",
    "normalize_action_chunk",
    "run_episode",
    "seed_global_rngs",
]


@dataclass(frozen=True)
class EpisodeResult:
    """Outcome of one episode: the success latch, summed reward, steps taken, seed, and the
    lengths K of the action chunks the policy returned (distinct, ascending)."""

    success_once: bool
    episode_return: float
    n_steps: int
    seed: int
    chunk_sizes: tuple[int, ...] = ()


def seed_global_rngs(seed: int) -> None:
    """Seed python's, numpy's and torch's global RNGs (stochastic policies that draw from
    them become reproducible and independent of which worker runs the episode)."""
    import torch

    s = int(seed) % (2**32)
    random.seed(s)
    np.random.seed(s)
    torch.manual_seed(s)


def _global_rng_states() -> tuple[Any, ...]:
    import torch

    cuda = torch.cuda.get_rng_state_all() if torch.cuda.is_initialized() else None
    return random.getstate(), np.random.get_state(), torch.get_rng_state(), cuda


def _set_global_rng_states(states: tuple[Any, ...]) -> None:
    import torch

    py, np_state, cpu, cuda = states
    random.setstate(py)
    np.random.set_state(np_state)
    torch.set_rng_state(cpu)
    if cuda is not None:
        torch.cuda.set_rng_state_all(cuda)


class EpisodeRngs:
    """One episode's own copy of the global RNG states (seeded with the episode seed),
    swapped in around the policy's calls.

    Episodes that run in threads of one process (``--envs-per-worker``) share Python's,
    numpy's and torch's global RNGs; a policy drawing from them would get numbers that
    depend on the other threads. Inside `active` it sees exactly the sequence a process of
    its own would give it.
    """

    def __init__(self, seed: int) -> None:
        with self._swapped(None):
            seed_global_rngs(seed)

    @contextlib.contextmanager
    def active(self) -> Iterator[None]:
        """The episode's RNG states are the global ones for the duration of the block."""
        with self._swapped(self._states):
            yield

    @contextlib.contextmanager
    def _swapped(self, states: tuple[Any, ...] | None) -> Iterator[None]:
        from mikasa_envs.render_batcher import global_rng_section

        with global_rng_section():
            saved = _global_rng_states()
            if states is not None:
                _set_global_rng_states(states)
            try:
                yield
            finally:
                self._states = _global_rng_states()
                _set_global_rng_states(saved)


def first_value(x: Any) -> Any:
    """First element of a batched value (tensor, array, list) or the value itself: env 0's
    reward, flag or success of a ``num_envs=1`` env."""
    if hasattr(x, "reshape") and hasattr(x, "shape"):
        flat = x.reshape(-1)
        return flat[0] if len(flat) else False
    if isinstance(x, (list, tuple)):
        return x[0] if x else False
    return x


def normalize_action_chunk(
    output: Any, action_shape: Sequence[int], step: int | None = None
) -> list[Any]:
    """Split a policy output into a list of float32 torch actions of shape ``action_shape``.

    Accepted: ``A`` (one action), ``(K, *A)`` or ``(1, K, *A)`` as a torch tensor or numpy
    array (array-likes are converted). Anything else raises `PolicyOutputError` naming the
    expected shapes; an empty chunk (``K == 0``) and NaN or inf values too (naming ``step``,
    the env step the chunk starts at, when given).
    """
    import torch

    a = tuple(int(d) for d in action_shape)
    if isinstance(output, torch.Tensor):
        t = output.detach()
    else:
        try:
            arr = np.asarray(output)
        except Exception as exc:  # ragged lists etc.
            raise PolicyOutputError(
                f"policy.forward returned {type(output).__name__}, which is not an array; "
                f"expected a torch.Tensor or numpy.ndarray of shape {a}, (K, {_dims(a)}) or "
                f"(1, K, {_dims(a)})"
            ) from exc
        if arr.dtype == object or not (
            np.issubdtype(arr.dtype, np.number) or arr.dtype == np.bool_
        ):
            raise PolicyOutputError(
                f"policy.forward returned {type(output).__name__} with dtype {arr.dtype}; "
                f"expected numeric actions of shape {a}, (K, {_dims(a)}) or (1, K, {_dims(a)})"
            )
        t = torch.from_numpy(np.ascontiguousarray(arr))
    shape = tuple(t.shape)
    if shape == a:
        chunk = t.unsqueeze(0)
    elif len(shape) == len(a) + 1 and shape[1:] == a:
        chunk = t
    elif len(shape) == len(a) + 2 and shape[0] == 1 and shape[2:] == a:
        chunk = t[0]
    else:
        raise PolicyOutputError(
            f"policy.forward returned an action of shape {shape}; expected one action of "
            f"shape {a}, a chunk (K, {_dims(a)}) or a batched chunk (1, K, {_dims(a)})"
        )
    if chunk.shape[0] == 0:
        raise PolicyOutputError(
            f"policy.forward returned an empty action chunk (shape {shape}); expected K >= 1."
        )
    chunk = chunk.to(torch.float32)
    if not bool(torch.isfinite(chunk).all()):
        at = "" if step is None else f" at step {step}"
        raise PolicyOutputError(f"policy.forward returned non-finite actions (NaN or inf){at}")
    return list(chunk.unbind(0))


def _dims(a: tuple[int, ...]) -> str:
    return ", ".join(str(d) for d in a)


def run_episode(
    env: Any,
    policy: Any,
    episode_seed: int,
    *,
    reset_policy_hook: bool = True,
    collect_video: bool = False,
    frame_sink: Callable[[np.ndarray], None] | None = None,
    own_global_rngs: bool = False,
    fresh_scene: bool = False,
    action_sink: Callable[[Any], None] | None = None,
) -> tuple[EpisodeResult, list[np.ndarray] | None]:
    """Run one episode of ``env`` (already wrapped, ``num_envs=1``) with ``policy``.

    Protocol (benchmark.md §6.2): reset with ``episode_seed``; a fresh FIFO action queue
    per episode (leftover chunk actions never leak into the next episode); the policy is
    queried whenever the queue is empty; at most ``env.max_episode_steps`` steps; success
    is a latch over ``info["success"]``. Extension: global RNGs are seeded with the episode
    seed and ``policy.reset()`` is called after the env reset (``reset_policy_hook``).

    Video (§8): with ``frame_sink`` every composed frame (`compose_frame`: ``env.render()``
    beside the cameras) is passed to it, one before each step and one after the last;
    ``collect_video=True`` returns them as a list instead of None (memory grows with the
    episode length: the runner streams to an encoder through ``frame_sink``). Rendering
    the scene view does not touch the simulation, so results are the same either way.

    ``own_global_rngs`` (for episodes run in threads of one process): the policy's calls
    see the episode's own global RNG states (`EpisodeRngs`) instead of the process's.
    ``fresh_scene``: the reset rebuilds the scene (``reconfigure``), as every
    `EPISODES_PER_SCENE`-th episode does (`starts_scene`). ``action_sink`` receives each
    action (float32, shape of the action space) before it is stepped: `RecordedActions`
    plays them again. Non-finite actions raise `PolicyOutputError` naming the step.
    """
    import torch

    if own_global_rngs:
        rngs = EpisodeRngs(episode_seed)
        policy_rngs: Callable[[], Any] = rngs.active
    else:
        seed_global_rngs(episode_seed)
        policy_rngs = contextlib.nullcontext
    options = {"reconfigure": True} if fresh_scene else None
    obs, _ = env.reset(seed=int(episode_seed), options=options)
    max_steps = getattr(env, "max_episode_steps", None)
    if max_steps is None:
        raise RuntimeError(
            "the env has no max_episode_steps attribute; wrap it with "
            "apply_mikasa_vla_wrappers (or make_benchmark_env)"
        )
    if reset_policy_hook:
        with policy_rngs():
            reset_policy(policy, episode_seed)
    action_shape = tuple(env.action_space.shape)
    device = getattr(env.unwrapped, "device", None) or torch.device("cpu")
    frames: list[np.ndarray] | None = [] if collect_video else None
    sink = frame_sink
    if frames is not None:
        sink = frames.append if frame_sink is None else _tee(frames.append, frame_sink)

    queue: deque[Any] = deque()
    chunk_sizes: set[int] = set()
    success, total, n_steps = False, 0.0, 0
    for _ in range(int(max_steps)):
        if sink is not None:
            sink(compose_frame(env.render(), obs))
        if not queue:
            with policy_rngs():
                output = policy.forward(obs)
            chunk = normalize_action_chunk(output, action_shape, step=n_steps)
            chunk_sizes.add(len(chunk))
            queue.extend(chunk)
        if action_sink is not None:
            action_sink(queue[0])
        action = queue.popleft().to(device=device, dtype=torch.float32).unsqueeze(0)
        obs, reward, terminated, truncated, info = env.step(action)
        n_steps += 1
        total += float(first_value(reward))
        if isinstance(info, dict) and "success" in info:
            success = success or bool(first_value(info["success"]))
        if bool(first_value(terminated)) or bool(first_value(truncated)):
            break
    if sink is not None:
        sink(compose_frame(env.render(), obs))  # the state after the last step
    result = EpisodeResult(
        bool(success), float(total), n_steps, int(episode_seed), tuple(sorted(chunk_sizes))
    )
    return result, frames


class RecordedActions:
    """A policy that plays back recorded actions, all in one chunk (`run_episode`'s
    ``action_sink`` records them): the same env calls as the episode that recorded them,
    so the env ends in the same state."""

    def __init__(self, actions: Sequence[Any]) -> None:
        import torch

        self.actions = torch.stack(list(actions))

    def forward(self, obs: Any) -> Any:
        return self.actions


def _tee(*sinks: Callable[[np.ndarray], None]) -> Callable[[np.ndarray], None]:
    def both(frame: np.ndarray) -> None:
        for f in sinks:
            f(frame)

    return both


def _state_chain(env: Any, env_id: str, *, include_overlays: bool = False) -> Any:
    """The non-canonical ``obs_mode="state"`` chain (`mikasa_wrappers.apply_mikasa_vla_state_wrappers`):
    the canonical action path and 7-value ``proprio``, the flat privileged ``state`` vector
    in place of the images."""
    from mikasa_wrappers import VLA_WRAPPER_CONFIGS, apply_mikasa_vla_state_wrappers

    if env_id not in VLA_WRAPPER_CONFIGS:
        raise UnknownTaskError(f"env id {env_id!r} has no canonical wrapper configuration")
    return apply_mikasa_vla_state_wrappers(env, include_overlays=include_overlays)


def make_benchmark_env(env_id: str, config: BenchmarkConfig | None = None) -> Any:
    """``gym.make`` with the protocol's arguments, then the canonical wrapper chain.

    ``render_mode`` is ``"all"`` for metric-only runs and ``"rgb_array"`` when saving
    videos; overlays are forced on for videos (they only change ``render()`` frames, not
    observations), as upstream. ``config.render_device`` picks ManiSkill's render backend
    (executors pass each worker its own device); to render on the CPU on a machine with a GPU the
    process must also have restricted Vulkan to lavapipe before its first env (see
    `mikasa_bench.media.render`).
    ``obs_mode="state"`` (non-canonical) uses `_state_chain` instead, which needs no
    rendering unless videos are saved.
    """
    import gymnasium as gym
    import mikasa_envs  # noqa: F401  (registers the envs)

    config = config or BenchmarkConfig()
    rgb = config.obs_mode == OBS_MODE
    if config.save_videos:
        render_mode: str | None = "rgb_array"
    else:
        render_mode = "all" if rgb else None
    overlays = config.include_overlays or config.save_videos
    env = gym.make(
        env_id,
        num_envs=NUM_ENVS,
        obs_mode=config.obs_mode,
        control_mode=config.control_mode,
        render_mode=render_mode,
        reward_mode=config.reward_mode,
        sim_backend=config.sim_backend,
        **gym_render_kwargs(config.render_device),
    )
    try:
        if rgb:
            from mikasa_wrappers import apply_mikasa_vla_wrappers

            return apply_mikasa_vla_wrappers(env, include_overlays=overlays)
        return _state_chain(env, env_id, include_overlays=overlays)
    except BaseException:
        env.close()
        raise
