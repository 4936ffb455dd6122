"""The recurrent memory policy: per-frame CNN encoders, a GRU over the episode, a readout of
each camera's grid queried by the GRU's state, an action head.

Shapes (lerobot's batch keys; ``S`` = state size, ``A`` = action size):

* training, ``forward(batch)``: every camera ``(B, T, C, H, W)`` in [0, 1], the state
  ``(B, T, S)`` and the actions ``(B, T, A)`` normalised by the preprocessor, ``action_is_pad``
  ``(B, T)``, ``task`` (B instructions). Returns the L1 loss (with ``action_bins``, the
  cross-entropy over each dimension's bins) over the steps that are not padding, each step
  weighted by how much the demonstrator's action changes there (`keyframe_weights`); with
  ``chunk_size`` K > 1, step t is also scored on the actions of steps t+1 .. t+K-1 that the
  sequence holds (`chunk_targets`).
* acting, ``select_action(batch)``: every camera ``(B, C, H, W)``, the state ``(B, S)``, ``task``;
  one step of the GRU from the hidden state the previous call left (``reset()`` clears it at
  an episode's start). Returns ``(B, A)``, normalised (the postprocessor undoes it).
"""

from __future__ import annotations

import copy
import re
import zlib
from collections.abc import Sequence

import torch
import torch.nn.functional as F
from lerobot.policies.pretrained import PreTrainedPolicy
from lerobot.utils.constants import ACTION, OBS_STATE
from torch import Tensor, nn

from lerobot_policy_memory_gru.configuration_memory_gru import POLICY_TYPE, MemoryGRUConfig

TASK_KEY = "task"
PAD_SUFFIX = "_is_pad"


def instruction_word_buckets(texts: Sequence[str], buckets: int) -> tuple[Tensor, Tensor]:
    """The words of each instruction hashed into ``buckets`` (CRC-32: the same in every
    process), as EmbeddingBag's flat ``(indices, offsets)``; an empty text is bucket 0."""
    indices: list[int] = []
    offsets: list[int] = []
    for text in texts:
        offsets.append(len(indices))
        words = re.findall(r"[a-z0-9]+", str(text).lower()) or [""]
        indices.extend(zlib.crc32(w.encode()) % buckets for w in words)
    return torch.tensor(indices, dtype=torch.long), torch.tensor(offsets, dtype=torch.long)


def random_shift(images: Tensor, pixels: int) -> Tensor:
    """Each image shifted by up to ``pixels`` in x and y (edge pixels repeated), ``(N, C, H, W)``."""
    n, _, h, w = images.shape
    padded = F.pad(images, (pixels, pixels, pixels, pixels), mode="replicate")
    dy = torch.randint(0, 2 * pixels + 1, (n,), device=images.device)
    dx = torch.randint(0, 2 * pixels + 1, (n,), device=images.device)
    rows = (torch.arange(h, device=images.device)[None] + dy[:, None])[:, :, None]  # (N, H, 1)
    cols = (torch.arange(w, device=images.device)[None] + dx[:, None])[:, None, :]  # (N, 1, W)
    batch = torch.arange(n, device=images.device)[:, None, None]
    return padded.permute(0, 2, 3, 1)[batch, rows, cols].permute(0, 3, 1, 2)


def leading_padding(pad: Tensor) -> Tensor:
    """Per row of a ``(B, T)`` padding mask, how many steps at its start are padding."""
    return torch.cumprod(pad.to(torch.long), dim=1).sum(dim=1)


def shift_left(x: Tensor, lead: Tensor) -> Tensor:
    """Row b of ``x`` (``(B, T, ...)``) moved ``lead[b]`` steps to the left (the tail repeats
    the last step; the caller masks it)."""
    b, t = x.shape[:2]
    steps = (torch.arange(t, device=x.device)[None] + lead[:, None]).clamp(max=t - 1)
    return x[torch.arange(b, device=x.device)[:, None], steps]


