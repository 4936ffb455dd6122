"""Configuration of the recurrent memory policy (``--policy.type=memory_gru``)."""

from __future__ import annotations

from dataclasses import dataclass, field

from lerobot.configs.policies import PreTrainedConfig
from lerobot.configs.types import FeatureType, NormalizationMode
from lerobot.optim.optimizers import AdamWConfig

POLICY_TYPE = "memory_gru"


@PreTrainedConfig.register_subclass(POLICY_TYPE)
@dataclass
class MemoryGRUConfig(PreTrainedConfig):
    """A per-frame image encoder feeding a GRU that runs over the whole episode.

    At every step the policy encodes each camera with its own small CNN, embeds the state and
    the instruction, and feeds the concatenation to a GRU whose hidden state is carried from
    the episode's reset to its end; the hidden state also queries each camera's grid of local
    features (attention over cells that carry their image coordinates), and a head maps both
    to the step's action. So the action at step t depends on everything seen since the reset,
    not on a fixed window.

    Training sees sequences: a batch holds ``(B, T, ...)`` observations and actions with
    ``*_is_pad`` masks (lerobot's convention). Padding at the start (lerobot-train's windows
    that reach before the episode's first frame) keeps the GRU at its reset state; padding at
    the end (whole episodes of different lengths) is masked out of the loss.

    ``history_window``: how many frames one lerobot-train sample holds (the observation and
    action delta indices ``1 - history_window .. 0``). A window at least as long as the
    longest training episode reaches back to the reset from every step, so training and
    acting see the same history; `lerobot_policy_memory_gru.train` feeds whole episodes and
    does not use it.
    """

    history_window: int = 64
    n_action_steps: int = 1

    normalization_mapping: dict[str, NormalizationMode] = field(
        default_factory=lambda: {
            "VISUAL": NormalizationMode.IDENTITY,
            "STATE": NormalizationMode.MEAN_STD,
            "ACTION": NormalizationMode.MIN_MAX,
        }
    )

    # Per-camera encoder: three strided convolutions, then a linear layer.
    vision_channels: tuple[int, ...] = (32, 64, 64)
    vision_dim: int = 256
    # Per-pixel colour features (a 1x1 convolution) max-pooled to each grid cell and over the
    # frame, so that small cubes keep their colour; 0 turns it off.
    color_dim: int = 16
    state_dim: int = 64
    # Whether the GRU sees the robot's state. Without it, where the arm is heading has to be
    # read from the cameras, so the state cannot stand in for the memory (copycat).
    use_state: bool = True
    # Instruction: mean of hashed word embeddings (no tokenizer to download); 0 turns it off.
    instruction_buckets: int = 1024
    instruction_dim: int = 32
    hidden_dim: int = 256
    num_layers: int = 1
    # Each camera's grid of local features read by attention queried with the GRU's state
    # (what the memory looks for, and where it is); 0 turns it off.
    readout_dim: int = 64
    # Per camera, this many attention heads queried by the GRU's state whose output is the
    # attended cells' mean image position (where the remembered thing is); 0 turns it off.
    keypoint_heads: int = 0
    # What those heads compare the query with: "cells" (every feature of a cell) or "color"
    # (only its colour features, color_dim > 0). Matching on colour alone cannot learn the
    # layouts of the training episodes, only which colour to look for.
    keypoint_keys: str = "cells"
    # Whether the action head sees the memory and the readouts. False: it sees only where the
    # keypoint heads point and the robot's state, so the memory acts by pointing at a place in
    # view; a head that sees the memory's features can fit the training episodes' layouts
    # instead of learning what to look for (RememberColor3, in a supervised test).
    head_sees_memory: bool = True
    # Attention from each step over every earlier step's inputs, so that what the cue showed
    # can be looked up when the decision comes rather than carried through the delay by the
    # GRU alone; 0 turns it off.
    episode_attention_dim: int = 0
    head_dim: int = 256
    # Action chunking (Zhao et al., 2023): the head predicts this step's action and the next
    # chunk_size - 1; acting uses the first, the later ones are training targets only. A
    # decision whose effect shows over several later steps (the turn towards the remembered
    # cube) then weighs chunk_size times at the step where it is made, and the steps after it
    # cannot be explained by the arm's own motion alone.
    chunk_size: int = 8
    # 0: the head regresses each action dimension (L1). N > 1: it scores N evenly spaced values
    # of each dimension (cross-entropy; the most likely one is acted on), so that where the
    # demonstrations go one of three ways, the policy picks one instead of their median.
    action_bins: int = 0
    # An auxiliary loss with this weight (0: off): from every step's memory, a linear decoder
    # predicts each camera's first frame of the sequence (with whole episodes, as
    # mikasa-memory-train feeds them, the episode's start), average-pooled to
    # start_recall_size x start_recall_size, so that what the cue showed is kept through the
    # delay rather than left to fade until the decision needs it. Training only.
    start_recall_weight: float = 0.0
    start_recall_size: int = 16
    # Loss weight of a step: 1 + keyframe_weight * |a_t - a_(t-1)| (normalised actions), so
    # that the steps where the demonstrator changes course count (0: a plain mean).
    keyframe_weight: float = 10.0
    # Training-time augmentation: images shifted by up to this many pixels (replicate pad, crop).
    random_shift_pixels: int = 4

    optimizer_lr: float = 3e-4
    optimizer_weight_decay: float = 1e-4
    optimizer_grad_clip_norm: float = 10.0

    def __post_init__(self) -> None:
        super().__post_init__()
        if self.history_window < 1:
            raise ValueError(f"history_window must be >= 1, got {self.history_window}")
        if self.n_action_steps != 1:
            raise ValueError(
                f"n_action_steps must be 1 (the policy acts on every frame), got {self.n_action_steps}"
            )
        if self.chunk_size < 1:
            raise ValueError(f"chunk_size must be >= 1, got {self.chunk_size}")
        if self.action_bins == 1 or self.action_bins < 0:
            raise ValueError(f"action_bins must be 0 (L1) or >= 2, got {self.action_bins}")
        if self.keypoint_keys not in ("cells", "color"):
            raise ValueError(
                f"keypoint_keys must be 'cells' or 'color', got {self.keypoint_keys!r}"
            )
        if self.keypoint_keys == "color" and self.keypoint_heads > 0 and self.color_dim <= 0:
            raise ValueError(
                "keypoint_keys='color' needs color_dim > 0 (the cells' colour features)"
            )
        if not self.head_sees_memory and self.keypoint_heads <= 0:
            raise ValueError("head_sees_memory=False needs keypoint_heads > 0 (what the head sees)")
        if len(self.vision_channels) != 3:
            raise ValueError(f"vision_channels needs 3 entries, got {self.vision_channels}")

    @property
    def observation_delta_indices(self) -> list[int]:
        return list(range(1 - self.history_window, 1))

    @property
    def action_delta_indices(self) -> list[int]:
        return list(range(1 - self.history_window, 1))

    @property
    def reward_delta_indices(self) -> None:
        return None

    def get_optimizer_preset(self) -> AdamWConfig:
        return AdamWConfig(
            lr=self.optimizer_lr,
            weight_decay=self.optimizer_weight_decay,
            grad_clip_norm=self.optimizer_grad_clip_norm,
        )

    def get_scheduler_preset(self) -> None:
        return None

    def validate_features(self) -> None:
        if not self.image_features:
            raise ValueError("memory_gru needs at least one camera (a VISUAL input feature)")
        if self.action_feature is None:
            raise ValueError("memory_gru needs an 'action' output feature")
        for key, ft in self.image_features.items():
            if ft.type is not FeatureType.VISUAL or len(ft.shape) != 3:
                raise ValueError(f"camera {key}: expected a (C, H, W) VISUAL feature, got {ft}")
