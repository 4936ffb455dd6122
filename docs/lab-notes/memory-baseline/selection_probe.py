"""Can the memory policy's parts learn RememberColor3's colour match when told the answer?

A supervised test, without the GRU or the actions: the input is an episode's first frame (the
cue cube alone) and its first action-phase frame (three cubes), both cameras; the label is the
cube the demonstrator went to (left / middle / right, from the end-effector's final y). The
model encodes both frames with the policy's ``CameraEncoder``; the cue frame's vector is the
"memory" that queries the second frame. How the second frame is read:

* ``concat``: its global vector, next to the memory (no attention);
* ``readout``: the policy's ``MemoryReadout`` (attention over the cells, their features out);
* ``keypoints``: the policy's ``MemoryKeypoints`` (the attended cells' mean position out);
* ``color-keypoints``: the same with keys from the cells' colour features only.

``--head points`` gives the classifier only what the attention read (not the memory too).

    .venv-datasets/bin/python docs/lab-notes/memory-baseline/selection_probe.py \\
        --data DIR/data_npz/remember_color_3_vla_v0 --reader color-keypoints --head points

Prints held-out accuracy (the next 100 episodes after the training ones) as it trains; chance
is about 1/3.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F
from lerobot_policy_memory_gru.modeling_memory_gru import (
    CameraEncoder,
    MemoryKeypoints,
    MemoryReadout,
    random_shift,
)
from torch import Tensor, nn

CAMERAS = (slice(0, 3), slice(3, 6))  # the NPZ's rgb holds both cameras' channels
COLOR_DIM, QUERY_DIM = 16, 256


def load(data: Path, count: int) -> tuple[Tensor, Tensor, Tensor]:
    """Cue frames, first action-phase frames ``(N, 6, 128, 128)`` in [0, 1], labels ``(N,)``."""
    files = sorted(data.glob("train_data_*.npz"), key=lambda f: int(f.stem.rsplit("_", 1)[1]))
    cue, decision, label = [], [], []
    for path in files[:count]:
        episode = np.load(path)
        moving = np.abs(episode["action"][:, :6]).sum(axis=1) > 0
        cue.append(episode["rgb"][0])
        decision.append(episode["rgb"][int(np.argmax(moving))])
        y = float(episode["proprio"][-1, 1])
        label.append(0 if y < -0.1 else 2 if y > 0.1 else 1)
    frames = [torch.tensor(np.stack(x)).permute(0, 3, 1, 2).float() / 255 for x in (cue, decision)]
    return frames[0], frames[1], torch.tensor(label)


class Probe(nn.Module):
    def __init__(self, reader: str, head: str) -> None:
        super().__init__()
        self.reader, self.head_input = reader, head
        self.encoders = nn.ModuleList(
            CameraEncoder((3, 128, 128), (32, 64, 64), 128, COLOR_DIM) for _ in CAMERAS
        )
        memory_dim = sum(e.out_dim for e in self.encoders)
        self.memory = nn.Sequential(nn.Linear(memory_dim, QUERY_DIM), nn.ReLU())
        if reader == "readout":
            self.reads = nn.ModuleList(
                MemoryReadout(e.cell_dim, QUERY_DIM, 64) for e in self.encoders
            )
            read_dim = 64 * len(CAMERAS)
        elif reader in ("keypoints", "color-keypoints"):
            self.reads = nn.ModuleList(
                MemoryKeypoints(
                    e.color_dim if reader == "color-keypoints" else e.cell_dim, QUERY_DIM, 4
                )
                for e in self.encoders
            )
            read_dim = 8 * len(CAMERAS)
        else:
            read_dim = memory_dim
        head_in = read_dim + (0 if head == "points" else QUERY_DIM)
        self.classifier = nn.Sequential(nn.Linear(head_in, 256), nn.ReLU(), nn.Linear(256, 3))

    def forward(self, cue: Tensor, decision: Tensor) -> Tensor:
        memory = self.memory(
            torch.cat(
                [e(cue[:, c])[0] for e, c in zip(self.encoders, CAMERAS, strict=True)], dim=-1
            )
        )
        seen = [e(decision[:, c]) for e, c in zip(self.encoders, CAMERAS, strict=True)]
        if self.reader == "concat":
            read = [torch.cat([vector for vector, _ in seen], dim=-1)]
        else:
            read = []
            for module, encoder, (_, cells) in zip(self.reads, self.encoders, seen, strict=True):
                if self.reader == "readout":
                    read.append(module(memory, cells))
                    continue
                keys = encoder.cell_colors(cells) if self.reader == "color-keypoints" else cells
                read.append(module(memory, keys, encoder.coords))
        parts = read if self.head_input == "points" else [memory, *read]
        return self.classifier(torch.cat(parts, dim=-1))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--data", type=Path, required=True, help="a RememberColor3 NPZ dataset")
    parser.add_argument(
        "--reader", choices=["concat", "readout", "keypoints", "color-keypoints"], required=True
    )
    parser.add_argument("--head", choices=["memory-and-read", "points"], default="memory-and-read")
    parser.add_argument("--train", type=int, default=500, help="training episodes")
    parser.add_argument("--steps", type=int, default=800)
    parser.add_argument("--shift", type=int, default=0, help="random shift in pixels (0: none)")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    torch.manual_seed(args.seed)
    cue, decision, label = load(args.data, args.train + 100)
    held_out = slice(args.train, args.train + 100)
    probe = Probe(args.reader, args.head)
    optimizer = torch.optim.Adam(probe.parameters(), lr=3e-4)
    start = time.monotonic()
    for step in range(1, args.steps + 1):
        batch = torch.randint(0, args.train, (32,))
        c, d = cue[batch], decision[batch]
        if args.shift:
            c, d = random_shift(c, args.shift), random_shift(d, args.shift)
        loss = F.cross_entropy(probe(c, d), label[batch])
        optimizer.zero_grad()
        loss.backward()
        optimizer.step()
        if step % 100 == 0:
            probe.eval()
            with torch.no_grad():
                predicted = probe(cue[held_out], decision[held_out]).argmax(dim=-1)
            probe.train()
            accuracy = (predicted == label[held_out]).float().mean().item()
            print(
                f"step {step}: loss {loss.item():.3f}, held-out accuracy {accuracy:.2f} "
                f"({time.monotonic() - start:.0f} s)",
                flush=True,
            )


if __name__ == "__main__":
    main()
