"""The memory baseline (baselines/memory): the ``memory_gru`` LeRobot policy plugin, its
whole-episode trainer and the shipped checkpoints.

Needs lerobot 0.4.x: in the main environment this file contributes one test that runs it
inside `.venv-datasets` (where the setup script installs baselines/memory), as
tests/test_lerobot_policy.py does.
"""

from __future__ import annotations

import importlib.util
import json
import sys
from pathlib import Path

import pytest

IN_LEROBOT_ENV = all(
    importlib.util.find_spec(m) is not None
    for m in ("lerobot", "mikasa_bench", "mani_skill", "lerobot_policy_memory_gru")
)
REPO = Path(__file__).resolve().parents[1]
CHECKPOINTS = REPO / "baselines" / "memory" / "checkpoints"
SHIPPED = ("RememberColor3-VLA-v0", "ShellGameTouch-VLA-v0")

if not IN_LEROBOT_ENV:
    from test_validate import run_suite_in_datasets_env

    def test_memory_policy_suite_in_datasets_env() -> None:
        """Every test of the lerobot branch below, run inside `.venv-datasets`."""
        run_suite_in_datasets_env(__file__)

    @pytest.mark.parametrize("env_id", SHIPPED)
    def test_shipped_checkpoint_is_small_and_complete(env_id: str) -> None:
        d = CHECKPOINTS / env_id
        names = {p.name for p in d.iterdir()}
        assert {"config.json", "model.safetensors", "policy_preprocessor.json"} <= names
        assert json.loads((d / "config.json").read_text())["type"] == "memory_gru"
        assert sum(p.stat().st_size for p in d.iterdir()) < 20 * 2**20

