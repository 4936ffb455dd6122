"""LeRobot policies in mikasa-bench: ``mikasa-bench run --policy lerobot:DIR``.

``DIR`` is what ``lerobot-train`` saves as ``.../checkpoints/<step>/pretrained_model`` (or
``PreTrainedPolicy.save_pretrained`` plus the processors' ``save_pretrained``, lerobot
0.4.x): ``config.json``, ``model.safetensors``, ``policy_preprocessor.json`` and
``policy_postprocessor.json`` (+ their ``.safetensors`` states). It is loaded with
lerobot's public API: ``PreTrainedConfig.from_pretrained``, the policy class from
``get_policy_class(config.type)`` and its ``from_pretrained``, and
``make_pre_post_processors(config, pretrained_path=DIR)``.

The MIKASA observation of the canonical chain becomes the batch the project's LeRobot
datasets were written with (`mikasa_datasets.lerobot`), in the form ``lerobot-eval`` hands
a policy after ``preprocess_observation`` and ``add_envs_task``::

    observation.images.top    float32 (1, 3, 128, 128) in [0, 1]   rgb[..., 0:3] (top camera)
    observation.images.wrist  float32 (1, 3, 128, 128) in [0, 1]   rgb[..., 3:6] (wrist camera)
    observation.state         float32 (1, 7)                       proprio
    task                      [language instruction]               manifest language_instruction

then goes through the policy's own preprocessor, ``select_action`` (the policy keeps its own
action queue, so ``chunk_size`` is 1 for the runner) and its postprocessor. ``reset()`` at
every episode start resets the policy and both processor pipelines.

lerobot is imported lazily (only for ``lerobot:`` targets), so mikasa-bench works without it.
"""

from __future__ import annotations

import functools
import os
import re
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

from mikasa_bench.errors import BenchError
from mikasa_bench.policies.base import ACTION_SHAPE
from mikasa_bench.policies.spec import PolicySpec, is_lerobot_target

__all__ = [
    "LEROBOT_PREFIX",
    "TOP_KEY",
    "WRIST_KEY",
    "STATE_KEY",
    "ACTION_KEY",
    "TASK_KEY",
    "MIKASA_INPUT_FEATURES",
    "MIKASA_OUTPUT_FEATURES",
    "LeRobotPolicy",
    "check_policy_features",
    "import_lerobot",
    "is_lerobot_target",
    "lerobot_policy_factory",
    "load_policy_config",
    "observation_to_lerobot",
    "resolve_lerobot_policy",
    "task_instruction",
]

LEROBOT_PREFIX = "lerobot:"
TOP_KEY = "observation.images.top"
WRIST_KEY = "observation.images.wrist"
STATE_KEY = "observation.state"
ACTION_KEY = "action"
TASK_KEY = "task"
IMAGE_SIZE = 128

MIKASA_INPUT_FEATURES: dict[str, tuple[str, tuple[int, ...]]] = {
    TOP_KEY: ("VISUAL", (3, IMAGE_SIZE, IMAGE_SIZE)),
    WRIST_KEY: ("VISUAL", (3, IMAGE_SIZE, IMAGE_SIZE)),
    STATE_KEY: ("STATE", (7,)),
}
"""What MIKASA gives a LeRobot policy: feature key -> (lerobot FeatureType name, shape), in
the channel-first shapes lerobot's policy configs record for the dataset's (128, 128, 3)
video features (``dataset_to_policy_features``)."""

MIKASA_OUTPUT_FEATURES: dict[str, tuple[str, tuple[int, ...]]] = {
    ACTION_KEY: ("ACTION", ACTION_SHAPE),
}
"""What MIKASA takes: one ``pd_ee_delta_pose`` action of 7 values."""

INSTALL_HINT = (
    "pip install 'mikasa-bench[lerobot]' (lerobot 0.4.x and mikasa-datasets; on this "
    "repository's CPU machines: scripts/setup_datasets_envs.sh, then run "
    ".venv-datasets/bin/mikasa-bench)"
)
PROCESSOR_FILES = ("policy_preprocessor.json", "policy_postprocessor.json")
README_HINT = "see packages/mikasa-bench/README.md, 'LeRobot policies and lerobot-eval'"



# ------------------------------------------------------------------------------------
# importing lerobot
# ------------------------------------------------------------------------------------