def keyframe_weights(actions: Tensor, valid: Tensor, strength: float) -> Tensor:
    """Per step ``1 + strength * |a_t - a_(t-1)|`` (mean over the action's dimensions; 0 at
    an episode's first step), ``(B, T)``.

    With its own history in view, an imitation policy can copy what it just did instead of
    deciding (after the first step towards a cube, the arm's motion tells which cube), and
    the few steps where the demonstrator changes course, where memory decides, weigh
    little in a plain average: "copycat" behaviour. Weighting the steps by how much the
    action changes puts the loss where the decisions are (Wen et al., "Keyframe-Focused
    Visual Imitation Learning", ICML 2021).
    """
    if strength <= 0:
        return torch.ones_like(valid)
    change = (actions[:, 1:] - actions[:, :-1]).abs().mean(dim=-1) * valid[:, 1:] * valid[:, :-1]
    return 1.0 + strength * F.pad(change, (1, 0))


def chunk_targets(values: Tensor, valid: Tensor, size: int) -> tuple[Tensor, Tensor]:
    """For every step t of ``values (B, T, ...)``, the values of steps t .. t+size-1,
    ``(B, T, size, ...)``, and their weights from ``valid (B, T)`` (0 for steps past the
    sequence's end), ``(B, T, size)``."""
    t, device = values.shape[1], values.device
    steps = torch.arange(t, device=device)[:, None] + torch.arange(size, device=device)
    inside = steps < t
    steps = steps.clamp(max=t - 1)
    return values[:, steps], valid[:, steps] * inside.to(valid.dtype)


def action_bin(actions: Tensor, bins: int) -> Tensor:
    """Normalised actions in [-1, 1] -> the index of the nearest of ``bins`` evenly spaced
    values (long, same shape)."""
    return ((actions.clamp(-1, 1) + 1) * ((bins - 1) / 2)).round().long()


class CameraEncoder(nn.Module):
    """One camera's frame -> a global feature vector and a grid of local features.

    Two strided convolutions give the grid (each cell with its x, y in [-1, 1] appended, so
    that what is read from a cell says where it is); a third convolution and a linear layer
    give the global vector.

    With ``color_dim`` > 0, a per-pixel colour branch (a 1x1 convolution) is max-pooled to
    each cell and over the whole frame and appended to both: a cube a few pixels wide on a
    textured table keeps its colour, where the strided convolutions average it with the wood
    around it.
    """

    def __init__(
        self, shape: Sequence[int], channels: Sequence[int], out_dim: int, color_dim: int = 0
    ) -> None:
        super().__init__()
        c, h, w = shape
        c1, c2, c3 = channels
        self.trunk = nn.Sequential(
            nn.Conv2d(c, c1, kernel_size=8, stride=4),
            nn.ReLU(),
            nn.Conv2d(c1, c2, kernel_size=4, stride=2),
            nn.ReLU(),
        )
        self.top = nn.Sequential(
            nn.Conv2d(c2, c3, kernel_size=3, stride=2), nn.ReLU(), nn.Flatten()
        )
        with torch.no_grad():
            grid = self.trunk(torch.zeros(1, c, h, w))
            flat = self.top(grid).shape[1]
        gh, gw = grid.shape[2:]
        ys, xs = torch.meshgrid(torch.linspace(-1, 1, gh), torch.linspace(-1, 1, gw), indexing="ij")
        self.register_buffer(
            "coords", torch.stack([xs, ys]).flatten(1).T.contiguous(), persistent=False
        )
        self.grid_size = (gh, gw)
        self.color = (
            nn.Sequential(nn.Conv2d(c, color_dim, kernel_size=1), nn.ReLU()) if color_dim else None
        )
        self.color_dim = color_dim
        self.cell_dim = c2 + 2 + color_dim
        self.out_dim = out_dim + color_dim
        self.proj = nn.Sequential(nn.Linear(flat, out_dim), nn.LayerNorm(out_dim), nn.ReLU())

    def forward(self, images: Tensor) -> tuple[Tensor, Tensor]:
        """``(N, C, H, W)`` -> global ``(N, out_dim)``, cells ``(N, cells, cell_dim)``."""
        centred = images - 0.5
        grid = self.trunk(centred)
        vector = self.proj(self.top(grid))
        cells = [grid.flatten(2).transpose(1, 2), self.coords.expand(grid.shape[0], -1, -1)]
        if self.color is not None:
            colors = self.color(centred)
            pooled = F.adaptive_max_pool2d(colors, self.grid_size)
            cells.append(pooled.flatten(2).transpose(1, 2))
            vector = torch.cat([vector, colors.amax(dim=(2, 3))], dim=-1)
        return vector, torch.cat(cells, dim=-1)

    def cell_colors(self, cells: Tensor) -> Tensor:
        """The colour features of ``cells (N, K, cell_dim)``, ``(N, K, color_dim)``."""
        return cells[..., self.cell_dim - self.color_dim :]


