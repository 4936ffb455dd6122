"""Serve a policy to mikasa-bench with openpi's own websocket server.

    pip install openpi-server openpi-client        # openpi's server and its msgpack helpers
    python examples/serve_with_openpi.py --port 8000  # this file: a policy behind openpi's server
    mikasa-bench run --task RememberColor3-VLA-v0 --num-episodes 2 --workers 1 \
        --policy ws://127.0.0.1:8000

`ExamplePolicy` stands where a VLA goes. It shows what such a policy reads and answers:

* each request is a dict: ``observation/image`` and ``observation/wrist_image`` (uint8
  128x128x3; rgb runs), ``observation/state`` (float32 (7,): end-effector xyz,
  roll-pitch-yaw, gripper; the key openpi's LIBERO-style policies read), ``prompt`` (the
  task's instruction), ``reset`` (true on an episode's first request: openpi's protocol
  has no reset call, so the request carries it), ``episode_seed``, ``step_index``,
  ``env_id``; a ``--obs-mode state`` run adds ``privileged/state``;
* the reply is ``{"actions": (K, 7) float32}``: a chunk of K end-effector delta actions
  (xyz, roll-pitch-yaw, gripper in [-1, 1]), played in order before the next request.

Its actions depend on its own memory (the steps since its reset), as a policy that
remembers does. openpi's server hands every connection to the same policy object, and
each mikasa-bench worker opens its own connection: with a policy that keeps memory, run
one worker per server (``--workers 1``), or start one server per worker.
"""

from __future__ import annotations

import argparse
import logging

import numpy as np
from openpi_client import base_policy
from openpi_server import WebsocketPolicyServer


class ExamplePolicy(base_policy.BasePolicy):
    """Chunks of ``chunk_size`` actions: the gripper moves towards one of two points and
    opens or closes, switching every 10 steps since the episode's reset."""

    TARGETS = np.array([[0.0, -0.1, 0.15], [0.05, 0.1, 0.1]], dtype=np.float32)

    def __init__(self, chunk_size: int = 4) -> None:
        self.chunk_size = int(chunk_size)
        self.steps = 0  # the policy's memory: env steps since the episode's reset

    def infer(self, obs: dict) -> dict:
        if obs.get("reset"):
            self.reset()
        proprio = np.asarray(obs["observation/state"], dtype=np.float32)
        actions = np.zeros((self.chunk_size, 7), dtype=np.float32)
        for i in range(self.chunk_size):
            phase = (self.steps + i) // 10 % 2
            actions[i, :3] = np.clip(4.0 * (self.TARGETS[phase] - proprio[:3]), -1.0, 1.0)
            actions[i, 6] = 1.0 if phase == 0 else -1.0
        self.steps += self.chunk_size
        return {"actions": actions}

    def reset(self) -> None:
        self.steps = 0


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--host", default="0.0.0.0")
    parser.add_argument("--port", type=int, default=8000)
    parser.add_argument("--chunk-size", type=int, default=4, help="actions per reply (K)")
    args = parser.parse_args()
    logging.basicConfig(level=logging.INFO)
    server = WebsocketPolicyServer(
        ExamplePolicy(args.chunk_size),
        host=args.host,
        port=args.port,
        metadata={"policy": "openpi example"},
    )
    server.serve_forever()


if __name__ == "__main__":
    main()
