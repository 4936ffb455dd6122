"""Policy interface, built-in policies and loading of user policies.

A policy is any object with

* ``chunk_size: int`` (optional, default 1; recorded as ``action_chunk_size``),
* ``forward(obs) -> torch.Tensor | numpy.ndarray`` returning one action ``(7,)``, a
  chunk ``(K, 7)`` or a batched chunk ``(1, K, 7)``,
* ``reset()`` or ``reset(seed)`` (optional): called at every episode start, after the env
  reset, so recurrent policies can clear their memory; the ``seed`` form receives the
  episode seed, which makes stochastic policies reproducible whatever the worker count.

Policies are *described* by a `PolicySpec` (picklable, JSON-ready) in the main process
and *built* in each worker by `build_policy`, because some (the oracle) read privileged
state of the env instance they are built for.
"""

from __future__ import annotations

import hashlib
import importlib
import importlib.util
import inspect
import json
import sys
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Protocol, runtime_checkable

import numpy as np

from .errors import BenchError

__all__ = [
    "ChunkPolicy",
    "ZeroPolicy",
    "RandomPolicy",
    "DummyChunkPolicy",
    "PolicySpec",
    "BUILTIN_POLICIES",
    "resolve_policy",
    "build_policy",
    "policy_chunk_size",
    "reset_policy",
    "check_policy_supports",
    "is_remote_target",
    "is_lerobot_target",
]

ACTION_SHAPE: tuple[int, ...] = (7,)
"""Action shape of every MIKASA-Robo-VLA task under ``pd_ee_delta_pose`` (num_envs=1)."""


@runtime_checkable
class ChunkPolicy(Protocol):
    """What the runner calls; ``chunk_size`` and ``reset`` are optional (see module doc)."""

    def forward(self, obs: Any) -> Any:
        """Return one action, ``(K, *A)`` or ``(1, K, *A)`` actions for observation ``obs``."""
        ...


def policy_chunk_size(policy: Any) -> int:
    """``policy.chunk_size`` (default 1); ``ValueError`` unless it is a positive int."""
    k = getattr(policy, "chunk_size", 1)
    try:
        k_int = int(k)
    except (TypeError, ValueError):
        raise ValueError(f"policy.chunk_size must be a positive int, got {k!r}") from None
    if k_int <= 0:
        raise ValueError(f"policy.chunk_size must be > 0, got {k!r}")
    return k_int


def reset_policy(policy: Any, seed: int) -> None:
    """Call ``policy.reset(seed=seed)`` or ``policy.reset()``, whichever it accepts; no-op
    for policies without ``reset`` (the oracles' rollout does the same)."""
    from mikasa_oracles.rollout import reset_with_seed

    reset_with_seed(policy, seed)


class ZeroPolicy:
    """All-zero actions (under ``pd_ee_delta_pose``: hold the pose, gripper command 0)."""

    def __init__(self, chunk_size: int = 1, action_shape: Sequence[int] = ACTION_SHAPE) -> None:
        self.chunk_size = int(chunk_size)
        self.action_shape = tuple(action_shape)
        policy_chunk_size(self)

    def forward(self, obs: Any) -> np.ndarray:
        """``chunk_size`` zero actions."""
        return np.zeros((self.chunk_size, *self.action_shape), dtype=np.float32)


class RandomPolicy:
    """Uniform actions in ``[-1, 1]``, reproducible: reseeded from ``(seed, episode seed)``
    at every episode start."""

    def __init__(
        self, seed: int = 0, chunk_size: int = 1, action_shape: Sequence[int] = ACTION_SHAPE
    ) -> None:
        self.seed = int(seed)
        self.chunk_size = int(chunk_size)
        self.action_shape = tuple(action_shape)
        policy_chunk_size(self)
        self.reset(seed=0)

    def reset(self, seed: int | None = None) -> None:
        """Restart the action stream for the episode with seed ``seed``."""
        self._rng = np.random.default_rng([self.seed, int(seed or 0)])

    def forward(self, obs: Any) -> np.ndarray:
        """``chunk_size`` uniform random actions."""
        return self._rng.uniform(-1.0, 1.0, (self.chunk_size, *self.action_shape)).astype(
            np.float32
        )


class DummyChunkPolicy:
    """The reference demo's policy (benchmark.md §9): random ``(chunk_size, action_dim)``
    float32 tensor in ``[-1, 1]`` on the device of ``obs["proprio"]``."""

    def __init__(self, chunk_size: int = 8, action_dim: int = 7) -> None:
        if chunk_size <= 0:
            raise ValueError(f"chunk_size must be > 0, got {chunk_size}")
        self.chunk_size = int(chunk_size)
        self.action_dim = int(action_dim)

    def forward(self, obs: Any) -> Any:
        """Random chunk drawn from torch's global RNG (seeded per episode by the runner)."""
        import torch

        proprio = obs.get("proprio") if isinstance(obs, dict) else None
        device = proprio.device if isinstance(proprio, torch.Tensor) else torch.device("cpu")
        with torch.no_grad():
            return torch.rand(self.chunk_size, self.action_dim, device=device) * 2 - 1


