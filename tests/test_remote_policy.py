"""Remote policies: `mikasa-bench serve` and `run --policy ws://HOST:PORT`.

Server and clients run on 127.0.0.1 with a free port; evaluations use state
observations (the fast non-canonical mode) on one or two short tasks. The policies
below are loaded from this file by path (``tests/test_remote_policy.py:StatePolicy``),
in-process, by the server and by spawned workers alike.
"""

from __future__ import annotations

import json
import sys
import threading
import time
from contextlib import contextmanager
from pathlib import Path

import msgpack
import numpy as np
import pytest
import torch
from mikasa_bench import cli
from mikasa_bench.errors import BenchError, EpisodeInterrupted
from mikasa_bench.policies import resolve_policy
from mikasa_bench.policies.remote.client import RemotePolicy
from mikasa_bench.policies.remote.server import PolicyServer
from mikasa_bench.policies.remote.wire import (
    decode_observation,
    encode_observation,
    packb,
    unpackb,
)

TASK = "RememberColor3-VLA-v0"
TASK2 = "FindImposterColor3-VLA-v0"
PER_EPISODE = ("successes", "returns", "episode_lengths", "episode_seeds")
HERE = str(Path(__file__).resolve())


# ------------------------------------------------------------------------------------
# policies served in the tests
# ------------------------------------------------------------------------------------


class StatePolicy:
    """Deterministic and stateless: steers the gripper from the observed state."""

    def forward(self, obs):
        assert isinstance(obs["proprio"], torch.Tensor) and obs["proprio"].shape == (1, 7)
        assert obs["proprio"].dtype == torch.float32 and obs["state"].dtype == torch.float32
        p, s = obs["proprio"][0], obs["state"][0]
        a = torch.zeros(7)
        a[:3] = torch.tanh(4 * (s[:3] - p[:3]))
        a[6] = torch.sign(s[3])
        return a


class CountingChunkPolicy:
    """Deterministic and recurrent (a step counter cleared by reset), chunks of 2."""

    chunk_size = 2

    def __init__(self) -> None:
        self.calls = 0

    def reset(self, seed=None) -> None:
        self.calls = 0

    def forward(self, obs):
        p = obs["proprio"][0].numpy()
        a = np.zeros((2, 7), dtype=np.float32)
        a[:, :3] = np.clip(-p[:3], -1, 1)
        a[:, 6] = 1.0 if self.calls % 4 < 2 else -1.0
        self.calls += 1
        return a


class StepCounterPolicy:
    """Deterministic, one action a call, and its actions depend on its memory (the steps
    since its reset): continuing an episode after losing that memory changes them."""

    def __init__(self) -> None:
        self.steps = 0

    def reset(self, seed=None) -> None:
        self.steps = 0

    def forward(self, obs):
        a = np.zeros(7, dtype=np.float32)
        a[:3] = np.float32(0.8) * np.sin(np.array([1.0, 2.0, 3.0]) * self.steps / 5)
        a[6] = 1.0 if self.steps // 6 % 2 == 0 else -1.0
        self.steps += 1
        return a


class NanPolicy:
    def __init__(self) -> None:
        self.calls = 0

    def reset(self, seed=None) -> None:
        self.calls = 0

    def forward(self, obs):
        self.calls += 1
        return np.full(7, np.nan if self.calls == 3 else 0.0, dtype=np.float32)


class WrongShapePolicy:
    def forward(self, obs):
        return np.zeros(3, dtype=np.float32)


class SlowPolicy:
    def forward(self, obs):
        time.sleep(1.5)
        return np.zeros(7, dtype=np.float32)


class FailingPolicy:
    def forward(self, obs):
        raise RuntimeError("model exploded")


# ------------------------------------------------------------------------------------
# helpers
# ------------------------------------------------------------------------------------


@contextmanager
def serving(target: str, port: int = 0, **kwargs):
    server = PolicyServer(resolve_policy(target, kwargs), host="127.0.0.1", port=port).start()
    try:
        yield server
    finally:
        server.stop()


