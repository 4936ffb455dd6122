"""Tests of the procedural shape library (spec: shapes.md §1-§3).

One tiny robot-less ManiSkill env builds all nine task shapes (plus the target
disc) once per module; physics is stepped directly on the scene to keep the run
short on CPU.
"""

from __future__ import annotations

import math

import gymnasium as gym
import numpy as np
import pytest
import sapien
import torch
from mani_skill.envs.sapien_env import BaseEnv
from mani_skill.utils.registration import register_env
from mikasa_envs.building_blocks import shapes

# shapes.md §1 "Mass (kg)" column.
SPEC_MASS = {
    "cube": 0.0640,
    "sphere": 0.0335,
    "cylinder": 0.0499,
    "cross": 0.0270,
    "torus": 0.0382,
    "star": 0.0338,
    "pyramide": 0.0264,
    "t_shape": 0.0180,
    "crescent": 0.0320,
}
# shapes.md §1 "Rest z" column.
SPEC_REST_Z = {
    "cube": 0.02,
    "sphere": 0.02,
    "cylinder": 0.02,
    "cross": 0.0075,
    "torus": 0.007654,
    "star": 0.0075,
    "pyramide": 0.005,
    "t_shape": 0.0075,
    "crescent": 0.002846,
}
SPACING = 0.15  # m between shapes, far apart so they never touch
DROP = 0.005  # m above rest z each shape is released from
ENV_ID = "MikasaShapesTest-v0"


@register_env(ENV_ID, max_episode_steps=10)
class _ShapesTestEnv(BaseEnv):
    """Robot-less scene: a static table slab (top at z = 0) and every task shape."""

    def __init__(self, *args, **kwargs):
        super().__init__(*args, robot_uids="none", **kwargs)

    def _load_scene(self, options: dict):
        builder = self.scene.create_actor_builder()
        # A thick static box rather than a plane: same contact as the task table top.
        builder.add_box_collision(pose=sapien.Pose(p=[0, 0, -0.05]), half_size=[3.0, 3.0, 0.05])
        builder.initial_pose = sapien.Pose()
        self.table = builder.build_static(name="table")
        self.shape_actors = {
            name: shapes.build_task_shape(
                self.scene,
                name,
                [0, 0, 1, 1],
                f"{name}_{k}",
                initial_pose=sapien.Pose(p=[k * SPACING, 0, 0.5], q=shapes.shape_orientation(name)),
            )
            for k, name in enumerate(shapes.SHAPE_NAMES)
        }
        self.target = shapes.build_target(
            self.scene,
            0.05,
            0.005,
            "target",
            body_type="kinematic",
            initial_pose=sapien.Pose(p=[0, 0.5, 0.1]),
        )

    def _initialize_episode(self, env_idx: torch.Tensor, options: dict):
        pass

    # ManiSkill 3.0.1 does not guard these two against robot_uids="none".
    def _get_obs_agent(self):
        return {}

    def get_state_dict(self):
        return self.scene.get_sim_state()

    def _get_obs_extra(self, info: dict):
        return {}

    def evaluate(self):
        return {}


@pytest.fixture(scope="module")
def env():
    e = gym.make(ENV_ID, num_envs=1, obs_mode="state", sim_backend="cpu", render_mode=None)
    e.reset(seed=0)
    yield e.unwrapped
    e.close()


def test_constants():
    assert len(shapes.SHAPE_NAMES) == 9 and shapes.SHAPE_NAMES[6] == "pyramide"
    assert shapes.SHAPE_AND_COLOR_SHAPES == ("cube", "sphere", "t_shape", "cross", "torus")
    assert shapes.SHAPE_SCALE == 0.02
    for name, z in SPEC_REST_Z.items():
        assert shapes.SHAPE_REST_Z[name] == pytest.approx(z, abs=1e-6), name
    # Exact closed forms of the two non-trivial rest heights.
    assert shapes.SHAPE_REST_Z["torus"] == pytest.approx(0.02 * math.sin(math.pi / 8), rel=1e-12)
    assert shapes.SHAPE_REST_Z["crescent"] == pytest.approx(
        0.02 * math.sin(math.pi / 22), rel=1e-12
    )
    assert shapes.shape_orientation("cylinder") == [0.7071068, 0.0, 0.7071068, 0.0]
    assert shapes.shape_orientation("torus") == [1.0, 0.0, 0.0, 0.0]


