"""The LeRobot baselines' policy settings and the lerobot-train flags they become.

A setting is one trained policy configuration (lerobot policy type, its ``--policy.*``
flags, and what it sees when it acts); `train_flags` adds the flags every run needs offline
and the command line's overrides. Why each flag: README.md beside this file.
"""

from __future__ import annotations

import argparse
import math
import re
from collections.abc import Mapping
from dataclasses import dataclass, field

from mikasa_datasets import env_id_to_dataset_name

__all__ = [
    "DEFAULT_TASKS",
    "DEFAULT_SETTINGS",
    "DEFAULT_REFERENCES",
    "RUNTIME_TRAIN_KEYS",
    "Setting",
    "horizon",
    "make_settings",
    "dataset_name",
    "train_flags",
    "model_flags",
    "flag_diff",
    "memory_train_argv",
]

DEFAULT_TASKS = (
    "RememberColor3-VLA-v0",
    "ShellGameTouch-VLA-v0",
    "InterceptSlow-VLA-v0",
    "BunchOfColors3-VLA-v0",
    "BlinkCountButtonPressEasy-VLA-v0",
    "TakeItBack-VLA-v0",
)
DEFAULT_SETTINGS = ("act", "diffusion", "diffusion-hist", "memory-gru")
DEFAULT_REFERENCES = ("oracle", "oracle-memoryless")

# Keys of the training flags that do not define the model (they may change between calls);
# a training record made with other values of the rest is not reused silently.
RUNTIME_TRAIN_KEYS = frozenset(
    {
        "policy.device",
        "num_workers",
        "save_freq",
        "log_freq",
        "output_dir",
        "job_name",
        "dataset.root",
        "dataset.video_backend",
    }
)


@dataclass(frozen=True)
class Setting:
    """One trained policy configuration: lerobot policy type and its ``--policy.*`` flags."""

    name: str
    policy_type: str
    label: str
    sees: str
    args: Mapping[str, str]
    tiny_args: Mapping[str, str] = field(default_factory=dict)
    memoryless: bool = False
    # "lerobot-train", or "memory": baselines/memory's whole-episode trainer (same flags
    # dict; `memory_train_argv` turns it into that trainer's command line).
    trainer: str = "lerobot-train"


def horizon(history: int, future: int, factor: int) -> int:
    """Diffusion horizon: >= history - 1 + future steps, a multiple of the U-Net's factor."""
    need = history - 1 + future
    return factor * math.ceil(need / factor)


def make_settings(history: int) -> dict[str, Setting]:
    """The policy settings; ``history`` = observation steps of ``diffusion-hist``.

    Memoryless means: the policy's input is the current frame only AND it re-plans every
    step (``n_action_steps=1``). Executing a chunk open-loop would carry what the first
    frame showed into later steps (ACT's default executes 100 steps per inference), which is
    memory; ``act-chunk`` is that setting, kept out of the defaults. lerobot 0.4.4's ACT
    accepts only ``n_obs_steps=1`` (its config raises otherwise); Diffusion Policy takes a
    history of ``n_obs_steps`` frames.
    """
    act = {
        "policy.type": "act",
        "policy.n_obs_steps": "1",
        "policy.chunk_size": "20",
        "policy.n_action_steps": "1",
        # No download: a torchvision ResNet-18 with weights=None (trained from scratch).
        "policy.pretrained_backbone_weights": "null",
        # lerobot's 1e-5 assumes an ImageNet backbone and ~100k steps; from scratch in a few
        # thousand steps needs a larger rate.
        "policy.optimizer_lr": "1e-4",
        "policy.optimizer_lr_backbone": "1e-4",
    }
    act_tiny = {
        "policy.dim_model": "64",
        "policy.n_heads": "2",
        "policy.dim_feedforward": "128",
        "policy.n_encoder_layers": "1",
        "policy.n_decoder_layers": "1",
        "policy.use_vae": "false",
        "policy.chunk_size": "5",
    }

    def diffusion(n_obs: int) -> dict[str, str]:
        return {
            "policy.type": "diffusion",
            "policy.n_obs_steps": str(n_obs),
            "policy.horizon": str(horizon(n_obs, 8, 8)),  # 3 down-sampling stages: x8
            "policy.n_action_steps": "1",
            "policy.pretrained_backbone_weights": "null",
            # Episodes are 15-60 frames; lerobot's default drops the last 7 frames of each
            # episode from sampling. Pad instead and mask the padded actions out of the loss.
            "policy.drop_n_last_frames": "0",
            "policy.do_mask_loss_for_padding": "true",
            # One inference per env step: DDIM with 10 steps instead of 100 DDPM steps.
            "policy.noise_scheduler_type": "DDIM",
            "policy.num_inference_steps": "10",
        }

    def diffusion_tiny(n_obs: int) -> dict[str, str]:
        return {
            "policy.down_dims": "[32,64]",
            "policy.horizon": str(horizon(n_obs, 2, 4)),
            "policy.diffusion_step_embed_dim": "32",
            "policy.spatial_softmax_num_keypoints": "8",
            "policy.n_groups": "4",
            "policy.num_train_timesteps": "10",
            "policy.num_inference_steps": "2",
        }

    memory_tiny = {
        "policy.vision_channels": "[8,16,16]",
        "policy.vision_dim": "32",
        "policy.state_dim": "16",
        "policy.instruction_dim": "8",
        "policy.hidden_dim": "32",
        "policy.head_dim": "32",
    }

    replans = "the current frame; re-plans every step"
    return {
        "act": Setting("act", "act", "ACT, 1 frame", replans, act, act_tiny, memoryless=True),
        "act-chunk": Setting(
            "act-chunk",
            "act",
            "ACT, open-loop chunks",
            "the frame at each chunk start; executes chunks of 20 open-loop",
            {**act, "policy.n_action_steps": "20"},
            {**act_tiny, "policy.n_action_steps": "5"},
        ),
        "diffusion": Setting(
            "diffusion",
            "diffusion",
            "Diffusion, 1 frame",
            replans,
            diffusion(1),
            diffusion_tiny(1),
            memoryless=True,
        ),
        "diffusion-hist": Setting(
            "diffusion-hist",
            "diffusion",
            f"Diffusion, {history} frames",
            f"the last {history} frames; re-plans every step",
            diffusion(history),
            diffusion_tiny(history),
        ),
        "memory-gru": Setting(
            "memory-gru",
            "memory_gru",
            "GRU memory",
            "every frame since the reset (a GRU's state); acts every step",
            {"policy.type": "memory_gru", "policy.chunk_size": "8", "policy.color_dim": "16"},
            memory_tiny,
            trainer="memory",
        ),
    }


