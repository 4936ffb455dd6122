"""The PPO baselines' batched CPU env and the PPO-MLP trainer (tiny runs)."""

from __future__ import annotations

import dataclasses
import importlib.util
import sys
from pathlib import Path

import pytest
import torch
from mikasa_robo_rl.agents import AgentStateOnly
from mikasa_robo_rl.ppo import observation_mode, parse_args
from mikasa_robo_rl.vector_env import CpuVectorEnv, SubEnvSpec
from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

ROOT = Path(__file__).resolve().parents[1]
ENV_ID = "RememberColor3-v0"  # horizon 60
LAB_NOTES = "docs/lab-notes/rl-ppo-runs"  # the run files and diagnosis scripts of the PPO runs


def _load_script(name: str = "ppo_memtasks", folder: str = "legacy/rl/baselines/ppo"):
    """The script ``<folder>/<name>.py`` (by default a PPO trainer) as a module."""
    path = ROOT / folder / f"{name}.py"
    spec = importlib.util.spec_from_file_location(name, path)
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module  # dataclasses look their module up while building Args
    spec.loader.exec_module(module)
    return module


@pytest.fixture(scope="module")
def ppo():
    return _load_script()


@pytest.fixture(scope="module")
def ppo_lstm():
    return _load_script("ppo_memtasks_lstm")


def _mode(args) -> str:
    """The observation mode a trainer's parsed flags ask for."""
    return observation_mode(include_state=args.include_state, include_rgb=args.include_rgb,
                            include_joints=args.include_joints, include_oracle=args.include_oracle)


def _rollout(env: CpuVectorEnv, steps: int) -> tuple[dict, list[dict]]:
    first, _ = env.reset(seed=5)
    finals = []
    for _ in range(steps):
        _, reward, terminated, truncated, info = env.step(torch.full((env.num_envs, 8), 0.3))
        assert reward.shape == (env.num_envs,) and reward.dtype == torch.float32
        assert terminated.dtype == torch.bool and not terminated.any()  # ignore_terminations
        if "final_info" in info:
            finals.append({k: v.clone() for k, v in info["final_info"]["episode"].items()})
            finals[-1]["final_state"] = info["final_observation"]["state"].clone()
            assert info["_final_info"].all() and truncated.all()
            assert info["final_observation"]["state"].shape == (env.num_envs, 35)
    return first, finals


def test_vector_env_batches_sub_envs_and_matches_across_worker_counts():
    spec = SubEnvSpec(ENV_ID)
    with CpuVectorEnv(spec, 3, workers=0) as inline:
        assert inline.max_episode_steps == 60 and inline.single_action_space.shape == (8,)
        first_inline, finals_inline = _rollout(inline, 180)
    with CpuVectorEnv(spec, 3, workers=2) as pooled:
        first_pooled, finals_pooled = _rollout(pooled, 180)
    # The observations through shared memory instead of the queues, the three sub-envs of
    # one worker stepped in threads of their own: the same batches.
    with CpuVectorEnv(spec, 3, workers=1, shared_memory=True, render_together=True) as shared:
        first_shared, finals_shared = _rollout(shared, 180)
    assert first_inline["state"].shape == (3, 35) and first_inline["state"].dtype == torch.float32
    assert torch.equal(first_inline["state"], first_pooled["state"])
    assert torch.equal(first_inline["state"], first_shared["state"])
    # Three episodes each, the auto-reset ones too, identical however the sub-envs are spread.
    assert len(finals_inline) == len(finals_pooled) == len(finals_shared) == 3
    for inline_final, pooled_final, shared_final in zip(finals_inline, finals_pooled, finals_shared, strict=True):
        for key in ("success_once", "return", "episode_len", "final_state"):
            assert torch.equal(inline_final[key], pooled_final[key])
            assert torch.equal(inline_final[key], shared_final[key])
    assert finals_inline[0]["episode_len"].tolist() == [60, 60, 60]


