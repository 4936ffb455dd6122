"""What a BunchOfColors / SeqOfColors / ChainOfColors PPO state policy does per episode:
how many of the shown cubes it touched (and at which steps), how many others, how far it moved a cube
(more than ``STRONG_DISPLACEMENT_XY``, 6 cm, and the button can no longer be pressed; the step at which one
first lay 2 cm off, where the reward starts to shrink, and which cube), how near the button it came once
the button could be pressed (the shown cubes and no other touched), how far from it it ended,
whether a press registered (the TCP low over the button while pressable), how high the TCP
ended against the height that confirms that press, and whether it was confirmed (success needs
exactly the shown cubes touched, then a confirmed press).

    python docs/lab-notes/rl-ppo-runs/diagnose_bunch_of_colors.py CKPT [--env-id BunchOfColors3-v0] [--episodes 8]
        [--sample [--min-logstd -1.6] [--first-seed 1000]]

CKPT: a ``ppo_memtasks.py`` state checkpoint (``ckpt_*.pt`` or ``final_ckpt.pt``). Deterministic
actions (``--sample``: sampled from the policy, as in training, torch seed 0; ``--min-logstd``
floors its log std first, to see whether more noise would find what the mean misses), dense
reward mode, seeds 100.. (not the canonical evaluation seeds). Prints one line per episode.
"""

from __future__ import annotations

import argparse

import torch
from mikasa_robo_rl.agents import flatten_state_obs, load_agent
from mikasa_robo_rl.vector_env import SubEnvSpec


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("checkpoint", help="a ppo_memtasks.py state checkpoint")
    parser.add_argument("--env-id", default="BunchOfColors3-v0", help="an RL colour-set id (default BunchOfColors3-v0)")
    parser.add_argument("--episodes", type=int, default=8, help="episodes (default 8)")
    parser.add_argument("--first-seed", type=int, default=100, help="the first episode's seed (default 100)")
    parser.add_argument("--sample", action="store_true", help="sample actions instead of taking the mean")
    parser.add_argument("--min-logstd", type=float, default=None, help="with --sample: floor the policy's log std")
    args = parser.parse_args()
    if args.min_logstd is not None and not args.sample:
        parser.error("--min-logstd changes only sampled actions: add --sample")
    agent = load_agent(args.checkpoint)
    if args.min_logstd is not None:
        agent.floor_logstd(args.min_logstd)
    torch.manual_seed(0)
    env = SubEnvSpec(args.env_id, mode="state", reward_mode="dense").make()
    base = env.unwrapped
    targets = base.true_color_indices.shape[1]
    for episode in range(args.episodes):
        obs, _ = env.reset(seed=args.first_seed + episode)
        pressed = False
        registered_at = confirm_at = None  # TCP heights: where a press registered, what confirms it
        pressable_from = None  # the first step at which the button could be pressed
        nearest_button = float("inf")  # xy, from then on (the TCP starts over the button)
        max_shove = 0.0  # the farthest any cube got from its layout point (xy; > 6 cm forbids the press)
        max_rise = 0.0  # the highest the TCP got above where a press registered (CONFIRM_LIFT confirms it)
        touch_steps: list[int] = []  # the steps at which a cube's touch registered
        push = None  # (step, which cube) at which a cube first lay more than CARE_FROM_DISPLACEMENT_XY off
        for step in range(base.spec.max_episode_steps or 120):
            with torch.no_grad():
                action = agent.get_action(flatten_state_obs(obs), deterministic=not args.sample)
            obs, _, _, truncated, info = env.step(action)
            correct, wrong = (int(count[0]) for count in base.touch_counts())  # as the reward counts them
            if bool(info["button_pressable"][0]):
                if pressable_from is None:
                    pressable_from = step
                nearest_button = min(nearest_button, float(info["xy_dist_to_button"][0]))
            pressed |= bool(info["button_pressed"][0])
            max_shove = max(max_shove, float(info["max_cube_displacement_xy"][0]))
            touched = base.touched_cubes[0]
            if int(touched.sum()) > len(touch_steps):
                touch_steps.append(step)
            if push is None and max_shove > base.CARE_FROM_DISPLACEMENT_XY:
                cube = int(base.cube_displacements_xy()[0].argmax())
                kind = "a target" if bool(base.sequence_cubes_mask[0, cube]) else "no target"
                push = (step, f"{kind}, {'touched' if bool(touched[cube]) else 'not touched'}")
            latch = base.press_latch
            if bool(latch.pending[0]) and registered_at is None:
                registered_at, confirm_at = float(latch.press_start_z[0]), float(latch.confirm_z[0])
            if registered_at is not None:
                max_rise = max(max_rise, float(base.agent.tcp.pose.p[0, 2]) - registered_at)
            if bool(truncated[0]):
                break
        button = (f"pressable from step {pressable_from}, nearest to the button (xy) {nearest_button:.3f} m"
                  if pressable_from is not None else "never pressable")
        tcp_z = float(base.agent.tcp.pose.p[0, 2])
        press = ("no press registered" if registered_at is None else
                 f"a press registered at z {registered_at:.3f}, confirmed from z {confirm_at:.3f}, "
                 f"the TCP up to {max_rise:.3f} m above it")
        care_cm = round(base.CARE_FROM_DISPLACEMENT_XY * 100)
        pushed = f" (past {care_cm} cm at step {push[0]}: {push[1]})" if push is not None else ""
        print(f"episode {episode}: correct touches {correct}/{targets}, wrong touches {wrong}, "
              f"touches at steps {touch_steps}, a cube moved up to {max_shove:.3f} m{pushed}, {button}, "
              f"at the end {float(info['xy_dist_to_button'][0]):.3f} m from it (xy) at z {tcp_z:.3f}, {press}, "
              f"pressed {pressed}")
    env.close()


if __name__ == "__main__":
    main()
