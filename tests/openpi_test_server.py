"""openpi's own `WebsocketPolicyServer` serving the bench README's example policy, with
knobs the interoperability tests need (tests/test_openpi_interop.py runs this file as a
separate process; it is not collected by pytest):

    python tests/openpi_test_server.py --port P --log LOG [--chunk-size K]
        [--first-delay-s S]                  # the first reply takes S seconds
        [--pause-at SEED:STEP --marker F]    # at that request, once: create F, then hang
        [--nan-at SEED:STEP]                 # that reply holds a NaN

The log gets openpi's own lines ("connection ... opened") and one line per request.
"""

from __future__ import annotations

import argparse
import logging
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "packages/mikasa-bench/examples"))

from openpi_server import WebsocketPolicyServer  # noqa: E402
from serve_with_openpi import ExamplePolicy  # noqa: E402

logger = logging.getLogger("openpi_test_server")


def _at(text: str | None) -> tuple[int, int] | None:
    if not text:
        return None
    seed, step = text.split(":")
    return int(seed), int(step)


class TestPolicy(ExamplePolicy):
    def __init__(self, args: argparse.Namespace) -> None:
        super().__init__(args.chunk_size)
        self.first_delay_s = args.first_delay_s
        self.pause_at, self.nan_at = _at(args.pause_at), _at(args.nan_at)
        self.marker = Path(args.marker) if args.marker else None
        self.requests = 0

    def infer(self, obs: dict) -> dict:
        here = (int(obs.get("episode_seed") or -1), int(obs.get("step_index", -1)))
        logger.info(
            "request %d: episode_seed %d step %d reset %s", self.requests, *here, obs.get("reset")
        )
        if self.requests == 0 and self.first_delay_s:
            time.sleep(self.first_delay_s)
        self.requests += 1
        if here == self.pause_at and self.marker is not None and not self.marker.exists():
            self.marker.write_text("paused\n")
            time.sleep(600)  # the test kills this process meanwhile
        reply = super().infer(obs)
        if here == self.nan_at:
            reply["actions"][0, 2] = np.nan
        return reply


def main() -> None:
    p = argparse.ArgumentParser()
    p.add_argument("--port", type=int, required=True)
    p.add_argument("--log", required=True)
    p.add_argument("--chunk-size", type=int, default=4)
    p.add_argument("--first-delay-s", type=float, default=0.0)
    p.add_argument("--pause-at")
    p.add_argument("--marker")
    p.add_argument("--nan-at")
    args = p.parse_args()
    logging.basicConfig(filename=args.log, level=logging.INFO, format="%(name)s: %(message)s")
    WebsocketPolicyServer(TestPolicy(args), host="127.0.0.1", port=args.port).serve_forever()


if __name__ == "__main__":
    main()