@pytest.mark.parametrize("env_id, divisor", [(ENV_ID, 3.0), ("BunchOfColors3-v0", 100.0)])
def test_trainers_normalized_dense_is_upstreams_unclipped_dense_over_its_divisor(env_id, divisor):
    # RememberColor3's divisor is its success reward; BunchOfColors3's is the release's 100,
    # against a success reward of 400.
    rewards = {}
    for mode in ("normalized_dense", "dense"):
        with CpuVectorEnv(SubEnvSpec(env_id, reward_mode=mode), 2, workers=0) as env:
            env.reset(seed=3)
            generator = torch.Generator().manual_seed(0)
            rewards[mode] = torch.stack(
                [env.step(torch.rand(2, 8, generator=generator) * 2 - 1)[1] for _ in range(20)]
            )
    torch.testing.assert_close(rewards["normalized_dense"], rewards["dense"] / divisor)
    if env_id == ENV_ID:  # random actions' smoothness penalty outweighs the rest: below the envs' [0, 1] clip
        assert (rewards["normalized_dense"] < 0).any()


def test_vector_env_rejects_bad_actions():
    with CpuVectorEnv(SubEnvSpec(ENV_ID), 2, workers=0) as env:
        env.reset(seed=0)
        with pytest.raises(ValueError, match="shape"):
            env.step(torch.zeros(3, 8))
        with pytest.raises(ValueError, match="NaN"):
            env.step(torch.full((2, 8), float("nan")))


def test_vector_env_names_unknown_ids():
    with pytest.raises(ValueError, match="Unknown environment"):
        CpuVectorEnv(SubEnvSpec("RememberColour3-v0"), 1, workers=0)


@pytest.mark.parametrize(
    "flags, mode",
    [
        (["--include-state"], "state"),
        (["--include-rgb"], "rgb"),
        (["--include-rgb", "--include-oracle"], "rgb_oracle"),
        (["--include_rgb", "--include_joints"], "rgb_joints"),
        (["--include-rgb", "--include-joints", "--include-oracle"], "rgb_joints_oracle"),
    ],
)
def test_mode_resolution(ppo, flags, mode):
    assert _mode(parse_args(ppo.Args, ["--env_id=X-v0", *flags])) == mode


@pytest.mark.parametrize(
    "flags, error",
    [
        ([], ValueError),
        (["--include-joints", "--include-state"], ValueError),
        (["--include-state", "--include-rgb"], NotImplementedError),
        (["--include-state", "--include-oracle"], NotImplementedError),
    ],
)
def test_mode_errors(ppo, flags, error):
    with pytest.raises(error):
        _mode(parse_args(ppo.Args, flags))


def test_the_lstm_trainer_takes_the_mlp_trainers_flags_and_its_own(ppo, ppo_lstm):
    # Each trainer declares its flags; the shared ones must not drift apart (names and defaults).
    mlp = {f.name: f.default for f in dataclasses.fields(ppo.Args)}
    lstm = {f.name: f.default for f in dataclasses.fields(ppo_lstm.Args)}
    assert lstm == mlp | {"lstm_hidden_size": 512, "lstm_num_layers": 1, "lstm_dropout": 0.0}


def test_underscore_and_dash_spellings_agree(ppo):
    a = parse_args(ppo.Args, ["--env_id=RememberColor3-v0", "--total_timesteps=100", "--num_eval_steps", "5"])
    b = parse_args(ppo.Args, ["--env-id", "RememberColor3-v0", "--total-timesteps", "100", "--num-eval-steps=5"])
    assert a == b and a.total_timesteps == 100 and a.num_eval_steps == 5


TINY = ["--num-envs", "2", "--num-eval-envs", "1", "--num-steps", "8", "--num-eval-steps", "8",
        "--total-timesteps", "32", "--num-minibatches", "2", "--num-workers", "0", "--no-capture-video"]


