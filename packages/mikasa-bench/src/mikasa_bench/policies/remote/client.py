"""Remote policies: ``mikasa-bench run --policy ws://HOST:PORT`` evaluates a policy served
over a websocket (``mikasa-bench serve``, `mikasa_bench.policies.remote.server.PolicyServer`,
or any server speaking openpi's protocol with these keys).

A connection: the server sends its metadata (a map) first; then each binary message the
client sends is one request (`RemotePolicy.request`) and the server answers it with
``{"actions": (7,) | (K, 7) | (1, K, 7), "server_timing": {...}}``, or with a text
message holding its error. Wire format: `mikasa_bench.policies.remote.wire`.
"""

from __future__ import annotations

import functools
import logging
import socket
import time
import weakref
from collections.abc import Callable, Mapping
from typing import Any

import numpy as np

from mikasa_bench.errors import BenchError, EpisodeInterrupted
from mikasa_bench.policies.base import ACTION_SHAPE
from mikasa_bench.policies.remote.wire import (
    describe_value,
    encode_observation,
    packb,
    require_remote_deps,
    split_uri,
    unpackb,
    uri_with_env_id,
)
from mikasa_bench.policies.spec import PolicySpec

__all__ = ["RemotePolicy", "remote_policy_factory", "resolve_remote_policy"]

logger = logging.getLogger(__name__)

_REPLY_HELP = (
    "expected a msgpack map {'actions': array} with one action (7,), a chunk (K, 7) or a "
    "batched chunk (1, K, 7) of numbers"
)


class _Socket:
    """Holds the current connection, so a finalizer can close it (the websockets sync
    client runs a thread that keeps the connection object alive until it is closed)."""

    def __init__(self) -> None:
        self.ws: Any = None

    def close(self) -> None:
        ws, self.ws = self.ws, None
        if ws is not None:
            try:
                ws.close()
            except Exception:
                pass


