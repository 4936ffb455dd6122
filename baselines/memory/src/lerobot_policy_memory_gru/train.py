"""Train the memory policy on whole episodes: ``mikasa-memory-train --data DIR --out DIR``.

Why a trainer of its own: lerobot-train samples frames, and a sample of this policy is a
window reaching back to the episode's reset (``history_window`` frames, each decoded from the
dataset's videos), which supervises the steps of one prefix per sample. Here each batch is B
whole episodes held in memory as uint8 tensors (on the GPU when training there), every step of
every episode is a target, and nothing is decoded after loading. The result is the same
LeRobot pretrained-policy directory lerobot-train writes (``config.json``,
``model.safetensors``, the processors), made with the same policy, processors and optimizer
preset, so ``lerobot-eval --policy.path=DIR`` and ``mikasa-bench run --policy lerobot:DIR``
load it as they load any LeRobot policy.

Data: any dataset ``mikasa_datasets.loaders.iter_episodes`` reads (the NPZ episodes
``mikasa-collect`` writes, RLDS, LeRobot v3); ``--data`` repeated trains one policy on several
tasks (the instruction tells them apart).

Output under ``--out``: ``pretrained_model/`` (replaced atomically at every save),
``training_state.pt`` (optimizer, step, RNG: ``--resume`` continues from it),
``train_log.json`` (settings, data, per-save loss, steps/s, wall time) and ``loss.png``.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import signal
import sys
import time
from dataclasses import fields
from pathlib import Path
from typing import Any

import numpy as np
import torch
from lerobot.configs.types import FeatureType, PolicyFeature
from lerobot.datasets.compute_stats import get_feature_stats
from lerobot.utils.constants import ACTION, OBS_STATE

from lerobot_policy_memory_gru.configuration_memory_gru import MemoryGRUConfig
from lerobot_policy_memory_gru.modeling_memory_gru import PAD_SUFFIX, TASK_KEY, MemoryGRUPolicy
from lerobot_policy_memory_gru.processor_memory_gru import make_memory_gru_pre_post_processors

TOP_KEY = "observation.images.top"
WRIST_KEY = "observation.images.wrist"
MODEL_DIR = "pretrained_model"
STATE_FILE = "training_state.pt"
LOG_FILE = "train_log.json"
# Config fields that --policy KEY=VALUE may set (the rest are lerobot's bookkeeping).
POLICY_FIELDS = {
    f.name
    for f in fields(MemoryGRUConfig)
    if f.name
    not in {"input_features", "output_features", "device", "pretrained_path", "n_obs_steps"}
}


# --------------------------------------------------------------------------- data
class EpisodeBank:
    """Every episode of the training data in memory: uint8 frames, float32 state and action,
    the instruction; batches of whole episodes padded at the end."""

    def __init__(self, episodes: list[dict[str, Any]], device: torch.device) -> None:
        if not episodes:
            raise ValueError("no episodes to train on")
        self.device = device
        self.rgb = [torch.from_numpy(np.ascontiguousarray(e["rgb"])).to(device) for e in episodes]
        self.state = [torch.from_numpy(e["proprio"]).float().to(device) for e in episodes]
        self.action = [torch.from_numpy(e["action"]).float().to(device) for e in episodes]
        self.instruction = [str(e["language_instruction"]) for e in episodes]
        self.lengths = [int(e["action"].shape[0]) for e in episodes]
        proprio = np.concatenate([e["proprio"] for e in episodes]).astype(np.float32)
        actions = np.concatenate([e["action"] for e in episodes]).astype(np.float32)
        self.stats = {
            OBS_STATE: get_feature_stats(proprio, axis=0, keepdims=False),
            ACTION: get_feature_stats(actions, axis=0, keepdims=False),
        }

    def __len__(self) -> int:
        return len(self.rgb)

    @property
    def frames(self) -> int:
        return sum(self.lengths)

    def batch(self, indices: list[int]) -> dict[str, Any]:
        """Episodes ``indices`` as one batch: cameras ``(B, T, 3, H, W)`` in [0, 1], state and
        action ``(B, T, 7)``, ``action_is_pad`` ``(B, T)``, the instructions."""
        t = max(self.lengths[i] for i in indices)
        b = len(indices)
        rgb = torch.zeros((b, t, *self.rgb[0].shape[1:]), dtype=torch.uint8, device=self.device)
        state = torch.zeros((b, t, self.state[0].shape[1]), device=self.device)
        action = torch.zeros((b, t, self.action[0].shape[1]), device=self.device)
        pad = torch.ones((b, t), dtype=torch.bool, device=self.device)
        for row, i in enumerate(indices):
            n = self.lengths[i]
            rgb[row, :n], state[row, :n], action[row, :n] = (
                self.rgb[i],
                self.state[i],
                self.action[i],
            )
            pad[row, :n] = False
        images = rgb.permute(0, 1, 4, 2, 3).float().div_(255.0)  # (B, T, 6, H, W)
        return {
            TOP_KEY: images[:, :, 0:3],
            WRIST_KEY: images[:, :, 3:6],
            OBS_STATE: state,
            ACTION: action,
            ACTION + PAD_SUFFIX: pad,
            TASK_KEY: [self.instruction[i] for i in indices],
        }


def dataset_dirs(path: str) -> list[Path]:
    """``path`` itself if it holds episodes (``train_data_<i>.npz``), else each of its
    subdirectories that does (a collection's ``data_npz``: one dataset per task)."""
    root = Path(path)
    if not root.is_dir():
        raise SystemExit(f"--data {path}: no such dataset directory")
    if any(root.glob("train_data_*.npz")):
        return [root]
    found = sorted(d for d in root.iterdir() if d.is_dir() and any(d.glob("train_data_*.npz")))
    if not found:
        raise SystemExit(
            f"--data {path}: no episodes (train_data_<i>.npz) in it or in its subdirectories"
        )
    return found


def load_bank(paths: list[str], device: torch.device, max_episodes: int | None) -> EpisodeBank:
    """The episodes of every dataset in ``paths`` (at most ``max_episodes`` from each); a
    path that holds several datasets (`dataset_dirs`) stands for all of them."""
    from mikasa_datasets.loaders import iter_episodes

    episodes: list[dict[str, Any]] = []
    for path in [d for p in paths for d in dataset_dirs(p)]:
        before = len(episodes)
        for episode in iter_episodes(path):
            if max_episodes is not None and len(episodes) - before >= max_episodes:
                break
            episodes.append(episode)
        print(f"[memory-train] {path}: {len(episodes) - before} episodes", flush=True)
    return EpisodeBank(episodes, device)


def mikasa_features() -> tuple[dict[str, PolicyFeature], dict[str, PolicyFeature]]:
    """MIKASA's inputs (two 128x128 cameras, the 7-D state) and output (the 7-D action)."""
    camera = PolicyFeature(type=FeatureType.VISUAL, shape=(3, 128, 128))
    return (
        {TOP_KEY: camera, WRIST_KEY: camera, OBS_STATE: PolicyFeature(FeatureType.STATE, (7,))},
        {ACTION: PolicyFeature(FeatureType.ACTION, (7,))},
    )


# --------------------------------------------------------------------------- saving
def save_policy(out: Path, policy: MemoryGRUPolicy, pre: Any, post: Any) -> None:
    """``out/pretrained_model`` replaced atomically by the current weights and processors."""
    staging = out / f".{MODEL_DIR}.partial"
    shutil.rmtree(staging, ignore_errors=True)
    policy.save_pretrained(staging)
    pre.save_pretrained(staging)
    post.save_pretrained(staging)
    old = out / f".{MODEL_DIR}.old"
    shutil.rmtree(old, ignore_errors=True)
    if (out / MODEL_DIR).exists():
        os.replace(out / MODEL_DIR, old)
    os.replace(staging, out / MODEL_DIR)
    shutil.rmtree(old, ignore_errors=True)


def write_json(path: Path, data: dict[str, Any]) -> None:
    tmp = path.with_suffix(".json.partial")
    tmp.write_text(json.dumps(data, indent=2) + "\n")
    os.replace(tmp, path)


def plot_loss(out: Path, log: list[dict[str, Any]]) -> None:
    """``out/loss.png``: the loss at every log line (skipped without matplotlib)."""
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        return
    fig, ax = plt.subplots(figsize=(5, 3))
    ax.plot([r["step"] for r in log], [r["loss"] for r in log])
    ax.set(xlabel="step", ylabel="L1 loss (normalised actions)", yscale="log")
    fig.tight_layout()
    fig.savefig(out / "loss.png", dpi=100)
    plt.close(fig)


# --------------------------------------------------------------------------- command line
def parse_policy_args(pairs: list[str]) -> dict[str, Any]:
    """``KEY=VALUE`` pairs for `MemoryGRUConfig` (values read as JSON, else as text)."""
    out: dict[str, Any] = {}
    for pair in pairs:
        key, sep, value = pair.partition("=")
        if not sep or key not in POLICY_FIELDS:
            raise SystemExit(
                f"--policy {pair!r}: expected KEY=VALUE with KEY one of {sorted(POLICY_FIELDS)}"
            )
        try:
            out[key] = json.loads(value)
        except json.JSONDecodeError:
            out[key] = value
        if isinstance(out[key], list):
            out[key] = tuple(out[key])
    return out


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="mikasa-memory-train",
        description="Train the memory_gru LeRobot policy on whole episodes of MIKASA datasets.",
    )
    p.add_argument(
        "--data",
        action="append",
        required=True,
        help="a dataset directory, or a directory of them such as a collection's data_npz, "
        "for one policy over several tasks (repeatable)",
    )
    p.add_argument("--out", required=True, help="output directory")
    p.add_argument("--steps", type=int, default=3000, help="optimizer steps (default 3000)")
    p.add_argument("--batch-size", type=int, default=32, help="episodes per step (default 32)")
    p.add_argument("--max-episodes", type=int, default=None, help="per dataset (default all)")
    p.add_argument("--device", default=None, help="cuda or cpu (default cuda when available)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument(
        "--policy",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="a MemoryGRUConfig field, e.g. hidden_dim=512 (repeatable)",
    )
    p.add_argument("--log-every", type=int, default=50, help="steps between progress lines")
    p.add_argument("--save-every-s", type=float, default=120.0, help="seconds between saves")
    p.add_argument(
        "--time-limit",
        type=float,
        default=None,
        help="save and exit with status 3 after this many seconds",
    )
    p.add_argument("--resume", action="store_true", help="continue from --out's training state")
    p.add_argument("--threads", type=int, default=None, help="torch CPU threads")
    return p


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    started = time.monotonic()
    out = Path(args.out)
    state_path = out / STATE_FILE
    if args.resume and not state_path.exists():
        raise SystemExit(f"--resume: {state_path} does not exist; run without --resume first")
    if not args.resume and (out / MODEL_DIR).exists():
        raise SystemExit(f"{out / MODEL_DIR} exists; pass --resume to continue or another --out")
    if args.threads:
        torch.set_num_threads(args.threads)
    device = torch.device(args.device or ("cuda" if torch.cuda.is_available() else "cpu"))
    torch.manual_seed(args.seed)
    torch.backends.cuda.matmul.allow_tf32 = True
    torch.backends.cudnn.allow_tf32 = True

    t0 = time.monotonic()
    bank = load_bank(args.data, device, args.max_episodes)
    load_s = time.monotonic() - t0
    print(
        f"[memory-train] {len(bank)} episodes, {bank.frames} frames loaded in {load_s:.1f} s "
        f"on {device}",
        flush=True,
    )

    inputs, outputs = mikasa_features()
    config = MemoryGRUConfig(
        input_features=inputs,
        output_features=outputs,
        device=device.type,
        **parse_policy_args(args.policy),
    )
    policy = MemoryGRUPolicy(config).to(device)
    pre, post = make_memory_gru_pre_post_processors(config, dataset_stats=bank.stats)
    optimizer_config = config.get_optimizer_preset()
    optimizer = optimizer_config.build(policy.get_optim_params())
    rng = np.random.default_rng(args.seed)
    step, log, train_s = 0, [], 0.0
    if args.resume:
        saved = torch.load(state_path, map_location=device, weights_only=False)
        policy.load_state_dict(saved["model"])
        optimizer.load_state_dict(saved["optimizer"])
        step, log, train_s = saved["step"], saved["log"], saved["train_s"]
        rng.bit_generator.state = saved["numpy_rng"]
        torch.set_rng_state(saved["torch_rng"].cpu())  # map_location moved it to the device
        print(f"[memory-train] resumed at step {step}", flush=True)
    params = sum(p.numel() for p in policy.parameters())
    info = {
        "data": args.data,
        "episodes": len(bank),
        "frames": bank.frames,
        "steps": args.steps,
        "batch_size": args.batch_size,
        "seed": args.seed,
        "device": torch.cuda.get_device_name(device) if device.type == "cuda" else "cpu",
        "parameters": params,
        "policy": parse_policy_args(args.policy),
        "command": "mikasa-memory-train " + " ".join(sys.argv[1:] if argv is None else argv),
    }

    def save() -> None:
        save_policy(out, policy, pre, post)
        torch.save(
            {
                "model": policy.state_dict(),
                "optimizer": optimizer.state_dict(),
                "step": step,
                "log": log,
                "train_s": train_s,
                "numpy_rng": rng.bit_generator.state,
                "torch_rng": torch.get_rng_state(),
            },
            out / f"{STATE_FILE}.partial",
        )
        os.replace(out / f"{STATE_FILE}.partial", state_path)
        write_json(
            out / LOG_FILE,
            {
                **info,
                "step": step,
                "train_s": round(train_s, 1),
                "steps_per_s": round(step / max(train_s, 1e-9), 2),
                "final_loss": log[-1]["loss"] if log else None,
                "log": log,
            },
        )
        plot_loss(out, log)

    out.mkdir(parents=True, exist_ok=True)
    print(
        f"[memory-train] {params / 1e6:.2f} M parameters; steps {step}..{args.steps} at "
        f"{args.batch_size} episodes per step",
        flush=True,
    )
    # A stop (the driver's time limit, Ctrl-C) saves first: --resume then loses no step.
    stop_signals: list[int] = []
    for signum in (signal.SIGINT, signal.SIGTERM):
        signal.signal(signum, lambda got, _frame: stop_signals.append(got))
    policy.train()
    last_save = time.monotonic()
    window_loss, window_start, window_steps = 0.0, time.monotonic(), 0
    while step < args.steps:
        tick = time.monotonic()
        indices = rng.integers(0, len(bank), size=args.batch_size).tolist()
        batch = pre(bank.batch(indices))
        loss, _ = policy.forward(batch)
        optimizer.zero_grad(set_to_none=True)
        loss.backward()
        torch.nn.utils.clip_grad_norm_(policy.parameters(), optimizer_config.grad_clip_norm)
        optimizer.step()
        step += 1
        window_loss += loss.item()
        window_steps += 1
        train_s += time.monotonic() - tick
        if step % args.log_every == 0 or step == args.steps:
            rate = window_steps / max(time.monotonic() - window_start, 1e-9)
            log.append(
                {
                    "step": step,
                    "loss": round(window_loss / window_steps, 5),
                    "steps_per_s": round(rate, 2),
                }
            )
            print(
                f"[memory-train] step {step}/{args.steps} loss {log[-1]['loss']:.4f} "
                f"{rate:.2f} steps/s",
                flush=True,
            )
            window_loss, window_start, window_steps = 0.0, time.monotonic(), 0
        over_time = args.time_limit is not None and time.monotonic() - started > args.time_limit
        stopping = over_time or bool(stop_signals)
        if stopping or time.monotonic() - last_save > args.save_every_s:
            save()
            last_save = time.monotonic()
            if stopping:
                why = "time limit" if over_time else f"signal {stop_signals[0]}"
                print(
                    f"[memory-train] {why}: saved at step {step}; run again with --resume",
                    flush=True,
                )
                return 3
    save()
    print(f"[memory-train] done: {step} steps in {train_s:.0f} s; {out / MODEL_DIR}", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