@contextmanager
def raw_server(replies, port: int = 0):
    """A bare websocket server: sends metadata, then ``replies(request)`` for each request
    (bytes or str; None closes the connection instead), recording the decoded requests."""
    from websockets.sync.server import serve

    requests: list[dict] = []

    def handler(conn):
        conn.send(packb({"chunk_size": 1}))
        for data in conn:
            requests.append(unpackb(data))
            reply = replies(requests[-1])
            if reply is None:
                conn.close()
                return
            conn.send(reply)

    server = serve(handler, "127.0.0.1", port, compression=None, max_size=None)
    thread = threading.Thread(target=server.serve_forever, daemon=True)
    thread.start()
    try:
        yield f"ws://127.0.0.1:{server.socket.getsockname()[1]}", requests
    finally:
        server.shutdown()
        thread.join(timeout=10)


def _free_port() -> int:
    import socket

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _run(out: Path, policy: str, kwargs=None, workers: int = 0, tasks=(TASK,), episodes=2):
    argv = ["run", "--num-episodes", str(episodes), "--obs-mode", "state", "--no-progress"]
    for t in tasks:
        argv += ["--task", t]
    argv += ["--no-report", "--policy", policy, "--workers", str(workers), "--out", str(out)]
    if kwargs:
        argv += ["--policy-kwargs", json.dumps(kwargs)]
    return cli.main(argv)


def _episodes(out: Path, tasks=(TASK,)) -> dict:
    res = {}
    for t in tasks:
        r = json.loads((out / f"{t}.json").read_text())
        res[t] = {k: r[k] for k in PER_EPISODE}
    return res


def _fake_obs(rgb: bool = True) -> dict:
    g = torch.Generator().manual_seed(0)
    obs = {"proprio": torch.randn(1, 7, generator=g)}
    if rgb:
        obs["rgb"] = torch.randint(0, 256, (1, 128, 128, 6), dtype=torch.uint8, generator=g)
    else:
        obs["state"] = torch.randn(1, 35, generator=g)
    return obs


# ------------------------------------------------------------------------------------
# wire format
# ------------------------------------------------------------------------------------


def test_arrays_use_openpi_msgpack_numpy_convention():
    arr = np.arange(6, dtype=np.float32).reshape(2, 3)
    raw = msgpack.unpackb(packb({"a": arr}), raw=False)
    assert set(raw["a"]) == {b"__ndarray__", b"data", b"dtype", b"shape"}
    assert raw["a"][b"dtype"] == "<f4" and list(raw["a"][b"shape"]) == [2, 3]
    back = unpackb(packb({"a": arr, "s": np.int64(5)}))
    assert np.array_equal(back["a"], arr) and back["a"].dtype == np.float32
    assert back["a"].flags.writeable and back["s"] == 5 and back["s"].dtype == np.int64


@pytest.mark.parametrize("rgb", [True, False])
def test_observation_round_trip_is_exact(rgb):
    obs = _fake_obs(rgb)
    request = encode_observation(obs)
    if rgb:
        assert list(request) == [
            "observation/state",
            "observation/proprio",
            "observation/image",
            "observation/wrist_image",
        ]
        assert request["observation/image"].shape == (128, 128, 3)
        assert np.array_equal(request["observation/wrist_image"], obs["rgb"][0, ..., 3:].numpy())
    else:
        # The privileged state never travels under a key that reads as proprio.
        assert list(request) == ["observation/state", "observation/proprio", "privileged/state"]
        assert np.array_equal(request["privileged/state"], obs["state"][0].numpy())
    # observation/state is the 7-D proprio, the key openpi's LIBERO-style policies read.
    assert request["observation/proprio"].shape == (7,)
    assert np.array_equal(request["observation/state"], obs["proprio"][0].numpy())
    back = decode_observation(unpackb(packb(request)))
    assert list(back) == list(obs)
    for k in obs:
        assert back[k].dtype == obs[k].dtype and torch.equal(back[k], obs[k])


