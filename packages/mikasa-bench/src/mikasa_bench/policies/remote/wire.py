"""Wire format of remote policies (openpi's websocket policy protocol): msgpack with
numpy arrays, the observation <-> request encoding, and the check of a request's keys.

numpy arrays travel as maps ``{"__ndarray__": True, "data": <raw bytes>, "dtype": <numpy
dtype str>, "shape": [...]}`` (openpi's ``msgpack_numpy`` convention, keys packed as
bytes), numpy scalars as ``{"__npgeneric__": True, "data": <item>, "dtype": ...}``.

Request keys follow openpi's LIBERO-style policies: the cameras as ``observation/image``
and ``observation/wrist_image``, the 7-D proprioception as ``observation/state`` (and, for
clients of protocol 1, ``observation/proprio``); the privileged simulator state of a
state-mode run travels as ``privileged/state``, a key no one mistakes for proprioception.

The observation encoding is exact: `decode_observation(encode_observation(obs))` gives
tensors equal to ``obs`` in dtype, shape and value, so a deterministic policy scores the
same served as in-process. The keys are documented in the package README (Remote
policies, Protocol).
"""

from __future__ import annotations

import urllib.parse
from collections.abc import Mapping
from typing import Any

import numpy as np

from mikasa_bench.errors import BenchError

__all__ = [
    "PROTOCOL_VERSION",
    "DEFAULT_PORT",
    "INSTALL_HINT",
    "OBS_PREFIX",
    "PRIVILEGED_STATE_KEY",
    "PROPRIO_DIM",
    "REQUEST_KEYS",
    "actions_to_numpy",
    "check_request",
    "decode_observation",
    "describe_value",
    "encode_observation",
    "packb",
    "require_remote_deps",
    "split_uri",
    "unpackb",
    "uri_with_env_id",
]

PROTOCOL_VERSION = 2
"""Bumped when request/reply keys change meaning (sent in the server's metadata). 2:
``observation/state`` is the 7-D proprio (openpi's key), the privileged state moved to
``privileged/state``."""

INSTALL_HINT = 'pip install "mikasa-bench[remote]"'
OBS_PREFIX = "observation/"
_IMAGE_KEYS = ("image", "wrist_image")  # the two 3-channel cameras of ``rgb`` (top, wrist)
PROPRIO_KEYS = (OBS_PREFIX + "state", OBS_PREFIX + "proprio")  # the same 7 values, both sent
PRIVILEGED_STATE_KEY = "privileged/state"
PROPRIO_DIM = 7  # end-effector xyz, roll-pitch-yaw, gripper
REQUEST_KEYS: dict[str, str] = {
    OBS_PREFIX + "image": "uint8 (H, W, 3), top camera",
    OBS_PREFIX + "wrist_image": "uint8 (H, W, 3), wrist camera",
    OBS_PREFIX + "state": f"float ({PROPRIO_DIM},), proprioception",
    OBS_PREFIX + "proprio": f"float ({PROPRIO_DIM},), the same proprioception",
    OBS_PREFIX + "task_cue": "numeric (N,), the task cue of some families",
    PRIVILEGED_STATE_KEY: "float (D,), privileged simulator state (state mode)",
    "prompt": "str",
    "env_id": "str or nil",
    "episode_index": "int",
    "step_index": "int",
    "episode_seed": "int or nil",
    "reset": "bool",
}
"""What a request may hold: key -> type and shape (`check_request`)."""
_INFO_TYPES: dict[str, tuple[type, ...]] = {
    "prompt": (str,),
    "env_id": (str, type(None)),
    "episode_index": (int, np.integer),
    "step_index": (int, np.integer),
    "episode_seed": (int, np.integer, type(None)),
    "reset": (bool, np.bool_),
}
DEFAULT_PORT = 8000  # openpi's default


def require_remote_deps() -> tuple[Any, Any]:
    """``(websockets, msgpack)``, or a `BenchError` saying how to install them."""
    try:
        import msgpack
        import websockets  # noqa: F401
        import websockets.sync.client  # noqa: F401
        import websockets.sync.server  # noqa: F401
    except ImportError as exc:
        raise BenchError(
            f"remote policies need the websockets and msgpack packages ({exc}); "
            f"install them with: {INSTALL_HINT}"
        ) from None
    import websockets

    return websockets, msgpack


# ------------------------------------------------------------------------------------
# msgpack with numpy arrays (openpi's msgpack_numpy convention)
# ------------------------------------------------------------------------------------