def test_state_trainer_runs_two_iterations_and_reloads_its_checkpoint(ppo, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    ppo.main(["--env-id", ENV_ID, "--include-state", *TINY, "--initial-logstd", "-2"])
    assert sorted(p.name for p in tmp_path.rglob("*.pt")) == ["ckpt_0_1.pt", "final_ckpt.pt", "resume.pt"]
    logstd = torch.load(next(tmp_path.rglob("final_ckpt.pt")), weights_only=True)["actor_logstd"]
    assert logstd.shape == (1, 8) and torch.allclose(logstd, torch.full_like(logstd, -2.0), atol=0.05)
    (events,) = tmp_path.rglob("events.out.tfevents.*")
    logged = EventAccumulator(str(events)).Reload().Tags()["scalars"]
    assert {"losses/value_loss", "losses/actor_grad_norm", "losses/critic_grad_norm"} <= set(logged)
    result = ppo.main(["--env-id", ENV_ID, "--include-state", *TINY, "--evaluate", "--checkpoint",
                       str(next(tmp_path.rglob("final_ckpt.pt")))])
    assert result["episodes"] == 0 and "success_once" not in result  # 8 steps < the horizon


def test_rgb_joints_trainer_runs_two_iterations(ppo, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    ppo.main(["--env-id", ENV_ID, "--include-rgb", "--include-joints", *TINY])
    state = torch.load(next(tmp_path.rglob("final_ckpt.pt")), weights_only=True)
    assert state["feature_net.extractors.rgb.1.0.weight"].shape == (256, 9216)
    assert state["feature_net.extractors.proprio.0.weight"].shape == (128, 25)


def test_lstm_trainer_runs_two_iterations_in_rgb_joints(ppo_lstm, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    ppo_lstm.main(["--env-id", ENV_ID, "--include-rgb", "--include-joints", *TINY, "--lstm-hidden-size", "32",
                   "--initial-logstd", "-1.5"])
    state = torch.load(next(tmp_path.rglob("final_ckpt.pt")), weights_only=True)
    assert torch.allclose(state["actor_logstd"], torch.full((1, 8), -1.5), atol=0.05)
    assert state["lstm.weight_hh_l0"].shape == (4 * 32, 32)
    assert state["feature_net.extractors.proprio.0.weight"].shape == (256, 25)  # 256 wide in the LSTM script
    # --evaluate reloads it with the default --num-minibatches (32), which no single env divides.
    at = TINY.index("--num-minibatches")
    tiny_eval = TINY[:at] + TINY[at + 2:]
    result = ppo_lstm.main(["--env-id", ENV_ID, "--include-rgb", "--include-joints", *tiny_eval,
                            "--lstm-hidden-size", "32", "--evaluate", "--checkpoint",
                            str(next(tmp_path.rglob("final_ckpt.pt")))])
    assert result["episodes"] == 0  # 8 steps < the horizon


@pytest.mark.parametrize(
    "flags, error, match",
    [
        (["--include-state"], NotImplementedError, "image observations"),
        (["--include-rgb", "--num-envs", "3", "--num-minibatches", "2"], ValueError, "multiple of num_minibatches"),
    ],
)
def test_lstm_trainer_rejects(ppo_lstm, tmp_path, monkeypatch, flags, error, match):
    monkeypatch.chdir(tmp_path)
    with pytest.raises(error, match=match):
        ppo_lstm.main(["--env-id", ENV_ID, *flags, "--no-capture-video"])


def _run_file_lines():
    """(trainer, flags) of every run in the run files that side_by_side.sh takes."""
    for path in sorted((ROOT / "docs/lab-notes/rl-ppo-runs/run_scripts").glob("*.txt")):
        for words in map(str.split, path.read_text().splitlines()):
            if words and not words[0].startswith("#"):  # side_by_side.sh's rule for comments
                name, trainer, *flags = words
                yield pytest.param(trainer, flags, id=f"{path.stem}:{name}")


@pytest.mark.parametrize(("trainer", "flags"), list(_run_file_lines()))
def test_run_file_lines_parse(ppo, ppo_lstm, trainer, flags):
    # A mistyped or renamed flag fails here rather than minutes into a time-limited GPU job.
    module = {"ppo_memtasks.py": ppo, "ppo_memtasks_lstm.py": ppo_lstm}[trainer]
    args = parse_args(module.Args, [*flags, "--time-limit", "60"])
    assert args.env_id and _mode(args)


# Each shipped checkpoint with its task's horizon (one eval episode per env). Their figures
# (legacy/rl/baselines/RESULTS.md): RememberColor3-v0 1.00 over 64 episodes, ShellGameTouch-v0 0.93
# over 512, InterceptMedium-v0 0.94 over 512, RotateLenientPos-v0 0.96 over 512, TakeItBack-v0 0.97
# over 512, BunchOfColors3-v0 0.91 over 768, RememberColor3-VLA-v0 0.95 over 512,
# ShellGameTouch-VLA-v0 0.91 over 1,024.
SHIPPED_HORIZONS = {"RememberColor3-v0": 60, "ShellGameTouch-v0": 90, "RotateLenientPos-v0": 90,
                    "TakeItBack-v0": 180, "InterceptMedium-v0": 90, "RememberColor3-VLA-v0": 25,
                    "ShellGameTouch-VLA-v0": 30, "BunchOfColors3-v0": 120}


def test_every_shipped_checkpoint_is_tested():
    shipped = ROOT / "legacy/rl/baselines/checkpoints"
    assert sorted(p.parent.name for p in shipped.glob("*/final_ckpt.pt")) == sorted(SHIPPED_HORIZONS)


@pytest.mark.parametrize("env_id", sorted(SHIPPED_HORIZONS))
def test_shipped_state_checkpoint_solves_its_task(ppo, tmp_path, monkeypatch, env_id):
    monkeypatch.chdir(tmp_path)
    checkpoint = ROOT / "legacy/rl/baselines/checkpoints" / env_id / "final_ckpt.pt"
    result = ppo.main(["--env-id", env_id, "--include-state", "--evaluate", "--checkpoint", str(checkpoint),
                       "--num-eval-envs", "4", "--num-eval-steps", str(SHIPPED_HORIZONS[env_id]),
                       "--num-workers", "0", "--no-capture-video"])
    # A policy at 0.93 may miss one of four episodes; a broken checkpoint or env misses most.
    assert result["episodes"] == 4 and result["success_once"] >= 0.75


def test_time_limited_run_resumes_where_it_stopped(ppo, tmp_path, monkeypatch, capsys):
    # --time-limit 0 stops after the first iteration with resume.pt written; --resume goes on
    # in the same run directory from iteration 2 and ends with the final checkpoint.
    monkeypatch.chdir(tmp_path)
    flags = ["--env-id", ENV_ID, "--include-state", *TINY]
    assert ppo.main([*flags, "--time-limit", "0"]) == {"stopped_early": 1.0}
    (resume_file,) = tmp_path.rglob("resume.pt")
    state = torch.load(resume_file, weights_only=False)
    assert (state["iteration"], state["global_step"]) == (1, 16)
    assert not any(tmp_path.rglob("final_ckpt.pt"))
    ppo.main([*flags, "--resume", str(resume_file), "--learning-rate", "1e-4", "--resume-min-logstd", "-0.2"])
    assert "log std raised to at least -0.2: [-0.2, -0.2," in capsys.readouterr().out
    assert [p.relative_to(resume_file.parent).as_posix() for p in sorted(tmp_path.rglob("*.pt"))] == [
        "ckpt_0_1.pt", "final_ckpt.pt", "resume.pt"]
    state = torch.load(resume_file, weights_only=False)
    assert state["global_step"] == 32
    # The resumed run went on at the command's learning rate, with the saved Adam moments.
    assert [g["lr"] for g in state["optimizer"]["param_groups"]] == [1e-4]
    with pytest.raises(ValueError, match="env_id 'RememberColor3-v0'"):
        ppo.main(["--env-id", "RememberColor5-v0", "--include-state", *TINY, "--resume", str(resume_file)])
    with pytest.raises(FileNotFoundError, match="no such file"):
        ppo.main([*flags, "--resume", "nowhere/resume.pt"])
    with pytest.raises(ValueError, match="applies to a --resume run"):
        ppo.main([*flags, "--resume-min-logstd", "-1"])


def test_resume_with_a_larger_batch_goes_on_to_the_total_steps(ppo, tmp_path, monkeypatch):
    # Saved after iteration 1 (16 steps); going on with 4 envs (32 steps an iteration) to 48
    # steps is one more iteration, numbered 2, though 48 // 32 = 1 iteration in all.
    monkeypatch.chdir(tmp_path)
    flags = ["--env-id", ENV_ID, "--include-state", *TINY]
    ppo.main([*flags, "--time-limit", "0"])
    (resume_file,) = tmp_path.rglob("resume.pt")
    ppo.main([*flags, "--resume", str(resume_file), "--num-envs", "4", "--total-timesteps", "48"])
    state = torch.load(resume_file, weights_only=False)
    assert (state["iteration"], state["global_step"]) == (2, 48)


@pytest.mark.parametrize(
    "flag, value, printed, critic_factor",
    [
        ("--reward-scale", "0.01", "critic outputs scaled by 0.01", 0.01),
        ("--vf-coef", "0.0005", "--vf-coef 0.0005 (saved with 0.5)", 1.0),
        ("--reward-mode", "sparse", "--reward-mode sparse (saved with normalized_dense): the critic refits", 1.0),
    ],
)
def test_resume_in_other_units_adapts_the_critic_and_resets_adam(
    ppo, tmp_path, monkeypatch, capsys, flag, value, printed, critic_factor
):
    # Saved after iteration 1 at --reward-scale 1, --vf-coef 0.5; going on at another value with
    # no step left to train (total = the saved step) writes final_ckpt.pt straight from the
    # restored agent. Another reward scale scales the critic's outputs; any of the three starts
    # Adam's moments afresh (their units changed: the critic's directly, the actor's through the clip).
    monkeypatch.chdir(tmp_path)
    flags = ["--env-id", ENV_ID, "--include-state", *TINY]
    ppo.main([*flags, "--time-limit", "0"])
    (resume_file,) = tmp_path.rglob("resume.pt")
    saved = torch.load(resume_file, weights_only=False)
    assert (saved["reward_scale"], saved["vf_coef"], saved["reward_mode"]) == (1.0, 0.5, "normalized_dense")
    ppo.main([*flags, "--resume", str(resume_file), flag, value, "--total-timesteps", "16"])
    out = capsys.readouterr().out
    assert printed in out and "optimizer moments reset" in out
    assert ("critic outputs scaled" in out) == (critic_factor != 1.0)
    (final,) = tmp_path.rglob("final_ckpt.pt")
    head = torch.load(final, weights_only=True)
    for name in ("critic.6.weight", "critic.6.bias"):
        torch.testing.assert_close(head[name], saved["agent"][name] * critic_factor)
    for name in ("critic.4.weight", "actor_mean.6.weight"):
        torch.testing.assert_close(head[name], saved["agent"][name])


def test_head_grad_norms_split_the_gradient_between_policy_and_critic():
    agent = AgentStateOnly(obs_dim=5, action_dim=3)
    x = torch.randn(4, 5)
    agent.get_value(x).sum().backward()  # a critic-only loss: the policy's parameters get none
    norms = agent.head_grad_norms()
    assert norms["actor_grad_norm"] == 0 and norms["critic_grad_norm"] > 0
    agent.zero_grad()
    _, logprob, _, _ = agent.get_action_and_value(x)
    (-logprob.sum()).backward()
    norms = agent.head_grad_norms()
    assert norms["actor_grad_norm"] > 0 and norms["critic_grad_norm"] == 0


VLA_ID = "RememberColor3-VLA-v0"


@pytest.mark.parametrize(
    "mode, shapes",
    [
        ("state", {"proprio": (2, 7), "state": (2, 35)}),
        ("rgb_joints", {"proprio": (2, 7), "rgb": (2, 128, 128, 6)}),
        ("rgb", {"rgb": (2, 128, 128, 6)}),
    ],
)
def test_vector_env_takes_vla_ids_with_the_canonical_chain(mode, shapes):
    with CpuVectorEnv(SubEnvSpec(VLA_ID, mode), 2, workers=0) as env:
        assert env.single_action_space.shape == (7,)  # pd_ee_delta_pose: 6 + gripper
        obs, _ = env.reset(seed=0)
        assert {k: tuple(v.shape) for k, v in obs.items()} == shapes
        obs, reward, *_ = env.step(torch.zeros(2, 7))
        assert reward.shape == (2,)


def test_vla_ids_reject_oracle_modes_and_noop_steps():
    with pytest.raises(ValueError, match="not available for VLA ids"):
        CpuVectorEnv(SubEnvSpec(VLA_ID, "rgb_oracle"), 1, workers=0)
    with pytest.raises(ValueError, match="noop_steps applies to the RL ids only"):
        CpuVectorEnv(SubEnvSpec(VLA_ID, noop_steps=3), 1, workers=0)


def test_state_trainer_runs_on_a_vla_id(ppo, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    ppo.main(["--env-id", VLA_ID, "--include-state", *TINY])
    state = torch.load(next(tmp_path.rglob("final_ckpt.pt")), weights_only=True)
    assert state["critic.0.weight"].shape[1] == 7 + 35  # proprio, then state


def test_capture_video_records_eval_episodes(ppo, tmp_path, monkeypatch):
    # Training evals record the first eval env under the run's videos/; --evaluate records
    # videos and the trajectory beside the checkpoint (test_videos/), as upstream.
    monkeypatch.chdir(tmp_path)
    flags = [a for a in TINY if a != "--no-capture-video"]
    ppo.main(["--env-id", ENV_ID, "--include-state", *flags, "--num-eval-envs", "2", "--render-mode", "rgb_array"])
    (run_dir,) = {p.parent for p in tmp_path.rglob("final_ckpt.pt")}
    assert len(list((run_dir / "videos").glob("*.mp4"))) == 2  # one per eval pass
    ppo.main(["--env-id", ENV_ID, "--include-state", *flags, "--evaluate", "--checkpoint",
              str(run_dir / "final_ckpt.pt")])
    assert {p.suffix for p in (run_dir / "test_videos").iterdir()} == {".mp4", ".h5", ".json"}


def test_bunch_diagnosis_reports_touches_and_the_press_per_episode(tmp_path, monkeypatch, capsys):
    from mikasa_robo_rl.agents import AgentStateOnly

    checkpoint = tmp_path / "untrained.pt"
    torch.save(AgentStateOnly(88, 8).state_dict(), checkpoint)  # BunchOfColors3-v0's state is 88 floats
    module = _load_script("diagnose_bunch_of_colors", LAB_NOTES)
    monkeypatch.setattr(sys, "argv", ["diagnose", str(checkpoint), "--episodes", "1"])
    module.main()
    line = capsys.readouterr().out.strip().splitlines()[-1]
    # An untrained policy stays near its start pose: nothing touched or moved, the button never pressable.
    assert line.startswith("episode 0: correct touches 0/3, wrong touches 0, touches at steps [], "
                           "a cube moved up to 0.000 m, never pressable")
    assert "no press registered, pressed False" in line


def test_bunch_diagnosis_samples_actions_reproducibly(tmp_path, monkeypatch, capsys):
    from mikasa_robo_rl.agents import AgentStateOnly

    checkpoint = tmp_path / "untrained.pt"
    torch.save(AgentStateOnly(88, 8).state_dict(), checkpoint)
    module = _load_script("diagnose_bunch_of_colors", LAB_NOTES)
    argv = ["diagnose", str(checkpoint), "--episodes", "1", "--sample", "--min-logstd", "-1", "--first-seed", "7"]
    lines = []
    for _ in range(2):  # torch seed 0 each run: the same sampled episode
        monkeypatch.setattr(sys, "argv", argv)
        module.main()
        lines.append(capsys.readouterr().out.strip().splitlines()[-1])
    assert lines[0] == lines[1] and lines[0].startswith("episode 0: correct touches")
    monkeypatch.setattr(sys, "argv", argv[:4] + ["--min-logstd", "-1"])
    with pytest.raises(SystemExit):
        module.main()
    assert "--min-logstd changes only sampled actions: add --sample" in capsys.readouterr().err


def test_shell_game_touch_diagnosis_reports_reach_and_shove_per_episode(tmp_path, monkeypatch, capsys):
    checkpoint = tmp_path / "untrained.pt"
    torch.save(AgentStateOnly(47, 7).state_dict(), checkpoint)  # ShellGameTouch-VLA-v0: 47 state floats, 7-D ee action
    module = _load_script("diagnose_shell_game_touch", LAB_NOTES)
    monkeypatch.setattr(sys, "argv", ["diagnose", str(checkpoint), "--episodes", "1"])
    module.main()
    episode, summary = capsys.readouterr().out.strip().splitlines()[-2:]
    # An untrained policy stays near its start pose: no mug within 8 cm, none shoved.
    assert episode.startswith("seed 100: success 0, within 8 cm from step None")
    assert summary.startswith("success 0/1, within 8 cm 0/1, shoved > 0.05 m 0/1")


def test_plot_curves_replaces_its_png_and_json_whole(tmp_path, monkeypatch):
    import json

    from torch.utils.tensorboard import SummaryWriter

    run = tmp_path / "run"
    with SummaryWriter(run) as writer:
        for step, value in [(0, 1.0), (100, 2.5), (200, 0.125)]:
            writer.add_scalar("eval/return", value, step)
    out = tmp_path / "curves" / "demo"
    out.parent.mkdir()
    out.with_suffix(".json").write_text("{}")  # a curve shipped before: replaced, not appended to
    module = _load_script("plot_curves", LAB_NOTES)
    monkeypatch.setattr(sys, "argv", ["plot", str(run), "--labels", "demo", "--tags", "eval/return", "--out", str(out)])
    module.main()
    assert json.loads(out.with_suffix(".json").read_text()) == {"demo": {"eval/return": [[0, 1.0], [100, 2.5], [200, 0.125]]}}
    assert out.with_suffix(".png").read_bytes().startswith(b"\x89PNG")
    assert sorted(p.name for p in out.parent.iterdir()) == ["demo.json", "demo.png"]  # no temporary left
