"""The LeRobotDataset v3 format as this package writes it: its names (feature keys,
defaults), the ``features`` mapping, and lerobot's offline import.

Shared by the writer (:mod:`mikasa_datasets.lerobot_write`,
:mod:`mikasa_datasets.lerobot_write_parts`) and the reader (:mod:`mikasa_datasets.lerobot`),
and imports neither; the feature table and the environment notes are in the docstring of
:mod:`mikasa_datasets.lerobot`, which re-exports every name here.
"""

from __future__ import annotations

import functools
import os
from typing import Any

from mikasa_datasets import torchvision_cpu
from mikasa_datasets.conversion import require

__all__ = [
    "ACTION_KEY",
    "CAMERA_KEYS",
    "DEFAULT_FPS",
    "DEFAULT_VCODEC",
    "DONE_KEY",
    "IMAGE_SHAPE",
    "LEROBOT_DIRNAME",
    "REWARD_KEY",
    "ROBOT_TYPE",
    "SOURCE_METADATA_NAME",
    "STATE_KEY",
    "SUCCESS_KEY",
    "TOP_KEY",
    "WRIST_KEY",
    "ensure_torchvision_importable",
    "lerobot_dataset_class",
    "lerobot_features",
]

LEROBOT_DIRNAME = "data_lerobot"
DEFAULT_FPS = 10
ROBOT_TYPE = "mikasa_robo"
DEFAULT_VCODEC = "libsvtav1"
"""lerobot's default codec, SVT-AV1 at lerobot's settings; why not H.264: `lerobot_write`."""
SOURCE_METADATA_NAME = "source_rlds_metadata.json"

TOP_KEY = "observation.images.top"
WRIST_KEY = "observation.images.wrist"
STATE_KEY = "observation.state"
ACTION_KEY = "action"
REWARD_KEY = "next.reward"
SUCCESS_KEY = "next.success"
DONE_KEY = "next.done"
CAMERA_KEYS = (TOP_KEY, WRIST_KEY)
IMAGE_SHAPE = (128, 128, 3)


# --------------------------------------------------------------------------- lerobot import
def ensure_torchvision_importable() -> None:
    """Make ``import torchvision`` work with a CPU torch and PyPI's CUDA torchvision.

    torchvision's ``_C`` ops library links against libtorch_cuda, so with the CPU build of
    torch it fails to load (torchvision tolerates that), and then its import dies
    registering fake kernels for ``torchvision::nms``/``qnms``, ops that only ``_C``
    defines. :mod:`mikasa_datasets.torchvision_cpu` declares those two schemas through
    torch's public ``torch.library`` once ``_C`` has failed to load, which lets the
    pure-Python parts (models, transforms: what lerobot's dataset and policy code use)
    import; the detection ops stay unusable, and nothing here calls them. A torchvision
    whose ``_C`` loads is left untouched; a missing one is left to the importer to report.
    In ``.venv-datasets`` the same code already runs as a start-up hook (so plain
    ``lerobot-train`` / ``lerobot-eval`` work there); this call makes it work in any other
    environment too. Also used by mikasa-bench's LeRobot policies
    (`mikasa_bench.lerobot.policy`).
    """
    torchvision_cpu.ensure_importable()


@functools.cache
def lerobot_dataset_class() -> type:
    """``lerobot.datasets.lerobot_dataset.LeRobotDataset``, imported offline."""
    # Must precede the first huggingface_hub / datasets import: both read it at import.
    os.environ.setdefault("HF_HUB_OFFLINE", "1")
    os.environ.setdefault("HF_DATASETS_OFFLINE", "1")
    os.environ.setdefault("TF_CPP_MIN_LOG_LEVEL", "2")  # datasets imports TF when present
    os.environ.setdefault("TF_ENABLE_ONEDNN_OPTS", "0")
    os.environ.setdefault("SVT_LOG", "1")  # SVT-AV1 prints a banner per encoder otherwise
    require("torch", "lerobot")
    ensure_torchvision_importable()
    return require("lerobot.datasets.lerobot_dataset", "lerobot").LeRobotDataset


def lerobot_features(*, use_videos: bool = True) -> dict[str, dict[str, Any]]:
    """The LeRobot ``features`` mapping written by the converters (the feature table of
    :mod:`mikasa_datasets.lerobot`)."""
    cam = {
        "dtype": "video" if use_videos else "image",
        "shape": IMAGE_SHAPE,
        "names": ["height", "width", "channel"],
    }
    return {
        TOP_KEY: dict(cam),
        WRIST_KEY: dict(cam),
        STATE_KEY: {"dtype": "float32", "shape": (7,), "names": None},
        ACTION_KEY: {"dtype": "float32", "shape": (7,), "names": None},
        REWARD_KEY: {"dtype": "float32", "shape": (1,), "names": None},
        SUCCESS_KEY: {"dtype": "bool", "shape": (1,), "names": None},
        DONE_KEY: {"dtype": "bool", "shape": (1,), "names": None},
    }