def _pack_default(obj: Any) -> Any:
    if isinstance(obj, (np.ndarray, np.generic)) and obj.dtype.kind in ("V", "O", "c"):
        raise TypeError(f"cannot send numpy dtype {obj.dtype} over msgpack")
    if isinstance(obj, np.ndarray):
        return {
            b"__ndarray__": True,
            b"data": np.ascontiguousarray(obj).tobytes(),
            b"dtype": obj.dtype.str,
            b"shape": list(obj.shape),
        }
    if isinstance(obj, np.generic):
        return {b"__npgeneric__": True, b"data": obj.item(), b"dtype": obj.dtype.str}
    raise TypeError(f"cannot send an object of type {type(obj).__name__} over msgpack")


def _get(obj: Mapping[Any, Any], key: str) -> Any:
    # Peers may pack map keys as bytes (openpi) or as str: accept both.
    return obj[key.encode()] if key.encode() in obj else obj[key]


def _unpack_hook(obj: dict[Any, Any]) -> Any:
    if b"__ndarray__" in obj or "__ndarray__" in obj:
        dtype = np.dtype(_get(obj, "dtype"))
        shape = tuple(int(d) for d in _get(obj, "shape"))
        # A copy: frombuffer views are read-only, and torch.from_numpy warns about those.
        return np.frombuffer(_get(obj, "data"), dtype=dtype).reshape(shape).copy()
    if b"__npgeneric__" in obj or "__npgeneric__" in obj:
        return np.dtype(_get(obj, "dtype")).type(_get(obj, "data"))
    return obj


def packb(obj: Any) -> bytes:
    """msgpack bytes of ``obj``; numpy arrays and scalars as openpi's msgpack_numpy packs them."""
    _, msgpack = require_remote_deps()
    return msgpack.packb(obj, default=_pack_default, use_bin_type=True)


def unpackb(data: bytes) -> Any:
    """Inverse of `packb` (arrays come back as writable numpy arrays)."""
    _, msgpack = require_remote_deps()
    return msgpack.unpackb(data, object_hook=_unpack_hook, raw=False)


# ------------------------------------------------------------------------------------
# observation <-> request
# ------------------------------------------------------------------------------------


def encode_observation(obs: Mapping[str, Any]) -> dict[str, Any]:
    """The observation entries of a request for the runner's observation ``obs``.

    Every tensor or array (batch of one env) is sent without its batch axis as a numpy
    array of the same dtype; ``rgb`` ``(1, H, W, 6)`` is split into its two cameras,
    ``observation/image`` (top) and ``observation/wrist_image`` ``(H, W, 3)``; ``proprio``
    goes as ``observation/state`` (openpi's key) and ``observation/proprio``; the
    privileged ``state`` as ``privileged/state``; any other key ``k`` as
    ``observation/k``. Key order is kept.
    """
    out: dict[str, Any] = {}
    for key, value in obs.items():
        if hasattr(value, "detach"):  # torch.Tensor, without importing torch here
            value = value.detach().cpu().numpy()
        if isinstance(value, np.ndarray):
            if value.ndim == 0 or value.shape[0] != 1:
                raise BenchError(
                    f"observation {key!r} has shape {value.shape}; a remote policy sends one "
                    f"env's observation, expected a leading batch axis of size 1"
                )
            value = value[0]
            if key == "rgb" and value.ndim == 3 and value.shape[-1] == 6:
                out[OBS_PREFIX + _IMAGE_KEYS[0]] = np.ascontiguousarray(value[..., :3])
                out[OBS_PREFIX + _IMAGE_KEYS[1]] = np.ascontiguousarray(value[..., 3:])
                continue
        if key == "proprio":
            for proprio_key in PROPRIO_KEYS:
                out[proprio_key] = value
        elif key == "state":
            out[PRIVILEGED_STATE_KEY] = value
        else:
            out[OBS_PREFIX + str(key)] = value
    return out


def decode_observation(request: Mapping[str, Any]) -> dict[str, Any]:
    """The observation an in-process policy's ``forward`` receives, rebuilt from a request:
    torch tensors on the CPU with the batch axis back, ``rgb`` from the two cameras."""
    import torch

    obs: dict[str, Any] = {}
    for key, value in request.items():
        if key == PRIVILEGED_STATE_KEY:
            name = "state"
        elif isinstance(key, str) and key.startswith(OBS_PREFIX):
            name = key[len(OBS_PREFIX) :]
        else:
            continue
        if key == PROPRIO_KEYS[0]:
            if PROPRIO_KEYS[1] in request:
                continue  # the same values: taken from observation/proprio
            name = "proprio"
        if name == _IMAGE_KEYS[1] and OBS_PREFIX + _IMAGE_KEYS[0] in request:
            continue  # joined with the top camera below
        if name == _IMAGE_KEYS[0] and OBS_PREFIX + _IMAGE_KEYS[1] in request:
            value = np.concatenate([value, request[OBS_PREFIX + _IMAGE_KEYS[1]]], axis=-1)
            name = "rgb"
        if isinstance(value, np.ndarray):
            value = torch.from_numpy(np.ascontiguousarray(value)).unsqueeze(0)
        obs[name] = value
    return obs