class MemoryReadout(nn.Module):
    """Attention over one camera's grid, queried by the GRU's state: the memory says what to
    look for (the remembered colour, the mug that hid the ball), the cells that match it give
    their features and their place."""

    def __init__(self, cell_dim: int, hidden_dim: int, dim: int) -> None:
        super().__init__()
        self.query = nn.Linear(hidden_dim, dim)
        self.key = nn.Linear(cell_dim, dim)
        self.value = nn.Linear(cell_dim, dim)
        self.scale = dim**-0.5

    def weights(self, hidden: Tensor, cells: Tensor) -> Tensor:
        """The attention over the cells, ``(N, K)``."""
        scores = torch.einsum("nd,nkd->nk", self.query(hidden), self.key(cells)) * self.scale
        return scores.softmax(dim=-1)

    def forward(self, hidden: Tensor, cells: Tensor) -> Tensor:
        """``hidden (N, hidden_dim)``, ``cells (N, K, cell_dim)`` -> ``(N, dim)``."""
        return torch.einsum("nk,nkd->nd", self.weights(hidden, cells), self.value(cells))


class MemoryKeypoints(nn.Module):
    """Where in one camera's grid the memory's object is: per head, the mean image position
    (x, y) of the cells under attention queried by the GRU's state (a spatial soft-argmax,
    Levine et al., 2016, that the memory steers).

    The readout's values are learned features of the cells, which the head ignores while the
    attention is still uniform, so nothing teaches the attention to look for the remembered
    colour. Here the output is the position itself: uniform attention gives the frame's
    centre, and the action's error pulls the weight towards the side the demonstrator went.
    (In a short CPU run on RememberColor3 its attention still stayed uniform; off by default.)
    """

    def __init__(self, cell_dim: int, hidden_dim: int, heads: int, dim: int = 32) -> None:
        super().__init__()
        self.heads, self.dim = heads, dim
        self.query = nn.Linear(hidden_dim, heads * dim)
        self.key = nn.Linear(cell_dim, heads * dim)
        self.scale = dim**-0.5

    def weights(self, hidden: Tensor, cells: Tensor) -> Tensor:
        """The attention of every head over the cells, ``(N, heads, K)``."""
        n, k = cells.shape[:2]
        query = self.query(hidden).view(n, self.heads, self.dim)
        key = self.key(cells).view(n, k, self.heads, self.dim)
        return (torch.einsum("nhd,nkhd->nhk", query, key) * self.scale).softmax(dim=-1)

    def forward(self, hidden: Tensor, cells: Tensor, coords: Tensor) -> Tensor:
        """``hidden (N, hidden_dim)``, ``cells (N, K, cell_dim)``, the cells' ``coords (K, 2)``
        -> every head's (x, y), ``(N, 2 * heads)``."""
        return torch.einsum("nhk,kc->nhc", self.weights(hidden, cells), coords).flatten(1)


