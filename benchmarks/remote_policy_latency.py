"""Cost of serving a policy over the websocket (`mikasa-bench serve`) instead of in-process.

Starts ``mikasa-bench serve --policy zero`` as a separate process on 127.0.0.1, then prints

* the round-trip time per request (mean / p50 / p95) of `RemotePolicy.forward` with a
  canonical rgb observation (two 128x128x3 uint8 cameras + 7 proprio) and a state one;
* env steps/s of one env (``run_episode``, one process) with the zero policy in-process
  and over the socket, for each ``--obs-mode``.

    python benchmarks/remote_policy_latency.py [--requests 500] [--episodes 10]
                                               [--obs-modes rgb,state] [--task ID]
"""

from __future__ import annotations

import argparse
import os
import socket
import subprocess
import sys
import time
import urllib.request

import numpy as np
import torch


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _start_server(port: int) -> subprocess.Popen:
    cmd = [sys.executable, "-m", "mikasa_bench", "serve", "--policy", "zero"]
    proc = subprocess.Popen(
        [*cmd, "--host", "127.0.0.1", "--port", str(port)],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    deadline = time.time() + 120
    while time.time() < deadline:
        try:
            with urllib.request.urlopen(f"http://127.0.0.1:{port}/healthz", timeout=1) as r:
                if r.status == 200:
                    return proc
        except OSError:
            time.sleep(0.2)
    proc.kill()
    raise SystemExit("the policy server did not start within 120 s")


def _stats_ms(ts: list[float]) -> str:
    a = np.asarray(ts) * 1000
    return f"mean {a.mean():6.2f} ms  p50 {np.percentile(a, 50):6.2f} ms  p95 {np.percentile(a, 95):6.2f} ms"


def _round_trips(uri: str, n: int) -> None:
    from mikasa_bench.policies.remote.client import RemotePolicy

    g = torch.Generator().manual_seed(0)
    observations = {
        "rgb (2 x 128x128x3 uint8 + 7 float32)": {
            "proprio": torch.randn(1, 7, generator=g),
            "rgb": torch.randint(0, 256, (1, 128, 128, 6), dtype=torch.uint8, generator=g),
        },
        "state (7 + 35 float32)": {
            "proprio": torch.randn(1, 7, generator=g),
            "state": torch.randn(1, 35, generator=g),
        },
    }
    policy = RemotePolicy(uri)
    for name, obs in observations.items():
        policy.reset(seed=0)
        for _ in range(20):  # warm-up
            policy.forward(obs)
        ts = []
        for _ in range(n):
            t0 = time.perf_counter()
            policy.forward(obs)
            ts.append(time.perf_counter() - t0)
        print(f"  round trip, {name:38s} {_stats_ms(ts)}  ({n} requests)")
    policy.close()


def _steps_per_s(task: str, obs_mode: str, episodes: int, uri: str) -> None:
    from mikasa_bench.policies import ZeroPolicy
    from mikasa_bench.policies.remote.client import RemotePolicy
    from mikasa_bench.protocol import START_SEED, BenchmarkConfig, starts_scene
    from mikasa_bench.runners.episode import make_benchmark_env, run_episode

    env = make_benchmark_env(task, BenchmarkConfig(obs_mode=obs_mode, sim_backend="cpu"))
    try:
        run_episode(env, ZeroPolicy(), START_SEED, fresh_scene=True)  # warm-up (shaders, caches)
        results = {}
        for name, policy in (
            ("in-process", ZeroPolicy()),
            ("websocket", RemotePolicy(uri, env_id=task)),
        ):
            steps, t0, returns = 0, time.perf_counter(), []
            for i in range(episodes):
                r, _ = run_episode(env, policy, START_SEED + i, fresh_scene=starts_scene(i))
                steps += r.n_steps
                returns.append(r.episode_return)
            dt = time.perf_counter() - t0
            results[name] = returns
            print(
                f"  {obs_mode:5s} {name:10s} {steps / dt:7.1f} env steps/s  ({steps} steps, {dt:.1f} s)"
            )
        same = results["in-process"] == results["websocket"]
        print(f"  {obs_mode:5s} per-episode returns identical: {same}")
    finally:
        env.close()


def main() -> None:
    p = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    p.add_argument("--requests", type=int, default=500)
    p.add_argument("--episodes", type=int, default=10)
    p.add_argument("--obs-modes", default="rgb,state")
    p.add_argument("--task", default="RememberColor3-VLA-v0")
    args = p.parse_args()
    os.environ.setdefault("OMP_NUM_THREADS", "1")
    torch.set_num_threads(1)
    port = _free_port()
    server = _start_server(port)
    uri = f"ws://127.0.0.1:{port}"
    try:
        print(
            f"server: mikasa-bench serve --policy zero (separate process) at {uri}; "
            f"{os.cpu_count()} CPUs"
        )
        _round_trips(uri, args.requests)
        for mode in args.obs_modes.split(","):
            _steps_per_s(args.task, mode.strip(), args.episodes, uri)
    finally:
        server.terminate()
        server.wait(timeout=30)


if __name__ == "__main__":
    main()