def _make_oracle(env: Any, **kwargs: Any) -> Any:
    from mikasa_oracles import make_oracle

    return make_oracle(env, **kwargs)


def _make_memoryless_oracle(env: Any, **kwargs: Any) -> Any:
    from mikasa_oracles import make_oracle

    return make_oracle(env, memoryless=True, **kwargs)


ORACLE_TARGETS: tuple[str, ...] = ("oracle", "oracle-memoryless")
"""Built-ins that read the privileged state of the env they are built for."""

BUILTIN_POLICIES: dict[str, Callable[..., Any]] = {
    "zero": ZeroPolicy,
    "random": RandomPolicy,
    "oracle": _make_oracle,
    "oracle-memoryless": _make_memoryless_oracle,
}
"""Built-in policy name -> factory."""

_BUILTIN_HELP = (
    "expected one of the built-in policies (zero, random, oracle, oracle-memoryless), "
    "'package.module:Name', "
    "'path/to/file.py[:Name]' (Name: a policy class or factory; default make_policy "
    "or Policy), a policy server 'ws://HOST:PORT' or a LeRobot pretrained policy "
    "'lerobot:DIR'"
)


def is_remote_target(target: str) -> bool:
    """Whether ``target`` names a policy server (``ws://HOST:PORT``, see `mikasa_bench.remote`)."""
    return target.startswith(("ws://", "wss://"))


def is_lerobot_target(target: str) -> bool:
    """Whether ``target`` names a LeRobot pretrained policy (``lerobot:DIR``, see
    `mikasa_bench.lerobot_policy`; lerobot itself is imported only when one is used)."""
    return target.startswith("lerobot:")


