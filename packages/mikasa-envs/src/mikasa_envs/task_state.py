"""Packing a task's own state into ManiSkill's state dict, and putting it back.

ManiSkill's ``get_state_dict`` holds the simulation (actor and articulation states) and
the controller. A MIKASA task also keeps per-episode state of its own in tensors: the
drawn phase lengths, the hidden answer, latches, counters, what a lamp shows. The base
env (``MikasaVLABaseEnv.get_state_dict``) adds it under ``"task"``, packed here:

* a tensor with one row per env is saved as a ``(num_envs, -1)`` copy, the layout of
  ManiSkill's own entries: ``RecordEpisode`` stores it in the ``env_states`` of its .h5
  (one ``(T + 1, D)`` dataset per entry), ``replay_trajectory`` feeds each step's row back,
  and ``get_state()`` flattens it into the state vector;
* a dict, list or building block (an object naming its tensors in ``STATE_ATTRS``, e.g. a
  lamp or a button) becomes a nested dict; ``None`` is left out.

``restored`` is the inverse: it returns new tensors (callers replace the attribute rather
than writing into it, so tensors an earlier ``step`` returned in its info keep their values)
reshaped to the attribute's shape and dtype. It accepts what the state may have become on
its way: numpy arrays read from an .h5, a single env's row without the batch dimension
(``replay_trajectory`` indexes one step), or the floats of a flat state vector.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import torch


def pack(value: Any, num_envs: int, path: str) -> torch.Tensor | dict | None:
    """A copy of ``value`` (an attribute named ``path``) in the saved layout; None for None."""
    if value is None:
        return None
    if isinstance(value, torch.Tensor):
        if value.ndim == 0 or value.shape[0] != num_envs:
            raise ValueError(
                f"task state {path!r} must be a tensor with one row per env ({num_envs}), "
                f"got shape {tuple(value.shape)}"
            )
        return value.detach().reshape(num_envs, -1).clone()
    packed = {}
    for key, item in _items(value, path):
        entry = pack(item, num_envs, f"{path}.{key}")
        if entry is not None:
            packed[key] = entry
    return packed


def restored(current: Any, saved: Any, rows: torch.Tensor | None, num_envs: int, path: str) -> Any:
    """The value ``current`` (the attribute ``path``) takes back from ``saved``, in the envs
    ``rows`` (None: all). Tensors and dicts are new objects; building blocks are updated in
    place and returned. Entries missing from ``saved`` keep their current value."""
    if isinstance(current, torch.Tensor):
        return _restored_tensor(current, saved, rows, num_envs, path)
    if current is None:
        return None
    if not isinstance(saved, dict):
        raise ValueError(f"task state {path!r}: expected a dict of saved entries, got {type(saved).__name__}")
    if isinstance(current, dict):
        return {
            key: restored(item, saved[key], rows, num_envs, f"{path}.{key}") if key in saved else item
            for key, item in current.items()
        }
    if isinstance(current, (list, tuple)):
        return type(current)(
            restored(item, saved[str(i)], rows, num_envs, f"{path}.{i}") if str(i) in saved else item
            for i, item in enumerate(current)
        )
    for attr, item in _items(current, path):
        if attr in saved:
            setattr(current, attr, restored(item, saved[attr], rows, num_envs, f"{path}.{attr}"))
    return current


def unflatten_like(template: dict, flat: torch.Tensor) -> dict:
    """Split a flat state vector ``flat`` ((B, D)) back into ``template``'s structure.

    The inverse of ManiSkill's ``common.flatten_state_dict`` for a state dict of tensors:
    entries in insertion order, a (B,) tensor one column wide, a (B, d) one d columns.
    """
    column = 0

    def split(node: dict) -> dict:
        nonlocal column
        out = {}
        for key, value in node.items():
            if isinstance(value, dict):
                out[key] = split(value)
                continue
            width = 1 if np.ndim(value) <= 1 else int(np.shape(value)[1])
            out[key] = flat[:, column : column + width]
            column += width
        return out

    result = split(template)
    if column != flat.shape[-1]:
        raise ValueError(
            f"state vector has {flat.shape[-1]} values per env; this env's get_state() has {column}"
        )
    return result


def _items(value: Any, path: str) -> list[tuple[str, Any]]:
    if isinstance(value, dict):
        return list(value.items())
    if isinstance(value, (list, tuple)):
        return [(str(i), item) for i, item in enumerate(value)]
    attrs = getattr(type(value), "STATE_ATTRS", None)
    if attrs is None:
        raise TypeError(
            f"task state {path!r} is a {type(value).__name__}: keep per-env state in tensors "
            "(first dim num_envs), dicts or lists of them, or objects that name theirs in STATE_ATTRS"
        )
    return [(attr, getattr(value, attr)) for attr in attrs]


def _restored_tensor(
    current: torch.Tensor, saved: Any, rows: torch.Tensor | None, num_envs: int, path: str
) -> torch.Tensor:
    out = current.clone()
    if current.numel() == 0:
        return out
    value = saved if isinstance(saved, torch.Tensor) else torch.as_tensor(np.asarray(saved))
    value = value.to(device=current.device, dtype=current.dtype)
    try:
        # (R, -1) from get_state_dict, (-1,) for one env read from an .h5: R rows of the
        # attribute's per-env shape.
        value = value.reshape(-1, *current.shape[1:])
    except RuntimeError:
        raise ValueError(
            f"task state {path!r}: saved shape {tuple(value.shape)} does not fit the attribute's "
            f"shape {tuple(current.shape)}"
        ) from None
    n = value.shape[0]
    if rows is None:
        if n not in (1, num_envs):
            raise ValueError(f"task state {path!r}: {n} saved rows for {num_envs} envs")
        out[:] = value
    elif n in (1, len(rows)):
        out[rows] = value
    elif n == num_envs:
        out[rows] = value[rows]
    else:
        raise ValueError(f"task state {path!r}: {n} saved rows for {len(rows)} envs to restore")
    return out
