"""The policy server of ``mikasa-bench serve`` (openpi's websocket policy protocol).

On each connection the server builds one policy instance (recurrent state of different
workers never mixes), sends its metadata, then answers every request with the policy's
actions. A request whose ``reset`` is true resets that instance with the episode seed
before ``forward``, and the policy's calls see the episode's own global RNG states
(`EpisodeRngs`), as in a runner's worker thread. Every request is checked first
(`check_request`: unknown keys, wrong types or shapes are named). If the check or the
policy fails, the error is sent as a text message and the connection is closed (as
openpi's server does).
"""

from __future__ import annotations

import functools
import http
import logging
import threading
import time
import traceback
import urllib.parse
from collections.abc import Callable
from contextlib import nullcontext
from typing import Any

from mikasa_bench.errors import BenchError
from mikasa_bench.policies.base import ACTION_SHAPE, policy_chunk_size, reset_policy
from mikasa_bench.policies.builtin import ORACLE_TARGETS
from mikasa_bench.policies.loading import build_policy
from mikasa_bench.policies.remote.wire import (
    DEFAULT_PORT,
    PROTOCOL_VERSION,
    actions_to_numpy,
    check_request,
    decode_observation,
    packb,
    require_remote_deps,
    unpackb,
)
from mikasa_bench.policies.spec import PolicySpec, is_remote_target
from mikasa_bench.protocol.tasks import load_benchmark_tasks
from mikasa_bench.runners.episode import EpisodeRngs

__all__ = ["PolicyServer"]

# The package's logger: the client (a child, by its module name) logs under it too.
logger = logging.getLogger("mikasa_bench.policies.remote")


@functools.lru_cache(maxsize=1)
def _manifest_by_id() -> dict[str, Any]:
    return {t.env_id: t for t in load_benchmark_tasks()}


def _task_row(env_id: str | None) -> Any:
    if not env_id:
        return None
    try:
        return _manifest_by_id().get(env_id)
    except Exception:  # a broken manifest must not stop serving
        return None


