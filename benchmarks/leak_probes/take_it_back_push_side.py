"""Leak probe for TakeItBack: does the frame in which the target switches show where the cube
started? The oracle pushes the cube from its start onto the target; at the switch the cube
and the gripper rest on the side of the target that faces the start, so their offset from
the target's centre may tell the start row (y = 0.1·j + jitter, j in {-1, 0, 1}) without
memory.

    python benchmarks/leak_probes/take_it_back_push_side.py --seeds 24

Prints, per start row, the range of the cube's and the TCP's y offset from the target at
the switch (state obs, the oracle's pushes). Rows whose ranges do not overlap can be told
apart from that one frame. 2-core CPU machine, 24 seeds, before the handover (DEVIATIONS.md,
Fixed #29): TCP dy row -1 -0.032..-0.016, row 0 -0.001..+0.019, row +1 +0.015..+0.041 (cube
dy -0.021..-0.010, -0.003..+0.017, +0.002..+0.022). With it (the cube set down at the
target's near edge, the arm at its rest pose): cube dy +0.000 in every row, TCP dy
-0.016..+0.024, -0.014..+0.024, -0.013..+0.025 (the rest pose's y against the target's own
draw): the rows overlap.
"""

from __future__ import annotations

import argparse

import gymnasium as gym
import mikasa_envs  # noqa: F401  (registers the tasks)
import numpy as np
from mikasa_oracles import make_oracle
from mikasa_oracles.rollout import reset_with_seed

ENV_ID = "TakeItBack-VLA-v0"


def offsets_at_switch(seed: int, env: gym.Env, max_steps: int = 200) -> tuple[int, float, float, int] | None:
    """(start row, cube dy, TCP dy, step) when the target switches, or None if it never does."""
    obs, _ = env.reset(seed=seed)
    oracle = make_oracle(env)
    reset_with_seed(oracle, seed)
    base = env.unwrapped
    start = base.initial_pos[0, :2].cpu().numpy().copy()
    goal = base.goal_pos[0, :2].cpu().numpy().copy()
    row = int(round((start[1] - base.START_Y_JITTER / 2) / base.START_Y_STEP))
    for step in range(max_steps):
        obs, *_ = env.step(oracle.forward(obs))
        if bool(base.goal_achieved[0]):
            cube = base.cube.pose.p[0, :2].cpu().numpy()
            tcp = base.agent.tcp.pose.p[0, :2].cpu().numpy()
            return row, float(cube[1] - goal[1]), float(tcp[1] - goal[1]), step
    return None


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seeds", type=int, default=24, help="episodes (seeds 0..N-1, default 24)")
    args = parser.parse_args()
    env = gym.make(ENV_ID, obs_mode="state_dict", control_mode="pd_ee_delta_pose")
    rows = [r for seed in range(args.seeds) if (r := offsets_at_switch(seed, env)) is not None]
    table = np.array(rows)
    for j in (-1, 0, 1):
        sel = table[table[:, 0] == j]
        if len(sel) == 0:
            continue
        print(
            f"row {j:+d}: {len(sel)} episodes; cube dy {sel[:, 1].min():+.3f}..{sel[:, 1].max():+.3f}, "
            f"TCP dy {sel[:, 2].min():+.3f}..{sel[:, 2].max():+.3f}, switch at step "
            f"{sel[:, 3].min():.0f}-{sel[:, 3].max():.0f}"
        )
    env.close()


if __name__ == "__main__":
    main()
