"""Training throughput of the memory baseline (``mikasa-memory-train``), on synthetic episodes.

Writes ``--episodes`` synthetic NPZ episodes of ``--length`` frames (two 128x128 cameras, the
project's episode schema), trains the ``memory_gru`` policy on them for ``--steps`` steps at
``--batch-size`` whole episodes per step with the trainer's own code, and prints optimizer
steps/s and supervised frames/s (the first ``--warmup`` steps excluded). Needs lerobot and
baselines/memory (``.venv-datasets`` on a CPU machine)::

    .venv-datasets/bin/python benchmarks/memory_train_throughput.py --device cpu --batch-size 16
    .venv-datasets/bin/python benchmarks/memory_train_throughput.py --device cpu --policy color_dim=0
    python benchmarks/memory_train_throughput.py --device cuda --length 50 --batch-size 32
"""

from __future__ import annotations

import argparse
import json
import tempfile
from pathlib import Path

from lerobot_policy_memory_gru import train as memory_train
from mikasa_datasets.loaders import write_synthetic_task


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--episodes", type=int, default=64)
    p.add_argument("--length", type=int, default=16, help="frames per episode")
    p.add_argument("--steps", type=int, default=30)
    p.add_argument("--warmup", type=int, default=5)
    p.add_argument("--batch-size", type=int, default=16, help="episodes per step")
    p.add_argument("--device", default="cpu")
    p.add_argument(
        "--policy",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="a MemoryGRUConfig field, as mikasa-memory-train takes it (repeatable)",
    )
    a = p.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        data = write_synthetic_task(
            Path(tmp) / "npz", "RememberColor3-VLA-v0", [a.length] * a.episodes
        )
        out = Path(tmp) / "run"
        common = ["--data", str(data), "--out", str(out), "--batch-size", str(a.batch_size)]
        common += ["--device", a.device, "--log-every", "1", "--save-every-s", "1e9"]
        common += [arg for pair in a.policy for arg in ("--policy", pair)]
        memory_train.main([*common, "--steps", str(a.steps)])
        log = json.loads((out / memory_train.LOG_FILE).read_text())
    timed = [r["steps_per_s"] for r in log["log"][a.warmup :]]
    rate = len(timed) / sum(1 / r for r in timed)  # harmonic mean: steps over seconds
    print(f"memory_gru, {log['parameters'] / 1e6:.2f} M parameters, device {log['device']}")
    print(
        f"batch {a.batch_size} episodes x {a.length} frames: {rate:.2f} steps/s, "
        f"{rate * a.batch_size * a.length:.0f} frames/s (steps {a.warmup + 1}-{a.steps})"
    )


if __name__ == "__main__":
    main()