def test_unknown_shape_raises(env):
    with pytest.raises(ValueError, match="pyramide"):
        shapes.build_task_shape(env.scene, "pyramid", [1, 0, 0, 1], "bad")
    with pytest.raises(ValueError, match="crescent"):
        shapes.shape_orientation("donut")


def test_masses(env):
    for name, actor in env.shape_actors.items():
        mass = float(actor.mass[0])
        assert mass == pytest.approx(SPEC_MASS[name], rel=0.02), (name, mass)


def test_part_counts_and_invisible_inner_arc(env):
    def render_shapes(actor):
        body = actor._objs[0].find_component_by_type(sapien.render.RenderBodyComponent)
        return body.render_shapes

    def n_collision(actor):
        return len(actor._bodies[0].collision_shapes)

    expected = {
        "cube": 1,
        "sphere": 1,
        "cylinder": 1,
        "cross": 2,
        "torus": 8,
        "star": 5,
        "pyramide": 3,
        "t_shape": 2,
        "crescent": 24,
    }
    for name, actor in env.shape_actors.items():
        assert n_collision(actor) == expected[name], name
        assert len(render_shapes(actor)) == expected[name], name
    alphas = [s.material.base_color[3] for s in render_shapes(env.shape_actors["crescent"])]
    assert alphas == [1.0] * 12 + [0.0] * 12
    assert n_collision(env.target) == 5
    target_colors = [tuple(np.round(s.material.base_color, 4)) for s in render_shapes(env.target)]
    assert target_colors[0] == tuple(np.round(np.array([194, 19, 22, 255]) / 255, 4))
    assert target_colors[1] == (1.0, 1.0, 1.0, 1.0)


def test_set_actor_visual_rgba(env):
    actor = env.shape_actors["cube"]
    shapes.set_actor_visual_rgba(actor, [0.2, 0.4, 0.6], emission_scale=2.0, remove_textures=True)
    mat = (
        actor._objs[0]
        .find_component_by_type(sapien.render.RenderBodyComponent)
        .render_shapes[0]
        .material
    )
    assert np.allclose(mat.base_color, [0.2, 0.4, 0.6, 1.0])
    assert np.allclose(mat.emission, [0.4, 0.8, 1.2, 1.0])
    assert mat.base_color_texture is None
    assert shapes._set_actor_visual_rgba is shapes.set_actor_visual_rgba


def test_rest_heights(env):
    """Each shape released just above its rest z in its task orientation settles there."""
    for k, (name, actor) in enumerate(env.shape_actors.items()):
        z = shapes.SHAPE_REST_Z[name] + DROP
        actor.set_pose(sapien.Pose(p=[k * SPACING, 0, z], q=shapes.shape_orientation(name)))
        actor.set_linear_velocity(torch.zeros(1, 3))
        actor.set_angular_velocity(torch.zeros(1, 3))
    for _ in range(60):  # 0.6 s at the default 100 Hz sim rate
        env.scene.step()
    for name, actor in env.shape_actors.items():
        p = actor.pose.p[0].numpy()
        assert p[2] == pytest.approx(shapes.SHAPE_REST_Z[name], abs=1.5e-3), (name, p)
        # Flat shapes must not have tipped over (orientation still the task one).
        q = actor.pose.q[0].numpy()
        assert abs(np.dot(q, shapes.shape_orientation(name))) > 0.99, (name, q)
