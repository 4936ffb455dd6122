"""Loading policies: `resolve_policy` checks a policy name in the main process and returns
its `PolicySpec`; `build_policy` builds it in the worker that owns the env.

A policy name is a built-in (`mikasa_bench.policies.builtin`), ``package.module:Name``,
``path/to/file.py[:Name]``, a policy server ``ws://HOST:PORT``
(`mikasa_bench.policies.remote.client`) or a LeRobot pretrained policy ``lerobot:DIR``
(`mikasa_bench.lerobot.policy`).
"""

from __future__ import annotations

import hashlib
import importlib
import importlib.util
import inspect
import sys
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

from mikasa_bench.errors import BenchError
from mikasa_bench.lerobot.policy import lerobot_policy_factory, resolve_lerobot_policy
from mikasa_bench.policies.base import ACTION_SHAPE, policy_chunk_size
from mikasa_bench.policies.builtin import BUILTIN_POLICIES, ORACLE_TARGETS
from mikasa_bench.policies.oracle_extra import require_oracles
from mikasa_bench.policies.remote.client import remote_policy_factory, resolve_remote_policy
from mikasa_bench.policies.spec import PolicySpec, is_lerobot_target, is_remote_target

__all__ = ["build_policy", "check_policy_supports", "resolve_policy"]

_BUILTIN_HELP = (
    "expected one of the built-in policies (zero, random, oracle, oracle-memoryless), "
    "'package.module:Name', "
    "'path/to/file.py[:Name]' (Name: a policy class or factory; default make_policy "
    "or Policy), a policy server 'ws://HOST:PORT' or a LeRobot pretrained policy "
    "'lerobot:DIR'"
)


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
        return remote_policy_factory(target)
    if is_lerobot_target(target):
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
        return resolve_remote_policy(name, kwargs)
    if is_lerobot_target(name):
        return resolve_lerobot_policy(name, kwargs)
    if name in ORACLE_TARGETS:
        require_oracles(f"the {name} policy")  # the missing extra named before workers start
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
    has_oracle = require_oracles(f"the {spec.target} policy").has_oracle
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
