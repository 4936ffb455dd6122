"""The network pieces of the RL release's PPO agents (``ppo_baselines.md`` §4): the state-only
MLP (``AgentStateOnly``), the image encoder (``NatureCNN``) and what every agent shares
(``GaussianActorCritic``). The trainers' image agents (``Agent`` in
``baselines/ppo/ppo_memtasks.py``, ``AgentLSTM`` in ``ppo_memtasks_lstm.py``) are built from them.

``AgentStateOnly`` is the network of the release's ``ppo_memtasks`` state baseline, whose
``final_success_ckpt.pt`` checkpoints the RL data collector replays
(``<ckpt-dir>/oracle_checkpoints/ppo_memtasks/state/normalized_dense/<env_id>/**``). Its
input is the state-mode observation flattened (``state``, then ``task_cue`` where the task
has one: :func:`flatten_state_obs`); the checkpoint is its plain ``state_dict``
(``critic.{0,2,4,6}.*``, ``actor_mean.{0,2,4,6}.*``, ``actor_logstd``).
:func:`find_checkpoints` and :func:`load_agent` read that layout.
"""

from __future__ import annotations

import math
import os
from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch import nn
from torch.distributions.normal import Normal

__all__ = [
    "CKPT_NAME",
    "CKPT_SUBDIR",
    "INITIAL_LOGSTD",
    "AgentStateOnly",
    "GaussianActorCritic",
    "NatureCNN",
    "find_checkpoints",
    "flatten_state_obs",
    "layer_init",
    "load_agent",
]

HIDDEN = 256
INITIAL_LOGSTD = -0.5
"""The actor's initial log std per action dimension (upstream's; std 0.61)."""
CKPT_SUBDIR = "oracle_checkpoints/ppo_memtasks/state/normalized_dense"
"""Where the release kept its PPO state agents, under a checkpoint root, per env id."""
CKPT_NAME = "final_success_ckpt.pt"
TRAINED_CKPT_NAME = "final_ckpt.pt"
"""What ``baselines/ppo/ppo_memtasks.py`` writes at the end of a run (and what ships)."""


def layer_init(layer: nn.Linear, std: float = math.sqrt(2), bias: float = 0.0) -> nn.Linear:
    """Orthogonal weights with gain ``std`` and constant bias (CleanRL's PPO init)."""
    nn.init.orthogonal_(layer.weight, std)
    nn.init.constant_(layer.bias, bias)
    return layer


def _mlp(in_dim: int, out_dim: int, out_std: float) -> nn.Sequential:
    return nn.Sequential(
        layer_init(nn.Linear(in_dim, HIDDEN)),
        nn.Tanh(),
        layer_init(nn.Linear(HIDDEN, HIDDEN)),
        nn.Tanh(),
        layer_init(nn.Linear(HIDDEN, HIDDEN)),
        nn.Tanh(),
        layer_init(nn.Linear(HIDDEN, out_dim), std=out_std),
    )


class GaussianActorCritic(nn.Module):
    """What the PPO agents share: a diagonal Gaussian policy with the state-independent
    ``actor_logstd`` over ``actor_mean(features)``, and ``critic(features)`` (``ppo_baselines.md``
    §4); the adjustments a resumed run makes to them and the gradient norms the update logs."""

    actor_mean: nn.Module
    critic: nn.Module
    actor_logstd: nn.Parameter

    def scale_values(self, factor: float) -> None:
        """Multiply every value the critic outputs by ``factor`` (its output layer's weight and
        bias): what a change of the reward scale does to the returns it predicts."""
        head = [m for m in self.critic.modules() if isinstance(m, nn.Linear)][-1]
        with torch.no_grad():
            head.weight.mul_(factor)
            head.bias.mul_(factor)

    def floor_logstd(self, min_logstd: float) -> None:
        """Raise the policy's log std to at least ``min_logstd`` in every action dimension
        (more action noise for a policy whose noise has collapsed)."""
        with torch.no_grad():
            self.actor_logstd.clamp_(min=min_logstd)

    def head_grad_norms(self) -> dict[str, torch.Tensor]:
        """L2 norms of the current gradients of the critic's parameters and of the policy's own
        (``actor_mean``, ``actor_logstd``; a shared encoder counts in neither), as
        ``actor_grad_norm`` / ``critic_grad_norm``. Taken before the one gradient-norm clip over
        all parameters: a critic norm far above the actor's means the clip shrinks the policy's
        step to a fraction of what its loss asked for."""
        def norm(params: Iterable[nn.Parameter]) -> torch.Tensor:
            return nn.utils.get_total_norm([p.grad for p in params if p.grad is not None])

        actor = [*self.actor_mean.parameters(), self.actor_logstd]
        return {"actor_grad_norm": norm(actor), "critic_grad_norm": norm(self.critic.parameters())}