def test_requests_carry_the_documented_keys(tmp_path):
    zeros = packb({"actions": np.zeros(7, dtype=np.float32)})
    with raw_server(lambda req: zeros) as (uri, requests):
        assert _run(tmp_path / "run", uri) == 0
    assert len(requests) == 50  # 2 episodes x 25 steps, one action per request
    from mikasa_bench.protocol.tasks import load_benchmark_tasks

    prompt = next(t for t in load_benchmark_tasks() if t.env_id == TASK).language_instruction
    for i, req in enumerate(requests):
        assert set(req) == {
            "observation/proprio",
            "observation/state",
            "privileged/state",
            "prompt",
            "env_id",
            "episode_index",
            "step_index",
            "episode_seed",
            "reset",
        }
        ep, step = divmod(i, 25)
        assert req["episode_index"] == ep and req["step_index"] == step
        assert req["episode_seed"] == 4242424242 + ep and req["reset"] == (step == 0)
        assert req["prompt"] == prompt and req["env_id"] == TASK
        assert req["observation/proprio"].dtype == np.float32
        assert req["observation/proprio"].shape == (7,) and req["privileged/state"].ndim == 1
        assert np.array_equal(req["observation/state"], req["observation/proprio"])


# ------------------------------------------------------------------------------------
# results equal in-process results
# ------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    "target, kwargs",
    [
        (f"{HERE}:StatePolicy", {}),
        (f"{HERE}:CountingChunkPolicy", {}),
        ("random", {"seed": 7}),
        ("mikasa_bench.policies:DummyChunkPolicy", {"chunk_size": 4}),  # torch's global RNG
    ],
    ids=["stateless", "recurrent-chunked", "random", "global-rng"],
)
def test_served_policy_scores_like_in_process(tmp_path, target, kwargs):
    assert _run(tmp_path / "local", target, kwargs) == 0
    with serving(target, **kwargs) as server:
        assert _run(tmp_path / "remote", server.uri) == 0
    assert _episodes(tmp_path / "local") == _episodes(tmp_path / "remote")
    local = json.loads((tmp_path / "local" / f"{TASK}.json").read_text())
    remote = json.loads((tmp_path / "remote" / f"{TASK}.json").read_text())
    assert remote["action_chunk_size"] == local["action_chunk_size"]  # from the replies
    assert remote["model"]["target"] == server.uri


def test_two_workers_share_one_server(tmp_path):
    target = f"{HERE}:CountingChunkPolicy"
    tasks = (TASK, TASK2)
    assert _run(tmp_path / "local", target, tasks=tasks) == 0
    with serving(target) as server:
        assert _run(tmp_path / "remote", server.uri, workers=2, tasks=tasks) == 0
    assert _episodes(tmp_path / "local", tasks) == _episodes(tmp_path / "remote", tasks)
    assert server.env_ids == set(tasks)
    assert server.peak_connections == 2  # one connection (and policy) per worker


# ------------------------------------------------------------------------------------
# dropped connections
# ------------------------------------------------------------------------------------


def test_a_connection_lost_mid_episode_restarts_the_episode():
    with serving("random", seed=3) as server:
        policy = RemotePolicy(server.uri, env_id=TASK)
        obs = _fake_obs(rgb=True)
        policy.reset(seed=11)
        first = [policy.forward(obs) for _ in range(3)]
        assert server.drop_connections() == 1
        time.sleep(0.1)
        # Never continued by a fresh server policy that missed the episode's start.
        with pytest.raises(EpisodeInterrupted, match=r"episode seed 11, step 3"):
            policy.forward(obs)
        # Played again from its reset, on a new connection.
        policy.reset(seed=11)
        again = policy.forward(obs)
        assert policy.n_connects == 2 and server.n_connections == 2
        assert np.array_equal(again, first[0]) and not np.array_equal(first[0], first[1])
        policy.close()