@functools.cache
def import_lerobot() -> Any:
    """Import lerobot (offline, torchvision made importable); `BenchError` with the install
    command if it is missing."""
    # Everything here is local: no Hub look-ups (must precede huggingface_hub's import to
    # take effect; a process that imported it already only loses the guard, not function).
    os.environ.setdefault("HF_HUB_OFFLINE", "1")
    try:
        import torch  # noqa: F401
    except ImportError as exc:
        raise BenchError(f"LeRobot policies need torch ({exc}); {INSTALL_HINT}") from None
    try:  # the project's one torchvision workaround lives beside its LeRobot datasets code
        from mikasa_datasets.lerobot import ensure_torchvision_importable
    except ImportError as exc:
        raise BenchError(f"LeRobot policies need mikasa-datasets ({exc}); {INSTALL_HINT}") from None
    ensure_torchvision_importable()
    try:
        import lerobot
        import lerobot.policies.factory  # noqa: F401
        from lerobot.utils.import_utils import register_third_party_plugins
    except ImportError as exc:
        raise BenchError(
            f"LeRobot policies need lerobot 0.4.x and its runtime dependencies ({exc}); "
            f"{INSTALL_HINT}"
        ) from None
    # Policies installed as LeRobot plugins (``lerobot_policy_*`` packages) register their
    # config types on import, as under lerobot-train and lerobot-eval.
    register_third_party_plugins()
    return lerobot


# ------------------------------------------------------------------------------------
# features
# ------------------------------------------------------------------------------------


def _feature(ft: Any) -> tuple[str, tuple[int, ...]]:
    """A lerobot ``PolicyFeature`` as (type name, shape)."""
    kind = getattr(ft.type, "value", ft.type)
    return str(kind), tuple(int(d) for d in ft.shape)


def _describe(features: Mapping[str, tuple[str, tuple[int, ...]]]) -> str:
    if not features:
        return "{}"
    return "{" + ", ".join(f"{k}: {t} {s}" for k, (t, s) in features.items()) + "}"


def check_policy_features(config: Any, where: str) -> None:
    """Raise `BenchError` unless ``config``'s input/output features fit MIKASA.

    Every input the policy declares must be one MIKASA provides, with the same type and
    shape (a policy may use a subset, e.g. the top camera only); LANGUAGE inputs are fed
    from the ``task`` string by the policy's own processor. The ``action`` output must be
    (7,). The message names both sides.
    """
    inputs = {k: _feature(v) for k, v in (getattr(config, "input_features", None) or {}).items()}
    outputs = {k: _feature(v) for k, v in (getattr(config, "output_features", None) or {}).items()}
    problems: list[str] = []
    if not inputs:
        problems.append("the policy declares no input features")
    for key, (kind, shape) in inputs.items():
        if kind == "LANGUAGE":
            continue
        provided = MIKASA_INPUT_FEATURES.get(key)
        if provided is None:
            problems.append(f"input {key!r} ({kind} {shape}) is not provided")
        elif provided != (kind, shape):
            problems.append(
                f"input {key!r}: the policy expects {kind} {shape}, MIKASA gives "
                f"{provided[0]} {provided[1]}"
            )
    action = outputs.get(ACTION_KEY)
    if action is None:
        problems.append(f"the policy has no {ACTION_KEY!r} output")
    elif action != MIKASA_OUTPUT_FEATURES[ACTION_KEY]:
        problems.append(
            f"output {ACTION_KEY!r}: the policy gives {action[0]} {action[1]}, MIKASA takes "
            f"ACTION {ACTION_SHAPE}"
        )
    if problems:
        raise BenchError(
            f"LeRobot policy {where} does not fit the MIKASA observation/action: "
            f"{'; '.join(problems)}. The policy expects inputs {_describe(inputs)} and "
            f"outputs {_describe(outputs)}; MIKASA provides {_describe(MIKASA_INPUT_FEATURES)} "
            f"plus the 'task' instruction, and takes {_describe(MIKASA_OUTPUT_FEATURES)} "
            f"(pd_ee_delta_pose); {README_HINT}"
        )


# ------------------------------------------------------------------------------------
# loading
# ------------------------------------------------------------------------------------