class EpisodeAttention(nn.Module):
    """Causal attention from each step over the inputs of every step so far in the episode.

    A GRU has to carry what the cue showed through the delay in its state, and nothing in the
    loss before the decision asks it to; this looks the cue up again when the decision comes.
    ``keys``/``values`` of earlier steps are the caller's to keep while acting.
    """

    def __init__(self, step_dim: int, hidden_dim: int, dim: int) -> None:
        super().__init__()
        self.query = nn.Linear(hidden_dim, dim)
        self.key = nn.Linear(step_dim, dim)
        self.value = nn.Linear(step_dim, dim)
        self.scale = dim**-0.5

    def forward(
        self, hidden: Tensor, steps: Tensor, past: tuple[Tensor, Tensor] | None = None
    ) -> tuple[Tensor, tuple[Tensor, Tensor]]:
        """``hidden (B, T, hidden_dim)``, ``steps (B, T, step_dim)`` and the keys/values of the
        episode's earlier steps -> ``(B, T, dim)`` and the keys/values including these steps."""
        keys, values = self.key(steps), self.value(steps)
        if past is not None:
            keys, values = torch.cat([past[0], keys], 1), torch.cat([past[1], values], 1)
        t, n = steps.shape[1], keys.shape[1]
        scores = torch.einsum("btd,bnd->btn", self.query(hidden), keys) * self.scale
        later = (
            torch.arange(n, device=steps.device)[None]
            > torch.arange(n - t, n, device=steps.device)[:, None]
        )
        scores = scores.masked_fill(later, float("-inf"))
        return torch.einsum("btn,bnd->btd", scores.softmax(dim=-1), values), (keys, values)


