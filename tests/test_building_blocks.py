"""Shared scene pieces: the colour-switch lamp, push buttons and their press latch, discs."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from mikasa_envs.base_env import MikasaVLABaseEnv
from mikasa_envs.building_blocks.buttons import (
    BUTTON_CAP_REST_Z,
    BUTTON_TOP_Z,
    PRESSED_DEPTH,
    Button,
    PressLatch,
    press_depth,
)
from mikasa_envs.building_blocks.discs import build_disc
from mikasa_envs.building_blocks.lamps import BULB_GLASS_Z, ColorSwitchLamp
from mikasa_envs.building_blocks.poses import HIDE_OFFSET_Z

LAMP_AT = (0.1, 0.2, 0.0)
BUTTON_AT = (-0.1, 0.05)


class _PiecesEnv(MikasaVLABaseEnv):
    """A lamp, a button and a disc on the table; nothing else."""

    LANGUAGE_INSTRUCTION = "test"

    def _load_scene(self, options: dict) -> None:
        super()._load_scene(options)
        self.lamp = ColorSwitchLamp(
            self.scene, "lamp", {"off": ((255, 255, 255), 0.0), "red": ((255, 0, 0), 2.0)}, self.num_envs, self.device
        )
        self.button = Button(
            self.scene, "button", (0.065, 0.065, 0.015), 0.03, (55, 64, 78, 255), (210, 80, 80, 255),
            self.num_envs, self.device,
        )
        self.disc = build_disc(self.scene, "disc", 0.07, 0.003, (30, 180, 30, 255))

    def _sample_episode(self, env_idx: torch.Tensor, options: dict) -> None:
        self.oracle_info = torch.zeros(self.num_envs, dtype=torch.uint8)
        self.lamp.place(env_idx, torch.tensor([LAMP_AT]).repeat(len(env_idx), 1))
        self.button.place(env_idx, torch.tensor([BUTTON_AT]).repeat(len(env_idx), 1))

    def evaluate(self) -> dict:
        return dict(success=torch.zeros(self.num_envs, dtype=torch.bool))

    def compute_dense_reward(self, obs, action, info) -> torch.Tensor:
        return torch.zeros(self.num_envs)


@pytest.fixture
def pieces_env():
    env = _PiecesEnv(obs_mode="state", sim_backend="cpu", control_mode="pd_ee_delta_pose")
    env.reset(seed=0)
    yield env
    env.close()


def _z(actor) -> float:
    return float(actor.pose.p[0, 2])


def test_lamp_shows_one_bulb(pieces_env):
    lamp = pieces_env.lamp
    off, red = lamp.bulbs
    np.testing.assert_allclose(lamp.body.pose.p[0].numpy(), LAMP_AT, atol=1e-6)
    assert _z(off) == pytest.approx(0.0) and _z(red) == pytest.approx(HIDE_OFFSET_Z)
    lamp.show(torch.tensor([0]), lamp.bulb_index("red"))
    assert _z(off) == pytest.approx(HIDE_OFFSET_Z) and _z(red) == pytest.approx(0.0)
    assert BULB_GLASS_Z < 0.1
    with pytest.raises(KeyError, match="no bulb 'blue'"):
        lamp.bulb_index("blue")


def test_button_cap_follows_depth(pieces_env):
    button = pieces_env.button
    assert _z(button.cap) == pytest.approx(BUTTON_CAP_REST_Z)
    button.show_depth(torch.tensor([0.01]))
    assert _z(button.cap) == pytest.approx(BUTTON_CAP_REST_Z - 0.01)
    np.testing.assert_allclose(pieces_env.disc.pose.p[0, 2].item(), HIDE_OFFSET_Z)


def test_press_depth_rule():
    xy = torch.tensor([[0.0, 0.0]])
    at = lambda x, z: torch.tensor([[x, 0.0, z]])  # noqa: E731
    assert float(press_depth(at(0.0, 0.2), xy, 0.065)) == 0.0
    assert float(press_depth(at(0.0, BUTTON_TOP_Z + 0.03 - 0.005), xy, 0.065)) == pytest.approx(0.005)
    assert float(press_depth(at(0.0, 0.0), xy, 0.065)) == pytest.approx(0.014)
    assert float(press_depth(at(0.065, 0.0), xy, 0.065)) == 0.0
    assert float(press_depth(at(0.065, 0.0), xy, 0.065, inclusive=True)) == pytest.approx(0.014)


def test_press_latch_counts_a_press_after_release_and_lift():
    latch = PressLatch(1, "cpu")
    yes = torch.tensor([True])
    events = []
    # Down (press registers at z = 0.08), up past the release height, on up by 0.085.
    for depth, z in [(0.0, 0.2), (PRESSED_DEPTH + 1e-4, 0.08), (0.014, 0.06), (0.0, 0.09), (0.0, 0.17)]:
        raw, confirmed = latch.update(torch.tensor([depth]), torch.tensor([z]), yes, yes)
        events.append((bool(raw), bool(confirmed)))
    assert events == [(False, False), (True, False), (False, False), (False, False), (False, True)]
    # A gated-off press does nothing.
    raw, confirmed = latch.update(torch.tensor([0.014]), torch.tensor([0.06]), yes, torch.tensor([False]))
    assert not bool(raw) and not bool(confirmed)
