"""The policy doors against openpi's own packages from the registry (``openpi-server``,
``openpi-client``), on 127.0.0.1:

* `mikasa-bench run --policy ws://` against openpi's `WebsocketPolicyServer` (the bench
  README's example server, run as a separate process: tests/openpi_test_server.py adds
  knobs for a slow first reply, a hang to kill it in, a NaN reply);
* openpi's `WebsocketClientPolicy` against `mikasa-bench serve`.

Evaluations use state observations on one short task except the README example's run.
"""

from __future__ import annotations

import json
import signal
import socket
import subprocess
import sys
import threading
import time
from contextlib import contextmanager
from pathlib import Path

import numpy as np
import pytest
from mikasa_bench import cli
from mikasa_bench.policies import resolve_policy
from mikasa_bench.policies.remote.server import PolicyServer
from openpi_client.websocket_client_policy import WebsocketClientPolicy

ROOT = Path(__file__).resolve().parents[1]
EXAMPLE = ROOT / "packages/mikasa-bench/examples/serve_with_openpi.py"
TEST_SERVER = Path(__file__).resolve().parent / "openpi_test_server.py"
TASK = "RememberColor3-VLA-v0"
SEED = 4242424242
PER_EPISODE = ("successes", "returns", "episode_lengths", "episode_seeds")


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _start(script: Path, port: int, *args: str, log: Path | None = None) -> subprocess.Popen:
    cmd = [sys.executable, str(script), "--port", str(port), *args]
    if log is not None:
        cmd += ["--log", str(log)]
    if script == EXAMPLE:
        cmd += ["--host", "127.0.0.1"]
    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    deadline = time.monotonic() + 30
    while time.monotonic() < deadline:
        try:
            socket.create_connection(("127.0.0.1", port), timeout=1).close()
            return proc
        except OSError:
            assert proc.poll() is None, f"{script.name} exited with {proc.returncode}"
            time.sleep(0.1)
    proc.kill()
    raise AssertionError(f"{script.name} did not listen on port {port} within 30 s")


@contextmanager
def openpi_server(script: Path, port: int, *args: str, log: Path | None = None):
    proc = _start(script, port, *args, log=log)
    try:
        yield proc
    finally:
        proc.kill()
        proc.wait()


def _run(out: Path, uri: str, kwargs=None, episodes: int = 2, obs_mode: str = "state") -> int:
    argv = ["run", "--task", TASK, "--num-episodes", str(episodes), "--obs-mode", obs_mode]
    argv += ["--no-progress", "--no-report", "--workers", "0", "--policy", uri, "--out", str(out)]
    if kwargs:
        argv += ["--policy-kwargs", json.dumps(kwargs)]
    return cli.main(argv)


def _result(out: Path) -> dict:
    return json.loads((out / f"{TASK}.json").read_text())


def _episodes(out: Path) -> dict:
    r = _result(out)
    return {k: r[k] for k in PER_EPISODE}


def _journal(out: Path) -> list[dict]:
    path = next(out.rglob("*.jsonl"))
    return [json.loads(line) for line in path.read_text().splitlines() if line.strip()]


# ------------------------------------------------------------------------------------
# mikasa-bench run against openpi's WebsocketPolicyServer
# ------------------------------------------------------------------------------------


def test_readme_example_server_runs_and_its_chunks_are_recorded(tmp_path):
    port = _free_port()
    with openpi_server(EXAMPLE, port, "--chunk-size", "10"):
        # The README's command (rgb observations, the canonical mode), one episode.
        assert _run(tmp_path / "run", f"ws://127.0.0.1:{port}", episodes=1, obs_mode="rgb") == 0
    result = _result(tmp_path / "run")
    # openpi's metadata has no chunk_size: the K of the replies is what gets recorded.
    assert result["action_chunk_size"] == 10 and result["action_chunk_size_varied"] is False
    assert result["episode_lengths"] == [25] and result["episode_restarts"] == [0]


def test_slow_first_reply_within_timeout_keeps_the_connection(tmp_path):
    """45 s exceeds the websockets library's default keepalive (20 s ping + 20 s timeout):
    only timeout_s may end the wait."""
    port, log = _free_port(), tmp_path / "server.log"
    with openpi_server(TEST_SERVER, port, "--first-delay-s", "45", log=log):
        t0 = time.monotonic()
        assert _run(tmp_path / "run", f"ws://127.0.0.1:{port}", {"timeout_s": 120}, 1) == 0
        assert time.monotonic() - t0 >= 45
    assert log.read_text().count("opened") == 1  # openpi's line per connection: no reconnect
    assert [r["restarts"] for r in _journal(tmp_path / "run")] == [0]