def dataset_name(env_id: str) -> str:
    """The project's dataset name of a task (``mikasa_datasets.env_id_to_dataset_name``)."""
    return str(env_id_to_dataset_name(env_id))


def train_flags(
    args: argparse.Namespace, task: str, setting: Setting, dataset_root: str, device: str
) -> dict[str, str]:
    """lerobot-train's flags (key -> value) for ``setting`` on ``task``: the setting's, the
    ones every offline run needs, the run's size from the command line ``args``, then its
    ``--train-arg [SETTING:]KEY=VALUE`` overrides."""
    d: dict[str, str] = {
        "dataset.repo_id": dataset_name(task),
        "dataset.root": dataset_root,
        **setting.args,
        **(setting.tiny_args if args.scale == "tiny" else {}),
        "policy.device": device,
        "policy.push_to_hub": "false",
        "wandb.enable": "false",
        "eval_freq": "0",  # evaluation is mikasa-bench's, after training
        "seed": str(args.seed),
        "steps": str(args.steps),
        "batch_size": str(args.batch_size),
        "num_workers": str(args.train_workers),
        "log_freq": str(args.log_freq),
        "job_name": f"{dataset_name(task)}-{setting.name}",
    }
    if args.save_freq:  # else the driver chooses it from the training rate
        d["save_freq"] = str(args.save_freq)
    if args.video_backend:
        d["dataset.video_backend"] = args.video_backend
    for item in args.train_arg:
        m = re.match(r"^([\w-]+):([\w.-]+=.*)$", item)  # SETTING:KEY=VALUE
        scope, kv = (m.group(1), m.group(2)) if m else ("", item)
        if scope and scope != setting.name:
            continue
        key, _, value = kv.partition("=")
        d[key.removeprefix("--")] = value
    return d


def model_flags(flags: Mapping[str, str]) -> dict[str, str]:
    """The model-defining part of `train_flags` (what a training record must match)."""
    return {k: v for k, v in flags.items() if k not in RUNTIME_TRAIN_KEYS}


def flag_diff(old: Mapping[str, str], new: Mapping[str, str]) -> str:
    """``key: old -> new`` for every key whose value differs."""
    keys = sorted(set(old) | set(new))
    return ", ".join(f"{k}: {old.get(k)} -> {new.get(k)}" for k in keys if old.get(k) != new.get(k))


MEMORY_FLAGS = {
    "dataset.root": "--data",
    "episodes": "--max-episodes",
    "policy.device": "--device",
    "steps": "--steps",
    "batch_size": "--batch-size",
    "seed": "--seed",
    "log_freq": "--log-every",
}
"""The flags of `train_flags` that baselines/memory's trainer takes, and its names for them
(its batch is whole episodes; ``policy.KEY`` becomes ``--policy KEY=VALUE``)."""


def memory_train_argv(flags: Mapping[str, str]) -> list[str]:
    """``mikasa-memory-train``'s arguments for a memory setting's `train_flags` (computed with
    the NPZ episodes as ``dataset.root``); lerobot-train's flags it has no use for are left out."""
    argv: list[str] = []
    for key, value in flags.items():
        if key in MEMORY_FLAGS:
            argv += [MEMORY_FLAGS[key], value]
        elif key.startswith("policy.") and key not in {"policy.type", "policy.push_to_hub"}:
            argv += ["--policy", f"{key.removeprefix('policy.')}={value}"]
    return argv