def check_request(request: Any) -> None:
    """`BenchError` naming every unknown key and every value of the wrong type or shape in
    a request (a msgpack map from a client), with the accepted keys; None if it is fine."""
    if not isinstance(request, dict):
        raise BenchError(f"a request must be a msgpack map, got {describe_value(request)}")
    problems = [f"unknown key {key!r}" for key in request if key not in REQUEST_KEYS]
    for key, value in request.items():
        if key in REQUEST_KEYS:
            problem = _value_problem(key, value)
            if problem:
                problems.append(f"{key!r} is {describe_value(value)}; expected {problem}")
    images = [OBS_PREFIX + k for k in _IMAGE_KEYS]
    if (images[0] in request) != (images[1] in request):
        problems.append(f"{images[0]!r} and {images[1]!r} come together (the two cameras)")
    elif images[0] in request and not problems:
        if request[images[0]].shape != request[images[1]].shape:
            problems.append("the two camera images differ in shape")
    if not problems and all(k in request for k in PROPRIO_KEYS):
        if not np.array_equal(request[PROPRIO_KEYS[0]], request[PROPRIO_KEYS[1]]):
            problems.append(
                f"{PROPRIO_KEYS[0]!r} and {PROPRIO_KEYS[1]!r} differ (both are the proprio)"
            )
    if problems:
        accepted = "; ".join(f"{k}: {v}" for k, v in REQUEST_KEYS.items())
        raise BenchError("bad request: " + "; ".join(problems) + f". Accepted keys: {accepted}")


def _value_problem(key: str, value: Any) -> str | None:
    """What ``value`` of request key ``key`` should have been, or None if it is right."""
    kind = REQUEST_KEYS[key]
    if key.startswith(OBS_PREFIX) or key == PRIVILEGED_STATE_KEY:
        if not isinstance(value, np.ndarray):
            return kind
        if key.endswith("image"):
            ok = value.dtype == np.uint8 and value.ndim == 3 and value.shape[-1] == 3
        elif key in PROPRIO_KEYS:
            ok = np.issubdtype(value.dtype, np.floating) and value.shape == (PROPRIO_DIM,)
        elif key == PRIVILEGED_STATE_KEY:
            ok = np.issubdtype(value.dtype, np.floating) and value.ndim == 1
        else:  # task_cue
            ok = (
                np.issubdtype(value.dtype, np.number) or value.dtype == np.bool_
            ) and value.ndim == 1
        return None if ok else kind
    allowed = _INFO_TYPES[key]
    if isinstance(value, bool) and bool not in allowed:
        return kind
    return None if isinstance(value, allowed) else kind


def actions_to_numpy(output: Any) -> np.ndarray:
    """A policy output as a numpy array for the reply (torch tensors leave the GPU)."""
    if hasattr(output, "detach"):
        t = output.detach().cpu()
        if str(t.dtype) == "torch.bfloat16":  # numpy has no bfloat16
            t = t.float()
        return t.numpy()
    return np.asarray(output)


def split_uri(uri: str) -> tuple[str, int]:
    """``(host, port)`` of a ``ws://HOST:PORT`` address; `BenchError` for anything else."""
    parts = urllib.parse.urlsplit(uri)
    if parts.scheme not in ("ws", "wss") or not parts.hostname:
        raise BenchError(f"bad policy server address {uri!r}; expected ws://HOST:PORT")
    try:
        port = parts.port or (443 if parts.scheme == "wss" else 80)
    except ValueError:
        raise BenchError(
            f"bad port in policy server address {uri!r}; expected ws://HOST:PORT"
        ) from None
    return parts.hostname, port


def uri_with_env_id(uri: str, env_id: str | None) -> str:
    """``uri`` with ``?env_id=...`` added: the server builds the connection's policy for it."""
    if not env_id:
        return uri
    parts = urllib.parse.urlsplit(uri)
    query = urllib.parse.parse_qsl(parts.query) + [("env_id", env_id)]
    return urllib.parse.urlunsplit(parts._replace(query=urllib.parse.urlencode(query)))


def describe_value(value: Any) -> str:
    """A short description of a received value for error messages."""
    if isinstance(value, np.ndarray):
        return f"an array of shape {value.shape} and dtype {value.dtype}"
    if isinstance(value, dict):
        keys = ", ".join(repr(k) for k in list(value)[:8])
        return f"a map with keys [{keys}]"
    if isinstance(value, (bytes, bytearray)):
        return f"{len(value)} bytes"
    text = repr(value)
    return f"{type(value).__name__} {text[:80]}{'...' if len(text) > 80 else ''}"