def _policy_dir(path: str | os.PathLike[str]) -> Path:
    """The absolute pretrained-model directory, checked for the files lerobot 0.4 saves."""
    raw = str(path)
    if raw.startswith(LEROBOT_PREFIX):
        raw = raw[len(LEROBOT_PREFIX) :]
    if not raw.strip():
        raise BenchError(
            "empty LeRobot policy path; expected lerobot:DIR with DIR a pretrained_model "
            "directory (config.json, model.safetensors, policy_pre/postprocessor.json)"
        )
    d = Path(raw).expanduser().resolve()
    if not d.is_dir():
        raise BenchError(
            f"LeRobot policy directory {d} does not exist; expected lerobot:DIR with DIR what "
            f"lerobot-train saves as .../checkpoints/<step>/pretrained_model"
        )
    missing = [
        n for n in ("config.json", "model.safetensors", *PROCESSOR_FILES) if not (d / n).is_file()
    ]
    if missing:
        hint = (
            " (checkpoints of lerobot < 0.4 have no processor files: convert them with "
            "python -m lerobot.processor.migrate_policy_normalization --pretrained-path DIR)"
            if set(missing) & set(PROCESSOR_FILES)
            else ""
        )
        raise BenchError(
            f"LeRobot policy directory {d} lacks {', '.join(missing)}; expected config.json, "
            f"model.safetensors, {' and '.join(PROCESSOR_FILES)}{hint}"
        )
    return d


def _pick_device(device: str | None) -> str:
    import torch

    if device is None:
        return "cuda" if torch.cuda.is_available() else "cpu"
    device = str(device)
    if device.startswith("cuda") and not torch.cuda.is_available():
        raise BenchError(
            f"LeRobot policy device {device!r} requested, but torch sees no CUDA device"
        )
    return device


def load_policy_config(path: str | os.PathLike[str], device: str | None = None) -> Any:
    """The policy's ``PreTrainedConfig`` from ``path/config.json``, on ``device`` (default:
    cuda when available, else cpu), its features checked against MIKASA's."""
    import_lerobot()
    from lerobot.configs.policies import PreTrainedConfig

    d = _policy_dir(path)
    try:
        config = PreTrainedConfig.from_pretrained(d)
    except Exception as exc:
        raise BenchError(
            f"cannot read the LeRobot policy config {d / 'config.json'}: {type(exc).__name__}: {exc}"
        ) from None
    config.device = _pick_device(device)
    config.pretrained_path = d
    check_policy_features(config, str(d))
    return config


def task_instruction(task: Any = None, env_id: str | None = None) -> str:
    """The language instruction: the manifest row's, else mikasa_envs' task table's."""
    text = getattr(task, "language_instruction", None) or (
        task.get("language_instruction") if isinstance(task, Mapping) else None
    )
    if text:
        return str(text)
    if env_id:
        try:
            import mikasa_envs

            return str(mikasa_envs.get_task(env_id).language_instruction)
        except Exception:  # an id outside the manifest: no instruction
            return ""
    return ""


def observation_to_lerobot(obs: Mapping[str, Any], instruction: str) -> dict[str, Any]:
    """The LeRobot batch (B=1) for a MIKASA observation (module docstring); raises
    `BenchError` when ``obs`` has no camera images (``--obs-mode state``)."""
    import torch

    if "rgb" not in obs:
        raise BenchError(
            f"a LeRobot policy needs the camera images, but the observation has only "
            f"{sorted(obs)}; run with --obs-mode rgb (the canonical default)"
        )
    rgb = torch.as_tensor(obs["rgb"])
    if rgb.ndim == 3:
        rgb = rgb.unsqueeze(0)
    if rgb.ndim != 4 or rgb.shape[-1] != 6 or rgb.dtype != torch.uint8:
        raise BenchError(
            f"expected obs['rgb'] uint8 of shape (1, H, W, 6) (top and wrist cameras), got "
            f"{rgb.dtype} {tuple(rgb.shape)}"
        )
    # Exactly what lerobot-eval's preprocess_observation does to uint8 HWC pixels.
    images = rgb.permute(0, 3, 1, 2).to(torch.float32).div_(255.0)
    state = torch.as_tensor(obs["proprio"]).to(torch.float32).reshape(1, -1)
    return {
        TOP_KEY: images[:, 0:3].contiguous(),
        WRIST_KEY: images[:, 3:6].contiguous(),
        STATE_KEY: state,
        TASK_KEY: [instruction],
    }