class AgentStateOnly(GaussianActorCritic):
    """PPO actor-critic MLP on the flattened state observation.

    Critic and actor mean are ``Linear(obs_dim, 256)-Tanh-Linear(256, 256)-Tanh-
    Linear(256, 256)-Tanh-Linear(256, out)``; the action distribution is a diagonal
    Gaussian with the state-independent ``actor_logstd`` (shape ``(1, action_dim)``).
    """

    def __init__(self, obs_dim: int, action_dim: int, initial_logstd: float = INITIAL_LOGSTD) -> None:
        super().__init__()
        self.obs_dim, self.action_dim = int(obs_dim), int(action_dim)
        self.critic = _mlp(self.obs_dim, 1, out_std=1.0)
        self.actor_mean = _mlp(self.obs_dim, self.action_dim, out_std=0.01 * math.sqrt(2))
        self.actor_logstd = nn.Parameter(torch.ones(1, self.action_dim) * initial_logstd)

    def get_value(self, x: torch.Tensor) -> torch.Tensor:
        """V(x), shape ``(B, 1)``."""
        return self.critic(x)

    def get_action(self, x: torch.Tensor, deterministic: bool = False) -> torch.Tensor:
        """The action for ``x``: the mean if ``deterministic``, else a Gaussian sample."""
        action_mean = self.actor_mean(x)
        if deterministic:
            return action_mean
        return Normal(action_mean, torch.exp(self.actor_logstd.expand_as(action_mean))).sample()

    def get_action_and_value(
        self, x: torch.Tensor, action: torch.Tensor | None = None
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
        """``(action, log_prob, entropy, value)`` as PPO's update needs them."""
        action_mean = self.actor_mean(x)
        probs = Normal(action_mean, torch.exp(self.actor_logstd.expand_as(action_mean)))
        if action is None:
            action = probs.sample()
        return action, probs.log_prob(action).sum(1), probs.entropy().sum(1), self.critic(x)

    @classmethod
    def from_state_dict(cls, state_dict: Mapping[str, Any]) -> AgentStateOnly:
        """An agent sized from a checkpoint's ``state_dict`` and loaded (strict)."""
        try:
            obs_dim = int(state_dict["actor_mean.0.weight"].shape[1])
            action_dim = int(state_dict["actor_logstd"].shape[-1])
        except (KeyError, AttributeError, IndexError) as exc:
            raise ValueError(f"not an AgentStateOnly state_dict (missing {exc})") from None
        agent = cls(obs_dim, action_dim)
        agent.load_state_dict(state_dict)
        return agent


class NatureCNN(nn.Module):
    """Features of an image observation dict (``ppo_baselines.md`` §4.2), concatenated in
    this order: ``rgb`` (uint8 ``(B, H, W, C)``) through the Nature DQN convs and a 256-wide
    layer; each of ``oracle_info`` / ``task_cue`` / ``proprio`` present (in the
    observation's key order) through one ReLU layer (64 / 64 / ``proprio_width``); ``state``
    through one linear layer of 256."""

    def __init__(self, sample_obs: Mapping[str, torch.Tensor], proprio_width: int = 128) -> None:
        super().__init__()
        extractors: dict[str, nn.Module] = {}
        self.out_features = 0
        if "rgb" in sample_obs:
            channels = sample_obs["rgb"].shape[-1]
            cnn = nn.Sequential(
                nn.Conv2d(channels, 32, kernel_size=8, stride=4), nn.ReLU(),
                nn.Conv2d(32, 64, kernel_size=4, stride=2), nn.ReLU(),
                nn.Conv2d(64, 64, kernel_size=3, stride=1), nn.ReLU(),
                nn.Flatten(),
            )
            with torch.no_grad():
                n_flat = cnn(self._image(sample_obs["rgb"][:1].cpu())).shape[1]
            extractors["rgb"] = nn.Sequential(cnn, nn.Sequential(nn.Linear(n_flat, 256), nn.ReLU()))
            self.out_features += 256
        widths = {"oracle_info": 64, "task_cue": 64, "proprio": proprio_width}
        for key in sample_obs:
            if key in widths:
                d = int(np.prod(sample_obs[key].shape[1:]))
                extractors[key] = nn.Sequential(nn.Linear(d, widths[key]), nn.ReLU())
                self.out_features += widths[key]
        if "state" in sample_obs:
            extractors["state"] = nn.Linear(int(np.prod(sample_obs["state"].shape[1:])), 256)
            self.out_features += 256
        self.extractors = nn.ModuleDict(extractors)

    @staticmethod
    def _image(rgb: torch.Tensor) -> torch.Tensor:
        return rgb.float().permute(0, 3, 1, 2) / 255.0

    def forward(self, obs: Mapping[str, torch.Tensor]) -> torch.Tensor:
        """``(B, out_features)`` features of ``obs``."""
        parts = []
        for key, extractor in self.extractors.items():
            x = self._image(obs[key]) if key == "rgb" else obs[key].float().reshape(obs[key].shape[0], -1)
            parts.append(extractor(x))
        return torch.cat(parts, dim=1)


def flatten_state_obs(obs: Mapping[str, Any]) -> torch.Tensor:
    """The agent input of a state-mode observation: its entries in key order (``state``,
    then ``task_cue``), each flattened per env, concatenated as float32 ``(B, obs_dim)``."""
    parts = [torch.as_tensor(np.asarray(v) if not torch.is_tensor(v) else v) for v in obs.values()]
    return torch.cat([p.reshape(p.shape[0], -1).to(torch.float32) for p in parts], dim=1)


def find_checkpoints(ckpt_dir: str | os.PathLike[str], env_id: str) -> list[Path]:
    """The state checkpoints of ``env_id`` under ``ckpt_dir``, sorted by path, from the first
    layout that has any: the release's ``<ckpt_dir>/<CKPT_SUBDIR>/<env_id>/**/
    final_success_ckpt.pt``; this package's shipped ``<ckpt_dir>/<env_id>/final_ckpt.pt``
    (``legacy/rl/baselines/checkpoints``); a ``ppo_memtasks.py`` run's
    ``<ckpt_dir>/checkpoints/ppo_memtasks/state/<reward_mode>/<env_id>/**/final_ckpt.pt``.
    ``ValueError`` if there is none."""
    root = Path(ckpt_dir)
    layouts = [
        (root / CKPT_SUBDIR / env_id, f"**/{CKPT_NAME}"),
        (root / env_id, TRAINED_CKPT_NAME),
        (root / "checkpoints/ppo_memtasks/state", f"*/{env_id}/**/{TRAINED_CKPT_NAME}"),
    ]
    for directory, pattern in layouts:
        found = sorted(directory.glob(pattern)) if directory.is_dir() else []
        if found:
            return found
    raise ValueError(f"no checkpoint {root / CKPT_SUBDIR / env_id}/**/{CKPT_NAME} (nor {root / env_id}/"
                     f"{TRAINED_CKPT_NAME}, nor a ppo_memtasks.py run's state {TRAINED_CKPT_NAME})")


def load_agent(path: str | os.PathLike[str]) -> AgentStateOnly:
    """The agent saved (as a ``state_dict``) at ``path``, in eval mode, on the CPU;
    ``ValueError`` naming the file if it is not one."""
    try:
        state = torch.load(path, map_location="cpu", weights_only=True)
        return AgentStateOnly.from_state_dict(state).eval()
    except Exception as exc:
        raise ValueError(f"{path}: not an AgentStateOnly checkpoint: {exc}") from None
