"""LeRobot policies in mikasa-bench: ``mikasa-bench run --policy lerobot:DIR``
and ``lerobot-eval --env.type=mikasa`` (mikasa_bench.lerobot.policy, mikasa_bench.lerobot.env).

Needs lerobot 0.4.x next to the MIKASA envs: in the main environment this file contributes
one test that runs it inside `.venv-datasets` (see tests/test_validate.py for the
mechanism), plus the checks that need no lerobot (clear errors without it). Inside, a tiny
randomly initialised ACT policy (no pretrained backbone) is built and saved with
``save_pretrained`` and its processors by the tests themselves.
"""

from __future__ import annotations

import importlib.util
import json
import math
import os
import sys
from pathlib import Path

import pytest

IN_LEROBOT_ENV = all(
    importlib.util.find_spec(m) is not None for m in ("lerobot", "mikasa_bench", "mani_skill")
)
TASK = "RememberColor3-VLA-v0"
SEED = 4242424242  # the protocol's START_SEED: episode 0 of the benchmark

if not IN_LEROBOT_ENV:
    from mikasa_bench import cli
    from mikasa_bench.errors import BenchError
    from mikasa_bench.policies import is_lerobot_target, resolve_policy
    from test_validate import run_plain_in_datasets_env, run_suite_in_datasets_env

    def test_lerobot_policy_suite_in_datasets_env() -> None:
        """Every test of the lerobot branch below, run inside `.venv-datasets`."""
        run_suite_in_datasets_env(__file__)

    @pytest.mark.parametrize(
        "argv",
        [
            ["lerobot-train", "--help"],
            ["lerobot-eval", "--help"],
            [
                "lerobot-eval",
                "--env.discover_packages_path=mikasa_bench.lerobot.env",
                "--env.type=mikasa",
                "--help",
            ],
        ],
        ids=["train", "eval", "eval-mikasa"],
    )
    def test_plain_lerobot_scripts_start_in_datasets_env(tmp_path: Path, argv: list[str]) -> None:
        """lerobot's own console scripts in `.venv-datasets`, with no project wrapper: they
        import torchvision (PyPI's CUDA build beside the CPU torch) through the environment's
        start-up hook, and lerobot-eval finds the ``mikasa`` env type."""
        proc = run_plain_in_datasets_env(*argv, cwd=tmp_path)
        assert proc.returncode == 0, proc.stderr[-3000:]
        assert proc.stdout.startswith(f"usage: {argv[0]} ")
        if "--env.type=mikasa" in argv:
            assert "--env.task" in proc.stdout and ",mikasa}" in proc.stdout

    def test_lerobot_target_errors_without_lerobot(tmp_path: Path, capsys) -> None:
        """Without lerobot: a missing directory or missing files are named; a complete
        directory fails with the install command; the CLI exits with 2."""
        assert is_lerobot_target("lerobot:/x") and not is_lerobot_target("ws://h:1")
        with pytest.raises(BenchError, match="does not exist"):
            resolve_policy(f"lerobot:{tmp_path / 'nope'}")
        (tmp_path / "config.json").write_text("{}")
        with pytest.raises(BenchError, match="lacks model.safetensors, policy_preprocessor.json"):
            resolve_policy(f"lerobot:{tmp_path}")
        for name in ("model.safetensors", "policy_preprocessor.json", "policy_postprocessor.json"):
            (tmp_path / name).write_text("{}")
        hint = r"need lerobot 0\.4\.x.*pip install 'mikasa-bench\[lerobot\]'"
        with pytest.raises(BenchError, match=hint):
            resolve_policy(f"lerobot:{tmp_path}")
        argv = [
            "run",
            "--task",
            TASK,
            "--policy",
            f"lerobot:{tmp_path}",
            "--out",
            str(tmp_path / "r"),
        ]
        assert cli.main(argv) == 2
        assert "lerobot" in capsys.readouterr().err