class PolicyServer:
    """Serves one mikasa-bench policy over a websocket, one instance per connection.

    ``PolicyServer(spec, host, port)``; ``port=0`` picks a free port (`port` tells which).
    `serve_forever` blocks (the CLI); `start` serves from a background thread and `stop`
    ends it (tests, benchmarks). The oracle cannot be served: it reads the privileged
    state of the env instance it is built for.
    """

    def __init__(self, spec: PolicySpec, host: str = "0.0.0.0", port: int = DEFAULT_PORT) -> None:
        require_remote_deps()
        if spec.target in ORACLE_TARGETS:
            raise BenchError(
                f"the {spec.target} policy cannot be served: it reads the privileged simulator "
                "state of the env instance it is built for, which a policy server does not "
                f"have; run it in-process (mikasa-bench run --policy {spec.target})"
            )
        if is_remote_target(spec.target):
            raise BenchError(f"cannot serve a remote policy ({spec.target}); serve its source")
        # Loaded now rather than at the first episode start (EpisodeRngs needs it, and it
        # imports ManiSkill: seconds, which a client's first request would wait for).
        import mikasa_envs.render_batcher  # noqa: F401

        self.spec = spec
        self.host = host
        self._requested_port = int(port)
        self._server: Any = None
        self._thread: threading.Thread | None = None
        self._lock = threading.Lock()
        self.n_connections = 0
        """Connections opened so far."""
        self.peak_connections = 0
        """Most connections open at the same time."""
        self.env_ids: set[str] = set()
        """Env ids named by the connections so far."""
        self._open = 0
        self._port = self._requested_port

    # -- lifecycle --------------------------------------------------------------------

    def _make_server(self) -> Any:
        from websockets.sync.server import serve

        def health(connection: Any, request: Any) -> Any:
            # Plain HTTP GET /healthz (load balancers, scripts), as openpi's server has.
            if request.path == "/healthz":
                return connection.respond(http.HTTPStatus.OK, "OK\n")
            return None

        try:
            server = serve(
                self._handle,
                self.host,
                self._requested_port,
                process_request=health,
                compression=None,  # images barely compress; deflate costs ms per step
                max_size=None,
            )
        except OSError as exc:
            raise BenchError(
                f"cannot listen on {self.host}:{self._requested_port}: {exc.strerror or exc}"
            ) from None
        self._port = int(server.socket.getsockname()[1])  # the free port when 0 was asked
        return server

    @property
    def port(self) -> int:
        """The port actually listened on (after `start` / during `serve_forever`)."""
        return self._port

    @property
    def uri(self) -> str:
        """``ws://HOST:PORT`` for clients (``127.0.0.1`` when listening on every address)."""
        host = "127.0.0.1" if self.host in ("", "0.0.0.0", "::") else self.host
        return f"ws://{host}:{self.port}"

    def start(self) -> PolicyServer:
        """Listen and serve from a daemon thread; returns self."""
        self._server = self._make_server()
        self._thread = threading.Thread(
            target=self._server.serve_forever, name="mikasa-policy-server", daemon=True
        )
        self._thread.start()
        return self

    def serve_forever(self, on_ready: Callable[[PolicyServer], None] | None = None) -> None:
        """Listen and serve in this thread until interrupted (Ctrl-C) or `stop`."""
        self._server = self._make_server()
        if on_ready is not None:
            on_ready(self)
        try:
            self._server.serve_forever()
        finally:
            self._server.shutdown()

    def stop(self) -> None:
        """Stop listening and close every connection."""
        if self._server is not None:
            self._server.shutdown()
        if self._thread is not None:
            self._thread.join(timeout=10)
            self._thread = None

    def drop_connections(self) -> int:
        """Close every open connection (the clients reconnect); returns how many."""
        conns = list(self._server.connections) if self._server is not None else []
        for conn in conns:
            conn.close()
        return len(conns)

    def __enter__(self) -> PolicyServer:
        return self.start()

    def __exit__(self, *exc: Any) -> None:
        self.stop()

    # -- one connection ---------------------------------------------------------------

    def metadata(self, policy: Any, env_id: str | None) -> dict[str, Any]:
        """What the server sends first on a connection."""
        return {
            "server": "mikasa-bench",
            "protocol_version": PROTOCOL_VERSION,
            "policy": self.spec.label or self.spec.target,
            "target": self.spec.target,
            "policy_kwargs": dict(self.spec.kwargs),
            "chunk_size": policy_chunk_size(policy),
            "action_shape": list(ACTION_SHAPE),
            "env_id": env_id,
        }

    def _handle(self, conn: Any) -> None:
        from websockets.exceptions import ConnectionClosed

        query = urllib.parse.parse_qs(urllib.parse.urlsplit(conn.request.path).query)
        env_id = (query.get("env_id") or [None])[0]
        with self._lock:
            self.n_connections += 1
            self._open += 1
            self.peak_connections = max(self.peak_connections, self._open)
            if env_id:
                self.env_ids.add(env_id)
        peer = conn.remote_address
        try:
            try:
                policy = build_policy(self.spec, None, env_id or "", _task_row(env_id))
                conn.send(packb(self.metadata(policy, env_id)))
            except ConnectionClosed:
                return
            except Exception as exc:
                logger.error("building the policy for %s failed: %s", peer, exc)
                self._send_error(conn, exc)
                return
            logger.info("connection from %s (env_id %s)", peer, env_id)
            self._serve_requests(conn, policy)
        finally:
            with self._lock:
                self._open -= 1
            logger.info("connection from %s closed", peer)

    def _serve_requests(self, conn: Any, policy: Any) -> None:
        from websockets.exceptions import ConnectionClosed

        rngs: EpisodeRngs | None = None
        while True:
            try:
                data = conn.recv()
            except ConnectionClosed:
                return
            try:
                t0 = time.perf_counter()
                if isinstance(data, str):
                    raise BenchError("expected a binary msgpack request, got a text message")
                request = unpackb(data)
                check_request(request)
                if request.get("reset"):
                    seed = request.get("episode_seed")
                    # The episode's own global RNG states, as a runner thread gives them
                    # (connections share this process's RNGs).
                    rngs = EpisodeRngs(int(seed)) if seed is not None else None
                    with rngs.active() if rngs is not None else nullcontext():
                        reset_policy(policy, None if seed is None else int(seed))
                obs = decode_observation(request)
                with rngs.active() if rngs is not None else nullcontext():
                    actions = actions_to_numpy(policy.forward(obs))
                reply = {
                    "actions": actions,
                    "server_timing": {"infer_ms": 1000 * (time.perf_counter() - t0)},
                }
                conn.send(packb(reply))
            except ConnectionClosed:
                return
            except Exception as exc:
                self._send_error(conn, exc)
                return

    @staticmethod
    def _send_error(conn: Any, exc: BaseException) -> None:
        from websockets.exceptions import ConnectionClosed
        from websockets.frames import CloseCode

        text = f"{type(exc).__name__}: {exc}\n\n{traceback.format_exc()}"
        try:
            conn.send(text)  # a text frame: the client reads it as the server's error
            conn.close(CloseCode.INTERNAL_ERROR, "policy error")
        except ConnectionClosed:
            pass