def test_a_connection_lost_at_an_episode_start_is_replaced_at_once():
    with serving("random", seed=3) as server:
        policy = RemotePolicy(server.uri, env_id=TASK)
        policy.reset(seed=11)
        first = policy.forward(_fake_obs(rgb=False))
        assert server.drop_connections() == 1
        time.sleep(0.1)
        policy.reset(seed=11)
        assert np.array_equal(policy.forward(_fake_obs(rgb=False)), first)
        assert policy.n_connects == 2
        policy.close()


def test_dropped_connections_leave_the_results_of_an_uninterrupted_run(tmp_path):
    """Connections dropped at random moments, a policy whose actions depend on its memory:
    every interrupted episode is played again from its reset (on a rewound scene), so the
    results equal the uninterrupted run's, whichever episodes were hit."""
    target = f"{HERE}:StepCounterPolicy"
    tasks, episodes = (TASK,), 6  # episodes 5: a second scene
    assert _run(tmp_path / "local", target, episodes=episodes) == 0
    with serving(target) as server:
        stop = threading.Event()

        def dropper():  # 8 drops, 0.15 s apart: a bounded number of restarts
            for _ in range(8):
                if stop.wait(0.15):
                    return
                server.drop_connections()

        thread = threading.Thread(target=dropper, daemon=True)
        thread.start()
        try:
            assert _run(tmp_path / "remote", server.uri, {"retries": 10}, episodes=episodes) == 0
        finally:
            stop.set()
            thread.join()
    assert server.n_connections > 2
    assert _episodes(tmp_path / "local", tasks) == _episodes(tmp_path / "remote", tasks)
    result = json.loads((tmp_path / "remote" / f"{TASK}.json").read_text())
    journal = tmp_path / "remote" / "meta" / "episodes.jsonl"
    restarts = [json.loads(line)["restarts"] for line in journal.read_text().splitlines()]
    assert sorted(result["episode_restarts"]) == sorted(restarts)


def test_retries_spent_stop_the_run_and_resume_finishes_it(tmp_path, capsys):
    target = f"{HERE}:StepCounterPolicy"
    assert _run(tmp_path / "local", target) == 0
    counter = StepCounterPolicy()

    def drop_at_step_3(request):
        if request["episode_seed"] == 4242424242 + 1 and request["step_index"] == 3:
            return None  # closes the connection instead of replying, on every attempt
        if request["reset"]:
            counter.reset()
        return packb({"actions": counter.forward(None)})

    port = _free_port()
    with raw_server(drop_at_step_3, port) as (uri, _):
        assert _run(tmp_path / "run", uri, {"retries": 1}) == 2
    err = capsys.readouterr().err
    assert f"lost the connection to policy server {uri} (episode seed 4242424243, step 3)" in err
    assert "restarted 1 time(s), the most the policy allows" in err
    journal = tmp_path / "run" / "meta" / "episodes.jsonl"
    assert [json.loads(line)["episode"] for line in journal.read_text().splitlines()] == [0]
    # --resume keeps the run's settings: the server comes back at the same address.
    with serving(target, port=port):
        argv = ["run", "--resume", str(tmp_path / "run"), "--no-progress", "--no-report"]
        assert cli.main(argv) == 0
    assert _episodes(tmp_path / "local") == _episodes(tmp_path / "run")


def test_chunk_sizes_come_from_the_replies(tmp_path):
    calls = []

    def alternating(request):  # K = 2, 3, 2, 3, ... whatever the metadata says (1)
        calls.append(1)
        return packb({"actions": np.zeros((2 + len(calls) % 2, 7), np.float32)})

    with raw_server(alternating) as (uri, _):
        assert _run(tmp_path / "run", uri) == 0
    result = json.loads((tmp_path / "run" / f"{TASK}.json").read_text())
    assert result["action_chunk_size"] == 3 and result["action_chunk_size_varied"] is True
    journal = tmp_path / "run" / "meta" / "episodes.jsonl"
    assert [
        json.loads(line)["action_chunk_sizes"] for line in journal.read_text().splitlines()
    ] == [
        [2, 3],
        [2, 3],
    ]


