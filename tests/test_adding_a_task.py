"""A family written outside the packages (tests/example_family: its env file and its oracle,
nothing else) works through every door: gym.make, the wrapper chain, ``mikasa-bench run``,
``mikasa-collect`` and ``mikasa-bench gallery``. The walk-through is docs/contributing/adding-a-task.md.

The family registers through the entry-point groups ``mikasa_envs.tasks`` and
``mikasa_oracles.families``, here from a distribution's metadata on PYTHONPATH, as an
installed package's would. Everything runs in subprocesses so that the 91st canonical id
never enters this test process's registry.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

EXAMPLE = Path(__file__).parent / "example_family"
TASK = "RememberCubePair-VLA-v0"
BIN = Path(sys.executable).parent


@pytest.fixture(scope="module")
def plugin_env(tmp_path_factory) -> dict[str, str]:
    """Environment variables under which the example family is an installed plugin."""
    site = tmp_path_factory.mktemp("site")
    dist_info = site / "remember_cube_pair-0.1.dist-info"
    dist_info.mkdir()
    (dist_info / "METADATA").write_text("Metadata-Version: 2.1\nName: remember-cube-pair\nVersion: 0.1\n")
    (dist_info / "entry_points.txt").write_text(
        "[mikasa_envs.tasks]\nremember_cube_pair = remember_cube_pair\n\n"
        "[mikasa_oracles.families]\nremember_cube_pair = remember_cube_pair_oracle\n"
    )
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join(filter(None, [str(EXAMPLE), str(site), env.get("PYTHONPATH")]))
    return env


def _run(args: list[str], env: dict[str, str], cwd: Path) -> str:
    done = subprocess.run(args, env=env, cwd=cwd, capture_output=True, text=True, timeout=900)
    assert done.returncode == 0, f"{args} failed:\n{done.stdout[-3000:]}\n{done.stderr[-3000:]}"
    return done.stdout


MAKE_AND_WRAP = f"""
import json, gymnasium as gym, mikasa_envs, mikasa_wrappers
from mikasa_envs.family import task_chance
from mikasa_oracles import make_oracle, rollout
spec = mikasa_envs.get_task("{TASK}")
env = gym.make("{TASK}", obs_mode="rgb", control_mode="pd_ee_delta_pose", sim_backend="physx_cpu",
               render_backend="cpu")
wrapped = mikasa_wrappers.apply_mikasa_vla_wrappers(env, include_overlays=True)
obs, _ = wrapped.reset(seed=0)
state_env = gym.make("{TASK}", obs_mode="state", control_mode="pd_ee_delta_pose",
                     sim_backend="physx_cpu", render_backend="cpu")
print(json.dumps(dict(
    canonical=spec.canonical, split=spec.split, family=spec.family,
    in_manifest="{TASK}" in mikasa_envs.canonical_env_ids(),
    chance=task_chance("{TASK}").rate,
    obs_keys=sorted(obs), rgb_shape=list(obs["rgb"].shape),
    curriculum=type(mikasa_wrappers.VLA_WRAPPER_CONFIGS["{TASK}"].curriculum_wrapper).__name__,
    oracle=[rollout(state_env, make_oracle(state_env), seed=s).success_once for s in range(2)],
    memoryless=type(make_oracle(state_env, memoryless=True)).__name__,
)))
"""


def test_the_example_family_goes_through_every_door(plugin_env, tmp_path):
    info = json.loads(_run([sys.executable, "-c", MAKE_AND_WRAP], plugin_env, tmp_path).splitlines()[-1])
    assert info["canonical"] and info["split"] == "short" and info["in_manifest"]
    assert info["family"] == "remember_cube_pair" and info["chance"] == 0.5
    assert info["obs_keys"] == ["proprio", "rgb"] and info["rgb_shape"][-3:] == [128, 128, 6]
    assert info["oracle"] == [True, True]
    assert info["memoryless"] != "SelectionOracle"

    # The benchmark, in state mode with the oracle: every episode succeeds.
    _run([str(BIN / "mikasa-bench"), "run", "--task", TASK, "--policy", "oracle", "--num-episodes", "2",
          "--obs-mode", "state", "--workers", "1", "--out", "run", "--no-progress"], plugin_env, tmp_path)
    results = json.loads((tmp_path / "run" / f"{TASK}.json").read_text())
    assert results["sr"] == 1.0 and results["n_episodes"] == 2 and results["split"] == "Short"

    # Demonstrations: two NPZ episodes.
    _run([str(BIN / "mikasa-collect"), "--env-id", TASK, "--num-episodes", "2", "--out", "data",
          "--no-progress"], plugin_env, tmp_path)
    episodes = sorted((tmp_path / "data" / "data_npz").rglob("train_data_*.npz"))
    assert len(episodes) == 2
    with np.load(episodes[0]) as episode:
        assert episode["rgb"].shape[-3:] == (128, 128, 6) and episode["success"][-1]

    # The gallery: one animation and its index entry.
    _run([str(BIN / "mikasa-bench"), "gallery", "--task", TASK, "--max-frames", "10", "gallery"],
         plugin_env, tmp_path)
    assert (tmp_path / "gallery" / "tasks" / f"{TASK}.webp").stat().st_size > 0
    assert TASK in (tmp_path / "gallery" / "gallery.json").read_text()