class LeRobotPolicy:
    """A LeRobot pretrained policy behind the mikasa-bench policy interface.

    ``path``: the pretrained_model directory; ``device``: where the policy runs (default
    cuda when available, else cpu). ``env``/``env_id``/``task`` come from the runner;
    the instruction is the task's ``language_instruction``.
    """

    chunk_size = 1  # the policy's own select_action keeps its action queue

    def __init__(
        self,
        path: str | os.PathLike[str],
        env: Any = None,
        env_id: str | None = None,
        task: Any = None,
        device: str | None = None,
    ) -> None:
        config = load_policy_config(path, device)
        from lerobot.policies.factory import get_policy_class, make_pre_post_processors

        self.path = Path(config.pretrained_path)
        self.config = config
        self.device = config.device
        self.instruction = task_instruction(task, env_id)
        policy_cls = get_policy_class(config.type)
        self.policy = policy_cls.from_pretrained(self.path, config=config)
        self.policy.eval()
        # lerobot-eval's override: run the preprocessor's device step on this device.
        self.preprocessor, self.postprocessor = make_pre_post_processors(
            policy_cfg=config,
            pretrained_path=str(self.path),
            preprocessor_overrides={"device_processor": {"device": str(config.device)}},
        )

    def reset(self) -> None:
        """Episode start: clear the policy's action queue / history and the processors' state."""
        self.policy.reset()
        self.preprocessor.reset()
        self.postprocessor.reset()

    def forward(self, obs: Mapping[str, Any]) -> Any:
        """One action ``(7,)`` (float32, CPU) for the observation ``obs``."""
        action = self._select(observation_to_lerobot(obs, self.instruction))
        return action[0] if action.ndim == 2 and action.shape[0] == 1 else action

    def forward_batch(self, observations: Sequence[Mapping[str, Any]]) -> Any:
        """One action per env, ``(B, 7)`` (float32, CPU), for B envs stepped in lockstep
        (``mikasa-bench run --policy-batch B``): one batch through the processors and
        ``select_action``, whose action queue then holds a chunk for every env, as under
        lerobot-eval's vector envs."""
        import torch

        parts = [observation_to_lerobot(obs, self.instruction) for obs in observations]
        batch = {k: torch.cat([p[k] for p in parts]) for k in (TOP_KEY, WRIST_KEY, STATE_KEY)}
        batch[TASK_KEY] = [t for p in parts for t in p[TASK_KEY]]
        return self._select(batch)

    def _select(self, batch: dict[str, Any]) -> Any:
        import torch

        with torch.inference_mode():
            batch = self.preprocessor(batch)
            action = self.policy.select_action(batch)
            action = self.postprocessor(action)
        return action.detach().to("cpu", torch.float32)


# ------------------------------------------------------------------------------------
# policy resolution hooks (mikasa_bench.policies)
# ------------------------------------------------------------------------------------


def _label(d: Path, policy_type: str) -> str:
    """``lerobot-<type>-<name>``; lerobot-train's ``<job>/checkpoints/<step>/pretrained_model``
    gives ``<job>-<step>``."""
    name = d.name
    if name == "pretrained_model" and d.parent.parent.name == "checkpoints":
        name = f"{d.parent.parent.parent.name}-{d.parent.name}"
    elif name == "pretrained_model":
        name = d.parent.name
    return re.sub(r"[^A-Za-z0-9._-]+", "_", f"lerobot-{policy_type}-{name}")


def lerobot_policy_factory(target: str) -> Callable[..., LeRobotPolicy]:
    """The factory `build_policy` calls for a ``lerobot:DIR`` target (declares env, env_id, task)."""
    return functools.partial(LeRobotPolicy, target[len(LEROBOT_PREFIX) :])


def resolve_lerobot_policy(target: str, kwargs: dict[str, Any] | None = None) -> PolicySpec:
    """Check a ``lerobot:DIR`` policy in the main process (lerobot importable, the files
    present, the kwargs known, the features MIKASA's) and return its `PolicySpec`."""
    kwargs = dict(kwargs or {})
    d = _policy_dir(target)
    unknown = sorted(set(kwargs) - {"device"})
    if unknown:  # env / env_id / task come from the runner
        raise BenchError(
            f"--policy-kwargs for a LeRobot policy accepts only 'device' (cpu, cuda, cuda:1, "
            f"...); got {unknown}"
        )
    config = load_policy_config(d, kwargs.get("device"))
    return PolicySpec(f"{LEROBOT_PREFIX}{d}", kwargs, _label(d, str(config.type)))
