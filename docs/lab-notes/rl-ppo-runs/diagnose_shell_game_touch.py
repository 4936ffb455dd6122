"""What a ShellGameTouch PPO state policy does per episode: whether it came within the 8 cm of
the ball mug that success needs (and first at which step), how close to the mug's centre it came,
how near the nearest *other* mug (a wrong choice), how far it shoved any mug (past 5 cm ends
success for the episode), its return and whether it succeeded.

    python docs/lab-notes/rl-ppo-runs/diagnose_shell_game_touch.py CKPT [--env-id ShellGameTouch-VLA-v0] [--episodes 24]

CKPT: a ``ppo_memtasks.py`` state checkpoint (``ckpt_*.pt`` or ``final_ckpt.pt``). Deterministic
actions, upstream's ``normalized_dense`` reward, seeds 100.. (not the canonical evaluation
seeds). Prints one line per episode, then the shares.
"""

from __future__ import annotations

import argparse

import torch
from mikasa_robo_rl.agents import flatten_state_obs, load_agent
from mikasa_robo_rl.vector_env import SubEnvSpec

PUSH_LIMIT = 0.05  # the mug displacement that ends success (TouchMugMixin.MUG_DISPLACEMENT_SUCCESS_THRESH)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("checkpoint", help="a ppo_memtasks.py state checkpoint")
    parser.add_argument("--env-id", default="ShellGameTouch-VLA-v0", help="a ShellGameTouch id (default ShellGameTouch-VLA-v0)")
    parser.add_argument("--episodes", type=int, default=24, help="episodes (default 24)")
    args = parser.parse_args()
    agent = load_agent(args.checkpoint)
    env = SubEnvSpec(args.env_id, mode="state").make()
    base = env.unwrapped
    totals = {"success": 0, "placed": 0, "pushed": 0, "return": 0.0}
    for episode in range(args.episodes):
        obs, info = env.reset(seed=100 + episode)
        success = False
        first_placed = None
        closest = nearest_other = float("inf")
        shove = episode_return = 0.0
        for step in range(base.spec.max_episode_steps or 30):
            with torch.no_grad():
                obs, reward, _, _, info = env.step(agent.get_action(flatten_state_obs(obs), deterministic=True))
            episode_return += float(reward)
            success |= bool(info["success"])
            if not bool(base.in_action_phase()[0]):
                continue
            closest = min(closest, float(torch.linalg.norm(info["obj_to_goal_pos"])))
            if bool(info["is_obj_placed"]) and first_placed is None:
                first_placed = step
            shove = max(shove, float(info["mug_max_displacement"]))
            tcp, mugs, answer = base.agent.tcp.pose.p[0], base.mug_positions()[0], int(base.cup_with_ball_number[0])
            others = [float(torch.linalg.norm(mugs[k] - tcp)) for k in range(len(mugs)) if k != answer]
            nearest_other = min(nearest_other, *others)
        totals["success"] += success
        totals["placed"] += first_placed is not None
        totals["pushed"] += shove > PUSH_LIMIT
        totals["return"] += episode_return
        print(f"seed {100 + episode}: success {int(success)}, within 8 cm from step {first_placed}, "
              f"closest {closest:.3f} m, nearest other mug {nearest_other:.3f} m, "
              f"largest mug shove {shove:.3f} m, return {episode_return:.2f}", flush=True)
    n = args.episodes
    print(f"success {totals['success']}/{n}, within 8 cm {totals['placed']}/{n}, "
          f"shoved > {PUSH_LIMIT} m {totals['pushed']}/{n}, mean return {totals['return'] / n:.2f}")


if __name__ == "__main__":
    main()