class RemotePolicy:
    """A policy served elsewhere (``mikasa-bench serve``, openpi's ``WebsocketPolicyServer``
    or any server speaking the same protocol); built per worker by
    `mikasa_bench.policies.loading.build_policy`.

    ``timeout_s``: the longest wait for one reply, and the only clock of a connection (no
    websocket keepalive runs: a server busy computing answers no pings); past it, a
    `BenchError` naming the server. ``connect_timeout_s``: per connection attempt.
    ``retries``: connection attempts after the first (with backoff), and how often an
    episode may be restarted: a connection lost mid-episode raises `EpisodeInterrupted`,
    and the worker plays the episode again from its reset on a new connection (the
    server's fresh policy), never continuing it with a policy that forgot its start.
    """

    def __init__(
        self,
        uri: str,
        env: Any = None,
        env_id: str | None = None,
        task: Any = None,
        timeout_s: float = 60.0,
        connect_timeout_s: float = 10.0,
        retries: int = 3,
    ) -> None:
        require_remote_deps()
        split_uri(uri)
        if not timeout_s or timeout_s <= 0 or connect_timeout_s <= 0 or int(retries) < 0:
            raise BenchError(
                f"remote policy options must be timeout_s > 0, connect_timeout_s > 0 and "
                f"retries >= 0; got {timeout_s}, {connect_timeout_s}, {retries}"
            )
        self.uri = uri
        self.timeout_s = float(timeout_s)
        self.connect_timeout_s = float(connect_timeout_s)
        self.retries = int(retries)
        self.env_id = env_id or None
        self.prompt = str(getattr(task, "language_instruction", "") or "")
        shape = getattr(getattr(env, "action_space", None), "shape", None)
        self.action_shape: tuple[int, ...] = tuple(shape) if shape else ACTION_SHAPE
        self.metadata: dict[str, Any] = {}
        self.n_connects = 0
        self._sock = _Socket()
        weakref.finalize(self, self._sock.close)
        self._episode_index = -1
        self._episode_seed: int | None = None
        self._step_index = 0
        self._reset_pending = False
        self._connect_with_retries()
        self.chunk_size = self._chunk_from_metadata()

    @property
    def max_episode_restarts(self) -> int:
        """How often the worker may restart an episode whose connection dropped."""
        return self.retries

    # -- connection -------------------------------------------------------------------

    def _connect_once(self) -> None:
        websockets, _ = require_remote_deps()
        from websockets.sync.client import connect

        ws = connect(
            uri_with_env_id(self.uri, self.env_id),
            open_timeout=self.connect_timeout_s,
            compression=None,
            max_size=None,
            # No keepalive pings: openpi's server computes inside its event loop and answers
            # none meanwhile, so a slow inference would end the connection whatever
            # timeout_s says. The wait for each reply is bounded by timeout_s instead.
            ping_interval=None,
            ping_timeout=None,
        )
        try:
            first = ws.recv(timeout=self.timeout_s)
        except TimeoutError:
            ws.close()
            raise BenchError(
                f"policy server {self.uri} sent no metadata within timeout_s={self.timeout_s:g} s "
                f"of connecting"
            ) from None
        except websockets.exceptions.ConnectionClosed:
            ws.close()
            raise
        if isinstance(first, str):
            ws.close()
            raise BenchError(f"policy server {self.uri} could not build its policy:\n{first}")
        try:
            metadata = unpackb(first)
        except Exception:
            metadata = first  # not msgpack: described as raw bytes below
        if not isinstance(metadata, dict):
            ws.close()
            raise BenchError(
                f"policy server {self.uri} sent malformed metadata on connect: expected a "
                f"msgpack map, got {describe_value(metadata)}"
            )
        self._sock.ws = ws
        self.metadata = metadata
        self.n_connects += 1

    def _connect_with_retries(self) -> None:
        websockets, _ = require_remote_deps()
        last: BaseException | None = None
        for attempt in range(self.retries + 1):
            if attempt:
                time.sleep(min(0.25 * 2**attempt, 4.0))  # 0.5, 1, 2, 4, 4 ... s
            try:
                self._connect_once()
                return
            except websockets.exceptions.InvalidHandshake as exc:
                raise BenchError(
                    f"{self.uri} is not a websocket policy server (handshake failed: {exc})"
                ) from None
            except (OSError, websockets.exceptions.ConnectionClosed) as exc:
                last = exc  # refused, unreachable, connect timeout, closed at once: retry
        host, port = split_uri(self.uri)
        raise BenchError(
            f"cannot reach policy server {self.uri} ({type(last).__name__}: {last}) after "
            f"{self.retries + 1} attempt(s); start one with "
            f"`mikasa-bench serve --policy POLICY --port {port}`, or raise retries / "
            f"connect_timeout_s in --policy-kwargs"
        )

    def _chunk_from_metadata(self) -> int:
        # openpi servers send no chunk_size: the replies' K is used as it comes, and the
        # runner records the K it actually received (`EpisodeResult.chunk_sizes`).
        k = self.metadata.get("chunk_size", 1)
        if isinstance(k, bool) or not isinstance(k, (int, np.integer)) or k <= 0:
            raise BenchError(
                f"policy server {self.uri} sent malformed metadata: chunk_size {k!r} is not a "
                f"positive int"
            )
        return int(k)

    def close(self) -> None:
        """Close the connection (it is also closed when this object is garbage collected)."""
        self._sock.close()

    # -- policy interface -------------------------------------------------------------

    def reset(self, seed: int | None = None) -> None:
        """Start an episode: the next request carries ``reset`` and the episode seed."""
        self._episode_index += 1
        self._episode_seed = None if seed is None else int(seed)
        self._step_index = 0
        self._reset_pending = True

    def request(self, obs: Mapping[str, Any]) -> dict[str, Any]:
        """The request `forward` sends for ``obs`` (see the package README)."""
        return {
            **encode_observation(obs),
            "prompt": self.prompt,
            "env_id": self.env_id,
            "episode_index": max(self._episode_index, 0),
            "step_index": self._step_index,
            "episode_seed": self._episode_seed,
            "reset": self._reset_pending,
        }

    def forward(self, obs: Mapping[str, Any]) -> np.ndarray:
        """Send ``obs``, return the server's actions (checked: ``A``, ``(K, *A)`` or ``(1, K, *A)``).

        A connection lost at the episode's first request is replaced at once (the
        request carries ``reset``); lost later, it raises `EpisodeInterrupted`: the
        server's policy has lost the episode's earlier steps, so the episode must start
        over (the next `reset` and `forward` connect again).
        """
        websockets, _ = require_remote_deps()
        message = self.request(obs)
        where = self._where(message)
        attempts = 0
        while True:
            if self._sock.ws is None:
                self._connect_with_retries()
            try:
                self._sock.ws.send(packb(message))
                data = self._sock.ws.recv(timeout=self.timeout_s)
                break
            except TimeoutError:
                # The late reply would answer the wrong request: drop this connection.
                self._sock.close()
                raise BenchError(
                    f"policy server {self.uri} did not reply within timeout_s={self.timeout_s:g} s "
                    f"({where}); raise it with --policy-kwargs '{{\"timeout_s\": 120}}'"
                ) from None
            except (OSError, websockets.exceptions.ConnectionClosed) as exc:
                # 1011 is a server's error, unless its own keepalive gave up on us.
                rcvd = getattr(exc, "rcvd", None)
                closed_by_error = getattr(rcvd, "code", None) == 1011 and "keepalive" not in str(
                    getattr(rcvd, "reason", "")
                )
                self._sock.close()
                lost = f"lost the connection to policy server {self.uri} ({where}): {type(exc).__name__}: {exc}"
                if closed_by_error:
                    raise BenchError(lost) from None
                if not self._reset_pending:
                    raise EpisodeInterrupted(lost) from None
                attempts += 1
                if attempts > self.retries:
                    raise BenchError(lost) from None
                logger.warning("connection to %s dropped (%s); reconnecting", self.uri, exc)
        self._reset_pending = False
        actions = self._check_reply(data, where)
        k = 1 if actions.shape == self.action_shape else actions.shape[-len(self.action_shape) - 1]
        self._step_index += int(k)
        return actions

    def _where(self, message: Mapping[str, Any]) -> str:
        seed = message["episode_seed"]
        episode = (
            f"episode seed {seed}" if seed is not None else f"episode {message['episode_index']}"
        )
        return f"{episode}, step {message['step_index']}"

    def _check_reply(self, data: Any, where: str) -> np.ndarray:
        if isinstance(data, str):
            self._sock.close()
            raise BenchError(f"policy server {self.uri} failed ({where}):\n{data}")
        try:
            reply = unpackb(data)
        except Exception as exc:
            raise BenchError(
                f"policy server {self.uri} sent a malformed reply ({where}): {len(data)} bytes "
                f"that are not msgpack ({type(exc).__name__}); {_REPLY_HELP}"
            ) from None
        if not isinstance(reply, dict) or "actions" not in reply:
            raise BenchError(
                f"policy server {self.uri} sent a malformed reply ({where}): got "
                f"{describe_value(reply)}; {_REPLY_HELP}"
            )
        actions = reply["actions"]
        if not isinstance(actions, np.ndarray):
            try:
                actions = np.asarray(actions)
            except Exception:
                actions = None
        if not isinstance(actions, np.ndarray) or not (
            np.issubdtype(actions.dtype, np.number) or actions.dtype == np.bool_
        ):
            raise BenchError(
                f"policy server {self.uri} sent a malformed reply ({where}): 'actions' is "
                f"{describe_value(reply['actions'])}; {_REPLY_HELP}"
            )
        a = self.action_shape
        dims = ", ".join(str(d) for d in a)
        ok = (
            actions.shape == a
            or (actions.ndim == len(a) + 1 and actions.shape[1:] == a and actions.shape[0] >= 1)
            or (
                actions.ndim == len(a) + 2
                and actions.shape[0] == 1
                and actions.shape[2:] == a
                and actions.shape[1] >= 1
            )
        )
        if not ok:
            raise BenchError(
                f"policy server {self.uri} returned actions of shape {actions.shape} ({where}); "
                f"accepted: one action {a}, a chunk (K, {dims}) or a batched chunk "
                f"(1, K, {dims}) with K >= 1"
            )
        finite = np.isfinite(actions.astype(np.float64, copy=False))
        if not finite.all():
            bad = np.argwhere(~finite)[0].tolist()
            raise BenchError(
                f"policy server {self.uri} returned non-finite actions ({where}): "
                f"{int((~finite).sum())} of {actions.size} values are NaN or inf, the first "
                f"at index {tuple(bad)}"
            )
        return actions