def test_non_finite_actions_of_an_in_process_policy_name_the_step(tmp_path, capsys):
    assert _run(tmp_path / "run", f"{HERE}:NanPolicy") == 2
    err = capsys.readouterr().err
    assert "non-finite actions (NaN or inf) at step 2" in err
    assert f"{TASK} episode 0 (seed 4242424242)" in err


# ------------------------------------------------------------------------------------
# errors
# ------------------------------------------------------------------------------------


def test_unreachable_server_is_a_clear_error(tmp_path, capsys):
    uri = f"ws://127.0.0.1:{_free_port()}"
    assert _run(tmp_path / "run", uri) == 2
    err = capsys.readouterr().err
    assert f"cannot reach policy server {uri}" in err and "mikasa-bench serve" in err
    # The worker-side client says the same after its retries.
    with pytest.raises(BenchError, match="cannot reach policy server .* after 2 attempt"):
        RemotePolicy(uri, retries=1, connect_timeout_s=1)


def test_malformed_reply_is_a_clear_error():
    with raw_server(lambda req: packb({"action": [0.0] * 7})) as (uri, _):
        policy = RemotePolicy(uri)
        with pytest.raises(BenchError, match=r"malformed reply .*got a map with keys \['action'\]"):
            policy.forward(_fake_obs(rgb=False))
    with raw_server(lambda req: b"\xc1\xc1") as (uri, _):
        with pytest.raises(BenchError, match="malformed reply .*2 bytes that are not msgpack"):
            RemotePolicy(uri).forward(_fake_obs(rgb=False))
    with raw_server(lambda req: packb({"actions": "left"})) as (uri, _):
        with pytest.raises(BenchError, match="'actions' is str 'left'"):
            RemotePolicy(uri).forward(_fake_obs(rgb=False))


def test_wrong_action_shape_is_a_clear_error(tmp_path, capsys):
    with serving(f"{HERE}:WrongShapePolicy") as server:
        assert _run(tmp_path / "run", server.uri) == 2
    err = capsys.readouterr().err
    assert f"policy server {server.uri} returned actions of shape (3,)" in err
    assert "accepted: one action (7,), a chunk (K, 7) or a batched chunk (1, K, 7)" in err
    assert f"{TASK} episode 0 (seed 4242424242)" in err


def test_timeout_names_server_and_timeout():
    with serving(f"{HERE}:SlowPolicy") as server:
        policy = RemotePolicy(server.uri, timeout_s=0.3)
        t0 = time.perf_counter()
        with pytest.raises(BenchError, match=rf"{server.uri} did not reply within timeout_s=0.3 s"):
            policy.forward(_fake_obs(rgb=False))
        assert time.perf_counter() - t0 < 1.2


def test_policy_error_on_the_server_reaches_the_client():
    with serving(f"{HERE}:FailingPolicy") as server:
        with pytest.raises(BenchError, match="(?s)failed .*RuntimeError: model exploded"):
            RemotePolicy(server.uri).forward(_fake_obs(rgb=False))


def test_serve_refuses_the_oracle_and_bad_options(capsys):
    assert cli.main(["serve", "--policy", "oracle", "--port", "0"]) == 2
    assert "oracle policy cannot be served" in capsys.readouterr().err
    with pytest.raises(BenchError, match="accepts timeout_s, connect_timeout_s and retries"):
        resolve_policy("ws://127.0.0.1:1", {"ckpt": "x"})
    with pytest.raises(BenchError, match="expected ws://HOST:PORT"):
        resolve_policy("ws://:80")


def test_missing_extra_names_the_install_command(monkeypatch):
    monkeypatch.setitem(sys.modules, "websockets", None)
    with pytest.raises(BenchError, match=r'pip install "mikasa-bench\[remote\]"'):
        resolve_policy("ws://127.0.0.1:8000")