else:
    os.environ.setdefault("OMP_NUM_THREADS", "1")
    os.environ.setdefault("HF_HUB_OFFLINE", "1")
    from mikasa_bench.lerobot.policy import import_lerobot

    import_lerobot()  # torchvision made importable before lerobot's modules below

    import mikasa_envs
    import torch
    from lerobot.configs.types import FeatureType, PolicyFeature
    from lerobot.policies.act.configuration_act import ACTConfig
    from lerobot.policies.act.modeling_act import ACTPolicy
    from lerobot.policies.factory import make_pre_post_processors
    from mikasa_bench import cli
    from mikasa_bench.errors import BenchError
    from mikasa_bench.lerobot.policy import (
        STATE_KEY,
        TOP_KEY,
        WRIST_KEY,
        LeRobotPolicy,
        observation_to_lerobot,
    )
    from mikasa_bench.policies import resolve_policy

    torch.set_num_threads(1)  # 2 shared cores; tiny model

    VISUAL_128 = PolicyFeature(FeatureType.VISUAL, (3, 128, 128))

    def save_tiny_act(
        out: Path,
        inputs: dict[str, PolicyFeature] | None = None,
        action_dim: int = 7,
    ) -> Path:
        """A randomly initialised ACT (ResNet-18 without pretrained weights, a 1+1-layer
        transformer of width 32, chunks of 5) saved as lerobot-train saves a checkpoint."""
        inputs = inputs or {
            TOP_KEY: VISUAL_128,
            WRIST_KEY: VISUAL_128,
            STATE_KEY: PolicyFeature(FeatureType.STATE, (7,)),
        }
        outputs = {"action": PolicyFeature(FeatureType.ACTION, (action_dim,))}
        config = ACTConfig(
            input_features=inputs,
            output_features=outputs,
            device="cpu",
            pretrained_backbone_weights=None,
            dim_model=32,
            n_heads=2,
            dim_feedforward=64,
            n_encoder_layers=1,
            n_decoder_layers=1,
            use_vae=False,
            chunk_size=5,
            n_action_steps=5,
        )
        torch.manual_seed(0)
        policy = ACTPolicy(config)
        stats = {
            key: (
                {"mean": torch.full((3, 1, 1), 0.5), "std": torch.full((3, 1, 1), 0.25)}
                if ft.type is FeatureType.VISUAL
                else {"mean": torch.zeros(ft.shape), "std": torch.ones(ft.shape)}
            )
            for key, ft in {**inputs, **outputs}.items()
        }
        pre, post = make_pre_post_processors(config, dataset_stats=stats)
        for obj in (policy, pre, post):
            obj.save_pretrained(out)
        return out

    @pytest.fixture(scope="module")
    def act_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
        return save_tiny_act(tmp_path_factory.mktemp("act") / "pretrained_model")

    @pytest.fixture(scope="module")
    def bench_run(act_dir: Path, tmp_path_factory: pytest.TempPathFactory) -> dict:
        """``mikasa-bench run --policy lerobot:DIR`` on one task, one episode (rgb)."""
        out = tmp_path_factory.mktemp("bench") / "run"
        argv = ["run", "--task", TASK, "--policy", f"lerobot:{act_dir}", "--num-episodes", "1"]
        argv += ["--workers", "0", "--no-progress", "--no-report", "--out", str(out)]
        argv += ["--policy-kwargs", json.dumps({"device": "cpu"})]
        assert cli.main(argv) == 0
        return json.loads((out / f"{TASK}.json").read_text())

    @pytest.fixture(scope="module")
    def eval_run(act_dir: Path, tmp_path_factory: pytest.TempPathFactory) -> dict:
        """lerobot-eval's CLI (``python -m mikasa_bench.lerobot.env``'s main, in this process
        to spare a second start-up of torch/lerobot/SAPIEN), with lerobot's plugin discovery
        flag, on the same task and the benchmark's first seed, one episode."""
        from mikasa_bench.lerobot.env import main

        out = tmp_path_factory.mktemp("eval") / "out"
        argv = ["lerobot-eval", "--env.discover_packages_path=mikasa_bench.lerobot.env"]
        argv += ["--env.type=mikasa", f"--env.task={TASK}", f"--policy.path={act_dir}"]
        argv += ["--policy.device=cpu", "--eval.n_episodes=1", "--eval.batch_size=1"]
        argv += [f"--seed={SEED}", f"--output_dir={out}"]
        with pytest.MonkeyPatch.context() as mp:
            mp.setattr(sys, "argv", argv)  # lerobot's draccus parser reads sys.argv
            main()
        return json.loads((out / "eval_info.json").read_text())

    # ---------------------------------------------------------------------------- bench
    def test_bench_runs_a_lerobot_policy(bench_run: dict, act_dir: Path) -> None:
        assert bench_run["n_episodes"] == 1 and bench_run["episode_seeds"] == [SEED]
        assert bench_run["episode_lengths"] == [mikasa_envs.get_task(TASK).max_episode_steps]
        assert math.isfinite(bench_run["returns"][0])
        assert bench_run["action_chunk_size"] == 1  # the policy queues its own chunk
        model = bench_run["model"]
        assert model["target"] == f"lerobot:{act_dir}" and model["config"] == {"device": "cpu"}
        assert model["name"].startswith("lerobot-act-")

    def test_lerobot_eval_runs_a_mikasa_task(eval_run: dict) -> None:
        overall = eval_run["overall"]
        assert overall["n_episodes"] == 1 and math.isfinite(overall["avg_sum_reward"])
        assert eval_run["per_task"][0]["task_group"] == "mikasa"
        assert all(Path(p).is_file() for p in overall["video_paths"])  # lerobot-eval's videos

    def test_bench_and_lerobot_eval_agree(bench_run: dict, eval_run: dict) -> None:
        """The same deterministic policy on the same seed: both paths feed it the same
        observations (mapping, instruction) and step the same env, so the returns match."""
        per_episode = eval_run["per_task"][0]["metrics"]
        assert per_episode["sum_rewards"][0] == pytest.approx(bench_run["returns"][0], abs=1e-9)
        assert bool(per_episode["successes"][0]) == bool(bench_run["successes"][0])

    def test_policy_interface_and_reset(act_dir: Path) -> None:
        """chunk_size 1, one (7,) action per call from the policy's own queue, instruction
        from the manifest, reset() empties the queue."""
        policy = LeRobotPolicy(act_dir, env_id=TASK, device="cpu")
        assert policy.chunk_size == 1
        assert policy.instruction == mikasa_envs.get_task(TASK).language_instruction
        g = torch.Generator().manual_seed(0)
        obs = {
            "rgb": torch.randint(0, 256, (1, 128, 128, 6), dtype=torch.uint8, generator=g),
            "proprio": torch.randn(1, 7, generator=g),
        }
        policy.reset()
        first = policy.forward(obs)
        assert first.shape == (7,) and first.dtype == torch.float32
        assert len(policy.policy._action_queue) == 4  # ACT: 5 actions per chunk, 1 used
        policy.reset()
        assert len(policy.policy._action_queue) == 0
        assert torch.equal(policy.forward(obs), first)  # same obs after reset: same action

        batch = observation_to_lerobot(obs, "go")
        assert batch["task"] == ["go"]
        rgb = obs["rgb"][0].permute(2, 0, 1).float() / 255
        assert torch.equal(batch[TOP_KEY][0], rgb[0:3]) and torch.equal(
            batch[WRIST_KEY][0], rgb[3:6]
        )
        assert torch.equal(batch[STATE_KEY], obs["proprio"])
        with pytest.raises(BenchError, match="--obs-mode rgb"):
            policy.forward({"state": torch.zeros(1, 35), "proprio": obs["proprio"]})

    def test_forward_batch_gives_each_env_its_action(act_dir: Path) -> None:
        """B observations in one call: row i is what forward gives observation i alone
        (a deterministic policy), and the queue holds the rest of every env's chunk."""
        policy = LeRobotPolicy(act_dir, env_id=TASK, device="cpu")
        g = torch.Generator().manual_seed(1)
        batch = [
            {
                "rgb": torch.randint(0, 256, (1, 128, 128, 6), dtype=torch.uint8, generator=g),
                "proprio": torch.randn(1, 7, generator=g),
            }
            for _ in range(3)
        ]
        policy.reset()
        actions = policy.forward_batch(batch)
        assert actions.shape == (3, 7) and actions.dtype == torch.float32
        assert len(policy.policy._action_queue) == 4 and policy.policy._action_queue[0].shape == (3, 7)
        for obs, row in zip(batch, actions, strict=True):
            policy.reset()
            assert torch.allclose(policy.forward(obs), row, atol=1e-5)

    def test_bench_runs_a_lerobot_policy_in_lockstep(
        act_dir: Path, bench_run: dict, tmp_path: Path
    ) -> None:
        """``--policy-batch`` (one env here: the first episode is a round of its own): the
        same episode as the one-at-a-time run."""
        out = tmp_path / "run"
        argv = ["run", "--task", TASK, "--policy", f"lerobot:{act_dir}", "--num-episodes", "1"]
        argv += ["--policy-batch", "4", "--no-progress", "--no-report", "--out", str(out)]
        argv += ["--policy-kwargs", json.dumps({"device": "cpu"})]
        assert cli.main(argv) == 0
        result = json.loads((out / f"{TASK}.json").read_text())
        assert result["returns"] == pytest.approx(bench_run["returns"], abs=1e-6)
        assert result["successes"] == bench_run["successes"]

    def test_mismatched_features_name_both_sides(tmp_path: Path, capsys) -> None:
        d = save_tiny_act(
            tmp_path / "pretrained_model",
            inputs={
                TOP_KEY: PolicyFeature(FeatureType.VISUAL, (3, 96, 96)),
                STATE_KEY: PolicyFeature(FeatureType.STATE, (8,)),
                "observation.environment_state": PolicyFeature(FeatureType.ENV, (4,)),
            },
            action_dim=6,
        )
        with pytest.raises(BenchError) as info:
            resolve_policy(f"lerobot:{d}")
        message = str(info.value)
        for fragment in (
            "input 'observation.images.top': the policy expects VISUAL (3, 96, 96), MIKASA gives VISUAL (3, 128, 128)",
            "input 'observation.state': the policy expects STATE (8,), MIKASA gives STATE (7,)",
            "input 'observation.environment_state' (ENV (4,)) is not provided",
            "output 'action': the policy gives ACTION (6,), MIKASA takes ACTION (7,)",
            "MIKASA provides {observation.images.top: VISUAL (3, 128, 128), "
            "observation.images.wrist: VISUAL (3, 128, 128), observation.state: STATE (7,)}",
        ):
            assert fragment in message, f"{fragment!r} not in {message!r}"
        argv = ["run", "--task", TASK, "--policy", f"lerobot:{d}", "--out", str(tmp_path / "r")]
        assert cli.main(argv) == 2  # before any worker starts, results dir untouched
        assert "observation.environment_state" in capsys.readouterr().err
        assert not (tmp_path / "r").exists()
        with pytest.raises(BenchError, match="accepts only 'device'"):
            resolve_policy(f"lerobot:{d}", {"ckpt": "x"})

        from mikasa_bench.lerobot.env import main  # lerobot-eval's entry: the same check

        argv = ["lerobot-eval", "--env.type=mikasa", f"--policy.path={d}", "--eval.n_episodes=1"]
        with pytest.MonkeyPatch.context() as mp, pytest.raises(SystemExit) as exit_info:
            mp.setattr(sys, "argv", argv)
            main()
        assert exit_info.value.code == 2
        assert "output 'action': the policy gives ACTION (6,)" in capsys.readouterr().err