# ------------------------------------------------------------------------------------
# policy resolution hooks (mikasa_bench.policies.loading)
# ------------------------------------------------------------------------------------


def remote_policy_factory(target: str) -> Callable[..., RemotePolicy]:
    """The factory `build_policy` calls for a ``ws://`` target (it declares env, env_id, task)."""
    return functools.partial(RemotePolicy, target)


def resolve_remote_policy(uri: str, kwargs: dict[str, Any] | None = None) -> PolicySpec:
    """Check a ``ws://HOST:PORT`` policy in the main process: the extra is installed, the
    kwargs are `RemotePolicy` options and the server accepts TCP connections."""
    import inspect

    require_remote_deps()
    kwargs = dict(kwargs or {})
    host, port = split_uri(uri)
    try:
        inspect.signature(RemotePolicy).bind_partial(uri, **kwargs)
    except TypeError as exc:
        raise BenchError(
            f"--policy-kwargs for a remote policy accepts timeout_s, connect_timeout_s and "
            f"retries ({exc}); the served policy's own kwargs go to `mikasa-bench serve`"
        ) from None
    timeout = float(kwargs.get("connect_timeout_s", 10.0))
    try:
        socket.create_connection((host, port), timeout=timeout).close()
    except OSError as exc:
        raise BenchError(
            f"cannot reach policy server {uri} ({exc.strerror or exc}); start one with "
            f"`mikasa-bench serve --policy POLICY --port {port}`"
        ) from None
    return PolicySpec(uri, kwargs, f"remote-{host}-{port}")