else:
    import torch
    import torch.nn.functional as F
    from lerobot.configs.policies import PreTrainedConfig
    from lerobot.utils.import_utils import register_third_party_plugins
    from lerobot_policy_memory_gru import MemoryGRUConfig, MemoryGRUPolicy
    from lerobot_policy_memory_gru import train as memory_train
    from lerobot_policy_memory_gru.modeling_memory_gru import (
        action_bin,
        chunk_targets,
        instruction_word_buckets,
        leading_padding,
        shift_left,
    )
    from mikasa_bench import cli
    from mikasa_datasets.loaders import write_synthetic_task

    torch.set_num_threads(1)  # 2 shared cores; tiny model
    TINY = {
        "vision_channels": (4, 8, 8),
        "vision_dim": 16,
        "state_dim": 8,
        "instruction_dim": 4,
        "hidden_dim": 16,
        "head_dim": 16,
        "color_dim": 2,
        "chunk_size": 2,
    }
    TINY_ARGS = [arg for k, v in TINY.items() for arg in ("--policy", f"{k}={json.dumps(v)}")]

    def tiny_policy(**overrides) -> MemoryGRUPolicy:
        inputs, outputs = memory_train.mikasa_features()
        config = MemoryGRUConfig(
            input_features=inputs, output_features=outputs, device="cpu", **{**TINY, **overrides}
        )
        torch.manual_seed(0)
        return MemoryGRUPolicy(config).eval()

    def sequence_batch(b: int, t: int, seed: int = 0) -> dict:
        g = torch.Generator().manual_seed(seed)
        return {
            memory_train.TOP_KEY: torch.rand(b, t, 3, 128, 128, generator=g),
            memory_train.WRIST_KEY: torch.rand(b, t, 3, 128, 128, generator=g),
            "observation.state": torch.randn(b, t, 7, generator=g),
            "action": torch.randn(b, t, 7, generator=g),
            "action_is_pad": torch.zeros(b, t, dtype=torch.bool),
            "task": ["touch the cube of the colour you saw"] * b,
        }

    # ----------------------------------------------------------------------- the plugin
    def test_lerobot_discovers_the_plugin() -> None:
        """lerobot's own plugin discovery (as in lerobot-train / lerobot-eval) finds the type."""
        register_third_party_plugins()
        assert PreTrainedConfig.get_choice_class("memory_gru") is MemoryGRUConfig

    @pytest.mark.parametrize(
        ("attention", "chunk", "color", "points", "bins", "keys"),
        [
            (0, 1, 0, 0, 0, "cells"),
            (8, 1, 0, 0, 0, "cells"),
            (0, 4, 3, 0, 0, "cells"),
            (8, 2, 3, 2, 5, "cells"),
            (0, 2, 3, 2, 0, "color"),
            (8, 2, 3, 2, 5, "pointer"),
        ],
        ids=[
            "gru",
            "gru+episode-attention",
            "gru+chunks+colour",
            "all",
            "colour-keypoints",
            "pointer",
        ],
    )
    def test_acting_step_by_step_equals_the_training_pass(
        attention: int, chunk: int, color: int, points: int, bins: int, keys: str
    ) -> None:
        """select_action over an episode, one frame at a time, predicts exactly what the
        training pass predicts for the whole sequence (the first action of each step's chunk):
        the GRU (and the attention over the episode's earlier steps) see the same history."""
        policy = tiny_policy(
            episode_attention_dim=attention,
            chunk_size=chunk,
            color_dim=color,
            keypoint_heads=points,
            keypoint_keys="color" if keys == "pointer" else keys,
            head_sees_memory=keys != "pointer",
            action_bins=bins,
        )
        batch = sequence_batch(2, 6)
        with torch.no_grad():
            whole = policy.decode(policy.actions(batch, 2, 6)[0])[:, :, 0]
        policy.reset()
        for t in range(6):
            step = {k: (v[:, t] if isinstance(v, torch.Tensor) else v) for k, v in batch.items()}
            torch.testing.assert_close(policy.select_action(step), whole[:, t])

    def test_colour_keypoints_and_a_head_that_sees_only_points() -> None:
        """With ``keypoint_keys='color'`` the attention's keys are the cells' colour features
        alone; with ``head_sees_memory=False`` the head sees the points and the state only;
        bad settings are refused, naming what is accepted."""
        policy = tiny_policy(keypoint_heads=2, keypoint_keys="color", color_dim=3)
        assert [heads.key.in_features for heads in policy.keypoints.values()] == [3, 3]
        # Without the memory in the head, the action depends on the memory only through the
        # points: the readouts are not built, and the head sees the points and the state.
        pointer = tiny_policy(keypoint_heads=2, keypoint_keys="color", head_sees_memory=False)
        assert not pointer.readouts
        assert pointer.head[0].in_features == 2 * 2 * 2 + TINY["state_dim"]
        pointer.forward(sequence_batch(2, 3))[0].backward()
        with pytest.raises(ValueError, match="keypoint_heads > 0"):
            tiny_policy(head_sees_memory=False)
        with pytest.raises(ValueError, match="'cells' or 'color'"):
            tiny_policy(keypoint_heads=2, keypoint_keys="colour")
        with pytest.raises(ValueError, match="color_dim > 0"):
            tiny_policy(keypoint_heads=2, keypoint_keys="color", color_dim=0)

    @pytest.mark.parametrize("chunk", [1, 3])
    def test_leading_padding_is_where_the_episode_starts(chunk: int) -> None:
        """A lerobot-train window that reaches before the episode (padding at its start) has
        the same loss as the episode alone: the GRU starts at the first real frame, and no
        action chunk reaches into the padding."""
        policy = tiny_policy(random_shift_pixels=0, chunk_size=chunk)
        batch = sequence_batch(1, 4)
        padded = {
            k: (torch.cat([v[:, :1].expand(1, 3, *v.shape[2:]), v], 1) if k != "task" else v)
            for k, v in batch.items()
            if k != "action_is_pad"
        }
        padded["action_is_pad"] = torch.tensor([[True] * 3 + [False] * 4])
        with torch.no_grad():
            torch.testing.assert_close(policy.forward(padded)[0], policy.forward(batch)[0])

    def test_padding_helpers() -> None:
        pad = torch.tensor([[True, True, False, False], [False, False, False, True]])
        assert leading_padding(pad).tolist() == [2, 0]
        x = torch.arange(8).view(2, 4)
        assert shift_left(x, torch.tensor([2, 0])).tolist() == [[2, 3, 3, 3], [4, 5, 6, 7]]

    def test_chunk_targets_stop_at_the_sequence_end() -> None:
        values = torch.arange(4.0).view(1, 4)
        valid = torch.tensor([[1.0, 1.0, 1.0, 0.0]])  # the last step is padding
        targets, weight = chunk_targets(values, valid, 2)
        assert targets[0, :, 0].tolist() == [0, 1, 2, 3] and targets[0, :3, 1].tolist() == [1, 2, 3]
        assert weight[0].tolist() == [[1, 1], [1, 1], [1, 0], [0, 0]]

    def test_action_bins_round_trip_within_half_a_bin() -> None:
        """An action binned and decoded is the nearest of the evenly spaced values; the loss
        with bins is a finite cross-entropy that trains."""
        policy = tiny_policy(action_bins=5)
        actions = torch.tensor([-1.0, -0.6, 0.0, 0.24, 0.26, 1.0, 1.7])
        one_hot = F.one_hot(action_bin(actions, 5), 5).float()
        torch.testing.assert_close(
            policy.decode(one_hot), torch.tensor([-1.0, -0.5, 0.0, 0.0, 0.5, 1.0, 1.0])
        )
        loss, info = policy.forward(sequence_batch(2, 5))
        loss.backward()
        assert torch.isfinite(loss) and "ce_loss" in info

    def test_start_recall_adds_a_training_loss_and_leaves_acting_alone() -> None:
        """With ``start_recall_weight`` the loss grows by the weighted recall of the first
        frame, which trains; the actions are those of the same weights without it."""
        plain, recall = tiny_policy(), tiny_policy(start_recall_weight=0.5)
        assert recall.start_recall is not None and plain.start_recall is None
        batch = sequence_batch(2, 4)
        torch.manual_seed(1)
        loss_plain, _ = plain.forward(batch)
        torch.manual_seed(1)
        loss, info = recall.forward(batch)
        torch.testing.assert_close(loss, loss_plain + 0.5 * info["recall_loss"])
        loss.backward()
        assert recall.start_recall.weight.grad.abs().sum() > 0
        with torch.no_grad():
            torch.testing.assert_close(
                recall.actions(batch, 2, 4)[0], plain.actions(batch, 2, 4)[0]
            )

    def test_instruction_buckets_are_stable_words() -> None:
        idx, off = instruction_word_buckets(["Touch the RED cube.", ""], 1024)
        assert off.tolist() == [0, 4] and len(idx) == 5
        again, _ = instruction_word_buckets(["touch the red cube"], 1024)
        assert idx[:4].tolist() == again.tolist()

    def test_batch_size_change_without_reset_is_refused() -> None:
        policy = tiny_policy()
        batch = sequence_batch(2, 1)
        step = {k: (v[:, 0] if isinstance(v, torch.Tensor) else v) for k, v in batch.items()}
        policy.select_action(step)
        one = {k: (v[:1] if isinstance(v, torch.Tensor) else v[:1]) for k, v in step.items()}
        with pytest.raises(ValueError, match="call reset"):
            policy.select_action(one)
        policy.reset()
        assert policy.select_action(one).shape == (1, 7)

    # ----------------------------------------------------------------------- the trainer
    @pytest.fixture(scope="module")
    def npz_task(tmp_path_factory: pytest.TempPathFactory) -> Path:
        root = tmp_path_factory.mktemp("npz")
        return write_synthetic_task(root, "RememberColor3-VLA-v0", [5, 7, 6, 4])

    def train(npz_task: Path, out: Path, steps: int, *extra: str) -> int:
        argv = ["--data", str(npz_task), "--out", str(out), "--steps", str(steps)]
        argv += ["--batch-size", "2", "--device", "cpu", "--log-every", "1", *TINY_ARGS, *extra]
        return memory_train.main(argv)

    def test_trainer_writes_a_lerobot_policy_and_resumes_exactly(
        npz_task: Path, tmp_path: Path
    ) -> None:
        """4 steps in one go, and 2 + 2 with a resume, give the same weights; the output is a
        LeRobot pretrained-policy directory with its processors and a log."""
        assert train(npz_task, tmp_path / "once", 4) == 0
        assert train(npz_task, tmp_path / "twice", 2) == 0
        assert train(npz_task, tmp_path / "twice", 4, "--resume") == 0
        model = tmp_path / "once" / "pretrained_model"
        names = {p.name for p in model.iterdir()}
        assert {"config.json", "model.safetensors", "policy_preprocessor.json"} <= names
        log = json.loads((tmp_path / "once" / "train_log.json").read_text())
        assert log["step"] == 4 and log["episodes"] == 4 and log["frames"] == 22
        a = MemoryGRUPolicy.from_pretrained(model).state_dict()
        b = MemoryGRUPolicy.from_pretrained(tmp_path / "twice" / "pretrained_model").state_dict()
        for key in a:
            torch.testing.assert_close(a[key], b[key])

    def test_trainer_refuses_to_overwrite_and_names_bad_flags(
        npz_task: Path, tmp_path: Path
    ) -> None:
        assert train(npz_task, tmp_path / "run", 1) == 0
        with pytest.raises(SystemExit, match="--resume"):
            train(npz_task, tmp_path / "run", 1)
        with pytest.raises(SystemExit, match="hidden_dim"):
            train(npz_task, tmp_path / "other", 1, "--policy", "hiden_dim=3")

    def test_a_directory_of_datasets_trains_one_policy_over_the_tasks(tmp_path: Path) -> None:
        """``--data`` given a collection's data_npz stands for every task in it, each
        episode with its own instruction; a directory without episodes is named."""
        root = tmp_path / "data_npz"
        write_synthetic_task(root, "RememberColor3-VLA-v0", [5, 4], instruction="colour")
        write_synthetic_task(root, "ShellGameTouch-VLA-v0", [3], instruction="ball")
        bank = memory_train.load_bank([str(root)], torch.device("cpu"), None)
        assert sorted(bank.instruction) == ["ball", "colour", "colour"]
        with pytest.raises(SystemExit, match="no episodes"):
            memory_train.load_bank([str(tmp_path)], torch.device("cpu"), None)

    # ----------------------------------------------------------------------- the checkpoints
    @pytest.mark.parametrize("env_id", SHIPPED)
    def test_shipped_checkpoint_plays_an_episode(env_id: str, tmp_path: Path) -> None:
        """The documented command, ``mikasa-bench run --policy lerobot:<checkpoint>``, one
        canonical episode on the CPU."""
        out = tmp_path / "run"
        argv = ["run", "--task", env_id, "--policy", f"lerobot:{CHECKPOINTS / env_id}"]
        argv += ["--num-episodes", "1", "--workers", "0", "--no-progress", "--no-report"]
        argv += ["--out", str(out), "--policy-kwargs", json.dumps({"device": "cpu"})]
        assert cli.main(argv) == 0
        result = json.loads((out / f"{env_id}.json").read_text())
        assert len(result["successes"]) == 1
        assert result["model"]["name"].startswith("lerobot-memory_gru")


if __name__ == "__main__":
    sys.exit(pytest.main([__file__, "-q"]))