class MemoryGRUPolicy(PreTrainedPolicy):
    """CNN per camera + state + instruction -> GRU over the episode -> action, with each
    camera's grid read by the GRU's state (module docstring)."""

    config_class = MemoryGRUConfig
    name = POLICY_TYPE

    def __init__(
        self, config: MemoryGRUConfig, dataset_stats: dict | None = None, **kwargs
    ) -> None:
        super().__init__(config)
        config.validate_features()
        self.config = config
        self.camera_keys = list(config.image_features)
        names = [key.replace(".", "_") for key in self.camera_keys]
        self.encoders = nn.ModuleDict(
            {
                name: CameraEncoder(
                    config.image_features[key].shape,
                    config.vision_channels,
                    config.vision_dim,
                    config.color_dim,
                )
                for name, key in zip(names, self.camera_keys, strict=True)
            }
        )
        step_dim = sum(encoder.out_dim for encoder in self.encoders.values())
        state = config.robot_state_feature
        self.state_proj = None
        if state is not None and config.use_state:
            self.state_proj = nn.Sequential(nn.Linear(state.shape[0], config.state_dim), nn.ReLU())
            step_dim += config.state_dim
        self.instruction = None
        if config.instruction_buckets > 0:
            self.instruction = nn.EmbeddingBag(
                config.instruction_buckets, config.instruction_dim, mode="mean"
            )
            step_dim += config.instruction_dim
        self.gru = nn.GRU(step_dim, config.hidden_dim, config.num_layers, batch_first=True)
        self.episode_attention = (
            EpisodeAttention(step_dim, config.hidden_dim, config.episode_attention_dim)
            if config.episode_attention_dim > 0
            else None
        )
        # What the cameras' grids are queried with: the GRU's state and what the episode
        # attention recalled (the cue, looked up again rather than carried through the delay).
        query_dim = config.hidden_dim + config.episode_attention_dim
        self.readouts = nn.ModuleDict(
            {
                name: MemoryReadout(
                    self.encoders[name].cell_dim,
                    query_dim,
                    config.readout_dim,
                )
                for name in names
            }
            if config.readout_dim > 0 and config.head_sees_memory
            else {}
        )
        self.keypoints = nn.ModuleDict(
            {
                name: MemoryKeypoints(
                    self.encoders[name].color_dim
                    if config.keypoint_keys == "color"
                    else self.encoders[name].cell_dim,
                    query_dim,
                    config.keypoint_heads,
                )
                for name in names
            }
            if config.keypoint_heads > 0
            else {}
        )
        head_in = 2 * config.keypoint_heads * len(self.keypoints)
        if config.head_sees_memory:
            head_in += query_dim + config.readout_dim * len(self.readouts)
        elif self.state_proj is not None:
            head_in += config.state_dim
        self.head = nn.Sequential(
            nn.Linear(head_in, config.head_dim),
            nn.ReLU(),
            nn.Linear(
                config.head_dim,
                config.action_feature.shape[0] * config.chunk_size * max(config.action_bins, 1),
            ),
        )
        # Training only: a decoder of the sequence's first frame from every step's memory
        # (made last, so that the other layers' initial weights do not depend on it).
        self.start_recall = (
            nn.Linear(query_dim, 3 * config.start_recall_size**2 * len(self.camera_keys))
            if config.start_recall_weight > 0
            else None
        )
        self.reset()

    # -------------------------------------------------------------- lerobot's interface
    def _save_pretrained(self, save_directory) -> None:
        # On a GPU, cuDNN keeps the GRU's weights as views of one flat buffer, which
        # safetensors refuses to save: save a CPU copy instead.
        if any(p.is_cuda for p in self.parameters()):
            copy.deepcopy(self).to("cpu")._save_pretrained(save_directory)
            return
        super()._save_pretrained(save_directory)

    def get_optim_params(self) -> dict:
        return self.parameters()

    def reset(self) -> None:
        """An episode starts: forget the hidden state."""
        self._hidden: Tensor | None = None
        self._past: tuple[Tensor, Tensor] | None = None

    def forward(self, batch: dict[str, Tensor]) -> tuple[Tensor, dict]:
        """The L1 loss of the predicted actions over a batch of sequences (module docstring)."""
        actions = batch[ACTION]
        if actions.ndim == 2:  # one target per sample: a sequence of length 1
            batch = {k: (v.unsqueeze(1) if isinstance(v, Tensor) else v) for k, v in batch.items()}
            actions = batch[ACTION]
        b, t = actions.shape[:2]
        pad = batch.get(ACTION + PAD_SUFFIX)
        pad = torch.zeros(b, t, dtype=torch.bool, device=actions.device) if pad is None else pad
        # Start the GRU at each sequence's first real step: move leading padding to the end.
        lead = leading_padding(pad)
        if bool(lead.any()):
            keys = [*self.camera_keys, OBS_STATE, ACTION]
            batch = {**batch, **{k: shift_left(batch[k], lead) for k in keys if k in batch}}
            pad = shift_left(pad, lead) | (
                torch.arange(t, device=pad.device)[None] + lead[:, None] >= t
            )
        raw, memory, _ = self.actions(batch, b, t)  # raw: (B, T, K, A), with bins (..., bins)
        valid = (~pad).to(raw.dtype)
        weight = valid * keyframe_weights(batch[ACTION], valid, self.config.keyframe_weight)
        targets, target_weight = chunk_targets(batch[ACTION], weight, self.config.chunk_size)
        if self.config.action_bins > 0:
            error = F.cross_entropy(
                raw.movedim(-1, 1), action_bin(targets, self.config.action_bins), reduction="none"
            ).mean(dim=-1)  # (B, T, K)
        else:
            error = (raw - targets).abs().mean(dim=-1)  # (B, T, K)
        loss = (error * target_weight).sum() / target_weight.sum().clamp(min=1e-6)
        first = (error[:, :, 0] * valid).sum() / valid.sum().clamp(min=1.0)
        info = {"ce_loss" if self.config.action_bins > 0 else "l1_loss": first.item()}
        if self.start_recall is not None:
            # Every step's memory asked for a thumbnail of the episode's first frame.
            size = self.config.start_recall_size
            target = torch.cat(
                [
                    F.adaptive_avg_pool2d(batch[k][:, 0], size).flatten(1) - 0.5
                    for k in self.camera_keys
                ],
                dim=-1,
            )
            recall = ((self.start_recall(memory) - target[:, None]) ** 2).mean(dim=-1)  # (B, T)
            recall = (recall * valid).sum() / valid.sum().clamp(min=1.0)
            loss = loss + self.config.start_recall_weight * recall
            info["recall_loss"] = recall.item()
        return loss, info

    def decode(self, raw: Tensor) -> Tensor:
        """The head's output -> actions ``(..., A)`` (normalised): itself under L1, the most
        likely bin's centre with ``action_bins``."""
        if self.config.action_bins <= 0:
            return raw
        return raw.argmax(dim=-1).to(raw.dtype) * (2.0 / (self.config.action_bins - 1)) - 1.0

    @torch.no_grad()
    def predict_action_chunk(self, batch: dict[str, Tensor], **kwargs) -> Tensor:
        """One step of the GRU: the action ``(B, 1, A)`` for this frame; advances the state."""
        b = batch[self.camera_keys[0]].shape[0]
        if self._hidden is not None and self._hidden.shape[1] != b:
            raise ValueError(
                f"memory_gru got a batch of {b} after batches of {self._hidden.shape[1]} in the "
                "same episode; call reset() when the set of episodes changes"
            )
        step = {k: (v.unsqueeze(1) if isinstance(v, Tensor) else v) for k, v in batch.items()}
        raw, _, (self._hidden, self._past) = self.actions(step, b, 1, self._hidden, self._past)
        return self.decode(raw)[:, :, 0]

    @torch.no_grad()
    def select_action(self, batch: dict[str, Tensor], **kwargs) -> Tensor:
        """The action ``(B, A)`` for this frame, given every frame since ``reset()``."""
        return self.predict_action_chunk(batch)[:, 0]

    # -------------------------------------------------------------- the network
    def actions(
        self,
        batch: dict[str, Tensor],
        b: int,
        t: int,
        hidden: Tensor | None = None,
        past: tuple[Tensor, Tensor] | None = None,
    ) -> tuple[Tensor, Tensor, tuple[Tensor, tuple[Tensor, Tensor] | None]]:
        """The action chunks ``(B, T, chunk_size, A)`` (with bins ``(..., A, bins)``) and the
        memory ``(B, T, query_dim)`` of ``T`` steps that follow the GRU state ``hidden`` and
        the episode attention's keys/values ``past`` (None: an episode's start), and both
        after them."""
        parts, cells = [], []
        for key in self.camera_keys:
            images = batch[key].flatten(0, 1)
            if self.training and self.config.random_shift_pixels > 0:
                images = random_shift(images, self.config.random_shift_pixels)
            vector, grid = self.encoders[key.replace(".", "_")](images)
            parts.append(vector.view(b, t, -1))
            cells.append(grid)
        state = self.state_proj(batch[OBS_STATE]) if self.state_proj is not None else None
        if state is not None:
            parts.append(state)
        if self.instruction is not None:
            parts.append(self._instruction(batch, b, t, parts[0].device))
        steps = torch.cat(parts, dim=-1)
        memory, hidden = self.gru(steps, hidden)
        if self.episode_attention is not None:
            recalled, past = self.episode_attention(memory, steps, past)
            memory = torch.cat([memory, recalled], dim=-1)
        if self.config.head_sees_memory:
            read = [memory]
        else:  # the memory acts only through where the keypoint heads point
            read = [state] if state is not None else []
        queries = memory.flatten(0, 1)
        colour_keys = self.config.keypoint_keys == "color"
        for key, grid in zip(self.camera_keys, cells, strict=True):
            name = key.replace(".", "_")
            encoder = self.encoders[name]
            if self.readouts:
                read.append(self.readouts[name](queries, grid).view(b, t, -1))
            if self.keypoints:
                keys = encoder.cell_colors(grid) if colour_keys else grid
                points = self.keypoints[name](queries, keys, encoder.coords)
                read.append(points.view(b, t, -1))
        chunks = self.head(torch.cat(read, dim=-1)).view(b, t, self.config.chunk_size, -1)
        if self.config.action_bins > 0:
            chunks = chunks.unflatten(-1, (-1, self.config.action_bins))
        return chunks, memory, (hidden, past)

    def _instruction(
        self, batch: dict[str, Tensor], b: int, t: int, device: torch.device
    ) -> Tensor:
        """``(B, T, instruction_dim)``: the mean of the instruction's hashed word embeddings."""
        texts = batch.get(TASK_KEY)
        if texts is None:
            raise KeyError(
                f"memory_gru with instruction_buckets > 0 needs the instruction in "
                f"batch[{TASK_KEY!r}]; got keys {sorted(batch)}"
            )
        texts = [texts] * b if isinstance(texts, str) else list(texts)
        indices, offsets = instruction_word_buckets(texts, self.config.instruction_buckets)
        words = self.instruction(indices.to(device), offsets.to(device))
        return words[:, None].expand(b, t, -1)