@dataclass(frozen=True)
class PolicySpec:
    """A picklable description of a policy: built-in name or import target, plus kwargs.

    ``target`` is ``zero``/``random``/``oracle``, ``module:Name`` or an absolute
    ``/path/file.py:Name``.
    """

    target: str
    kwargs: dict[str, Any] = field(default_factory=dict)
    label: str = ""

    @property
    def builtin(self) -> bool:
        """Whether this is one of `BUILTIN_POLICIES`."""
        return self.target in BUILTIN_POLICIES

    def key(self) -> str:
        """A stable identity string (worker caches, job grouping)."""
        return json.dumps([self.target, self.kwargs], sort_keys=True, default=str)

    def model_record(self) -> dict[str, Any]:
        """The ``model`` entry of result files: ``{"name": ..., "config": {...}}``."""
        return {
            "name": self.label or self.target,
            "target": self.target,
            "config": dict(self.kwargs),
        }

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready form (see `from_dict`)."""
        return {"target": self.target, "kwargs": dict(self.kwargs), "label": self.label}

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> PolicySpec:
        """Inverse of `to_dict`."""
        return cls(d["target"], dict(d.get("kwargs") or {}), d.get("label", ""))


def _split_target(target: str) -> tuple[str, str | None]:
    module, sep, attr = target.rpartition(":")
    if not sep:
        return target, None
    return module, attr or None


def _is_path(module_part: str) -> bool:
    return module_part.endswith(".py") or "/" in module_part or "\\" in module_part


def _load_module(module_part: str) -> Any:
    if _is_path(module_part):
        path = Path(module_part).expanduser().resolve()
        if not path.is_file():
            raise BenchError(f"policy file {path} does not exist; {_BUILTIN_HELP}")
        # A name derived from the path: each worker re-imports the same file as the same
        # module, and two different files never collide.
        name = "mikasa_bench_user_policy_" + hashlib.sha1(str(path).encode()).hexdigest()[:12]
        if name in sys.modules:
            return sys.modules[name]
        spec = importlib.util.spec_from_file_location(name, path)
        if spec is None or spec.loader is None:
            raise BenchError(f"cannot import policy file {path}")
        module = importlib.util.module_from_spec(spec)
        sys.modules[name] = module
        try:
            spec.loader.exec_module(module)
        except Exception as exc:
            del sys.modules[name]
            raise BenchError(
                f"importing policy file {path} failed: {type(exc).__name__}: {exc}"
            ) from exc
        return module
    try:
        return importlib.import_module(module_part)
    except ImportError as exc:
        raise BenchError(
            f"cannot import policy module {module_part!r} ({exc}); {_BUILTIN_HELP}"
        ) from exc


def _load_factory(target: str) -> Callable[..., Any]:
    if target in BUILTIN_POLICIES:
        return BUILTIN_POLICIES[target]
    if is_remote_target(target):
        from .remote import remote_policy_factory

        return remote_policy_factory(target)
    if is_lerobot_target(target):
        from .lerobot_policy import lerobot_policy_factory

        return lerobot_policy_factory(target)
    module_part, attr = _split_target(target)
    module = _load_module(module_part)
    names = [attr] if attr else ["make_policy", "Policy"]
    for name in names:
        obj: Any = module
        try:
            for part in name.split("."):
                obj = getattr(obj, part)
        except AttributeError:
            continue
        if not callable(obj):
            raise BenchError(f"{module_part}:{name} is not a class or factory function")
        return obj
    raise BenchError(
        f"policy module {module_part!r} has no {' or '.join(names)}; "
        f"name the policy class with '{module_part}:ClassName'"
    )


def _context_kwargs(factory: Callable[..., Any]) -> set[str]:
    """Which of env / env_id / task the factory declares (they are passed if so)."""
    try:
        params = inspect.signature(factory).parameters
    except (TypeError, ValueError):
        return set()
    return {n for n in ("env", "env_id", "task") if n in params}


def resolve_policy(name: str, kwargs: dict[str, Any] | None = None) -> PolicySpec:
    """Validate a policy name (in the main process, before any worker starts).

    Imports user targets, checks that ``kwargs`` fit the factory's signature and returns
    the `PolicySpec` that workers use. Errors are `BenchError` naming what was expected.
    """
    kwargs = dict(kwargs or {})
    if not isinstance(name, str) or not name.strip():
        raise BenchError(f"empty policy name; {_BUILTIN_HELP}")
    name = name.strip()
    if is_remote_target(name):
        from .remote import resolve_remote_policy

        return resolve_remote_policy(name, kwargs)
    if is_lerobot_target(name):
        from .lerobot_policy import resolve_lerobot_policy

        return resolve_lerobot_policy(name, kwargs)
    if name in BUILTIN_POLICIES:
        target, label = name, name
    else:
        module_part, attr = _split_target(name)
        if not attr and not _is_path(module_part):
            raise BenchError(f"unknown policy {name!r}; {_BUILTIN_HELP}")
        if _is_path(module_part):
            module_part = str(Path(module_part).expanduser().resolve())
        target = f"{module_part}:{attr}" if attr else module_part
        factory = _load_factory(target)
        label = getattr(factory, "__name__", None) or Path(module_part).stem
    factory = _load_factory(target)
    try:
        sig = inspect.signature(factory)
    except (TypeError, ValueError):
        sig = None
    if sig is not None:
        context = {n: None for n in _context_kwargs(factory)}
        try:
            sig.bind_partial(**context, **kwargs)
        except TypeError as exc:
            raise BenchError(
                f"policy {name!r} does not accept the given kwargs {kwargs}: {exc}"
            ) from None
    return PolicySpec(target, kwargs, label)


def check_policy_supports(spec: PolicySpec, env_ids: Sequence[str]) -> None:
    """Raise `BenchError` if ``spec`` cannot run on some task (the oracle exists only for
    some families)."""
    if spec.target not in ORACLE_TARGETS:
        return
    from mikasa_oracles import has_oracle

    missing = [e for e in env_ids if not has_oracle(e)]
    if missing:
        raise BenchError(
            f"no oracle exists for {len(missing)} selected task(s): {', '.join(missing)}; "
            f"the oracle policy needs tasks of a family listed in mikasa_oracles.ORACLES"
        )


def build_policy(spec: PolicySpec, env: Any, env_id: str, task: Any = None) -> Any:
    """Instantiate ``spec`` for one env instance (called in the worker that owns ``env``).

    Factories that declare ``env``, ``env_id`` or ``task`` parameters receive them.
    """
    factory = _load_factory(spec.target)
    context = {"env": env, "env_id": env_id, "task": task}
    extra = {n: context[n] for n in _context_kwargs(factory)}
    if spec.target in ORACLE_TARGETS:
        extra = {}
        policy = factory(env, **spec.kwargs)
    elif spec.target in ("zero", "random"):
        shape = tuple(env.action_space.shape) if env is not None else ACTION_SHAPE
        policy = factory(action_shape=shape, **spec.kwargs)
    else:
        policy = factory(**extra, **spec.kwargs)
    if not callable(getattr(policy, "forward", None)):
        raise BenchError(
            f"policy {spec.label or spec.target!r} built an object of type "
            f"{type(policy).__name__} without a forward(obs) method"
        )
    policy_chunk_size(policy)
    return policy