def test_server_killed_mid_episode_gives_the_uninterrupted_results(tmp_path):
    """The example policy's actions depend on its steps since reset: continuing an episode
    on a restarted server would change the returns; replaying it from its reset does not."""
    port = _free_port()
    with openpi_server(TEST_SERVER, port, log=tmp_path / "a.log"):
        assert _run(tmp_path / "uninterrupted", f"ws://127.0.0.1:{port}") == 0

    port, marker = _free_port(), tmp_path / "paused"
    log = tmp_path / "b.log"
    first = _start(
        TEST_SERVER, port, "--pause-at", f"{SEED + 1}:8", "--marker", str(marker), log=log
    )
    restarted: list[subprocess.Popen] = []

    def kill_and_restart() -> None:
        while not marker.exists():
            time.sleep(0.05)
        first.send_signal(signal.SIGKILL)
        first.wait()
        restarted.append(_start(TEST_SERVER, port, log=tmp_path / "c.log"))

    thread = threading.Thread(target=kill_and_restart, daemon=True)
    thread.start()
    try:
        assert _run(tmp_path / "interrupted", f"ws://127.0.0.1:{port}", {"retries": 20}) == 0
    finally:
        thread.join(timeout=60)
        for proc in [first, *restarted]:
            proc.kill()
            proc.wait()
    assert _episodes(tmp_path / "interrupted") == _episodes(tmp_path / "uninterrupted")
    assert [r["restarts"] for r in _journal(tmp_path / "interrupted")] == [0, 1]
    assert _result(tmp_path / "interrupted")["episode_restarts"] == [0, 1]
    # The restarted server saw episode 1 from its reset, never its step 8 first.
    lines = [ln for ln in (tmp_path / "c.log").read_text().splitlines() if "request" in ln]
    assert f"episode_seed {SEED + 1} step 0 reset True" in lines[0]


def test_nan_action_names_server_episode_and_step_and_the_run_resumes(tmp_path, capsys):
    port = _free_port()
    uri = f"ws://127.0.0.1:{port}"
    with openpi_server(TEST_SERVER, port, log=tmp_path / "a.log"):
        assert _run(tmp_path / "clean", uri) == 0
    with openpi_server(TEST_SERVER, port, "--nan-at", f"{SEED + 1}:4", log=tmp_path / "b.log"):
        assert _run(tmp_path / "run", uri) == 2
    err = capsys.readouterr().err
    assert (
        f"policy server {uri} returned non-finite actions (episode seed {SEED + 1}, step 4)" in err
    )
    assert "NaN or inf" in err and f"{TASK} episode 1 (seed {SEED + 1})" in err
    assert [r["episode"] for r in _journal(tmp_path / "run")] == [0]  # episode 0 kept
    with openpi_server(TEST_SERVER, port, log=tmp_path / "c.log"):
        assert (
            cli.main(["run", "--resume", str(tmp_path / "run"), "--no-progress", "--no-report"])
            == 0
        )
    assert _episodes(tmp_path / "run") == _episodes(tmp_path / "clean")


# ------------------------------------------------------------------------------------
# openpi's WebsocketClientPolicy against mikasa-bench serve
# ------------------------------------------------------------------------------------


@contextmanager
def mikasa_serve(target: str):
    server = PolicyServer(resolve_policy(target), host="127.0.0.1", port=0).start()
    try:
        yield server
    finally:
        server.stop()


def _openpi_request(state: np.ndarray, **extra) -> dict:
    return {"observation/state": state, "prompt": "touch the cube", "reset": True, **extra}


def test_openpi_client_against_mikasa_serve():
    target = f"{Path(__file__).resolve().parent / 'test_remote_policy.py'}:CountingChunkPolicy"
    with mikasa_serve(target) as server:
        client = WebsocketClientPolicy(f"{server.uri}/?env_id={TASK}")
        meta = client.get_server_metadata()
        assert meta["server"] == "mikasa-bench" and meta["protocol_version"] == 2
        assert meta["chunk_size"] == 2 and meta["env_id"] == TASK
        proprio = np.linspace(-0.3, 0.3, 7).astype(np.float32)
        reply = client.infer(_openpi_request(proprio, episode_seed=5))
        assert reply["actions"].shape == (2, 7) and reply["actions"].dtype == np.float32
        assert np.allclose(reply["actions"][:, :3], np.clip(-proprio[:3], -1, 1))
        assert "infer_ms" in reply["server_timing"]


@pytest.mark.parametrize(
    "request_extra, message",
    [
        # A LIBERO-style 8-D state (xyz, axis-angle, 2 gripper fingers).
        (
            {"observation/state": np.zeros(8, np.float32)},
            r"'observation/state' is an array of shape \(8,\)",
        ),
        (
            {"observation/joint_position": np.zeros(7, np.float32)},
            "unknown key 'observation/joint_position'",
        ),
        (
            {"observation/image": np.zeros((128, 128, 3), np.uint8)},
            "'observation/image' and 'observation/wrist_image' come together",
        ),
    ],
    ids=["libero-8d-state", "unknown-key", "one-camera"],
)
def test_mikasa_serve_names_bad_requests_to_openpi_clients(request_extra, message):
    with mikasa_serve("zero") as server:
        client = WebsocketClientPolicy(server.uri)
        request = {**_openpi_request(np.zeros(7, np.float32)), **request_extra}
        with pytest.raises(
            RuntimeError, match=f"(?s)Error in inference server.*{message}.*Accepted keys"
        ):
            client.infer(request)
