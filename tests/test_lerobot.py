"""NPZ -> LeRobot v3 and RLDS -> LeRobot v3 (mikasa_datasets.lerobot, written through
lerobot's public API): lerobot's own format, offline loading with LeRobotDataset, round
trip (exact for state, action, reward, success, done and instruction; video frames within
a PSNR tolerance), image statistics, parallel writers, output protocol, corrupt input, CLI.

Needs lerobot + tensorflow: in the main environment this file contributes one test that
runs it inside `.venv-datasets` (see tests/test_validate.py for the mechanism).
"""

from __future__ import annotations

import importlib.util
import json
import re
from pathlib import Path

import numpy as np
import pytest

IN_DATASETS_ENV = importlib.util.find_spec("tensorflow_datasets") is not None
ENV_ID = "RotateLenientPos-VLA-v0"
NAME = "rotate_lenient_pos_vla_v0"
# Video tolerance: AV1 at lerobot's settings (SVT-AV1 crf 30, preset 12, GOP 2, yuv420p) on
# render-like frames; collected RememberColor3 renders gave 30.5 dB (worst 29.1). The bar:
# every camera-episode >= 28 dB.
MIN_PSNR_DB = 28.0

if not IN_DATASETS_ENV:
    import subprocess
    import sys

    from test_validate import REPO, run_plain_in_datasets_env, run_suite_in_datasets_env

    def test_lerobot_suite_in_datasets_env() -> None:
        """Every test below, run inside `.venv-datasets`."""
        run_suite_in_datasets_env(__file__)

    HOOK_SOURCE = REPO / "packages/mikasa-datasets/src/mikasa_datasets/torchvision_cpu.py"

    def test_datasets_env_imports_torchvision_without_help(tmp_path: Path) -> None:
        """`.venv-datasets` holds PyPI's CUDA torchvision beside the CPU torch; its start-up
        hook (scripts/setup_datasets_envs.sh, mikasa_datasets.torchvision_cpu) makes a plain
        ``import torchvision`` and lerobot's dataset module import in a fresh interpreter,
        and imports nothing itself at start-up."""
        start = run_plain_in_datasets_env(
            "python",
            "-c",
            "import sys; print('torch' in sys.modules, 'torchvision' in sys.modules)",
            cwd=tmp_path,
        )
        assert (start.returncode, start.stdout.strip()) == (0, "False False"), start.stderr
        tv = run_plain_in_datasets_env(
            "python",
            "-c",
            "import sys; import torchvision; print(torchvision.__version__)",
            cwd=tmp_path,
        )
        assert tv.returncode == 0 and tv.stdout.startswith("0.28.0"), tv.stderr[-3000:]
        ds = run_plain_in_datasets_env(
            "python", "-c", "import lerobot.datasets.lerobot_dataset", cwd=tmp_path
        )
        assert ds.returncode == 0, ds.stderr[-3000:]
        site = run_plain_in_datasets_env(
            "python", "-c", "import _mikasa_torchvision_cpu as m; print(m.__file__)", cwd=tmp_path
        )
        assert Path(site.stdout.strip()).read_bytes() == HOOK_SOURCE.read_bytes()  # refreshed

    def _fake_torchvision(root: Path, has_ops: bool) -> None:
        """A stand-in for torchvision's import sequence: ``extension`` reports whether
        ``_C`` loaded, then the package registers a fake kernel for ``torchvision::nms``."""
        pkg = root / "torchvision"
        pkg.mkdir()
        (pkg / "extension.py").write_text(f"def _has_ops():\n    return {has_ops}\n")
        (pkg / "__init__.py").write_text(
            "import torch\n"
            "from . import extension\n"
            "torch.library.register_fake('torchvision::nms')(lambda dets, scores, t: dets)\n"
        )

    @pytest.mark.parametrize("has_ops", [False, True])
    def test_torchvision_hook_acts_only_where_c_ops_are_missing(
        tmp_path: Path, has_ops: bool
    ) -> None:
        """With ``_C`` missing the hook declares the schemas and the import succeeds; with
        ``_C`` loaded it declares nothing (the fake package then fails as it would without
        the hook, since nothing real defines the op here). Either way the module's own
        loader is put back."""
        _fake_torchvision(tmp_path, has_ops)
        code = (
            "import sys; sys.path.insert(0, sys.argv[1])\n"
            "from mikasa_datasets import torchvision_cpu as t\n"
            "t.install(); t.install()\n"
            "assert sum(hasattr(f, '_mikasa_torchvision_cpu') for f in sys.meta_path) == 1\n"
            "try:\n"
            "    import torchvision\n"
            "except RuntimeError as exc:\n"
            "    print('error', 'torchvision::nms' in str(exc))\n"
            "else:\n"
            "    import torch\n"
            "    print('ok', hasattr(torch.ops.torchvision, 'qnms'))\n"
            "ext = sys.modules['torchvision.extension']\n"
            "print(type(ext.__loader__).__name__, type(ext.__spec__.loader).__name__)\n"
        )
        proc = subprocess.run(
            [sys.executable, "-c", code, str(tmp_path)],
            capture_output=True,
            text=True,
            timeout=300,
        )
        assert proc.returncode == 0, proc.stderr[-3000:]
        first = "error True" if has_ops else "ok True"
        assert proc.stdout.split("\n")[:2] == [first, "SourceFileLoader SourceFileLoader"]

else:
    from mikasa_datasets import cli, lerobot_write, rlds
    from mikasa_datasets import lerobot as lr
    from mikasa_datasets.loaders import (
        DatasetFormatError,
        OutputExistsError,
        load_episodes,
        write_synthetic_task,
    )
    from mikasa_datasets.npz import EpisodeFormatError

    LENGTHS = [12, 25, 17]
    # Rotate tasks embed a per-episode angle: several task strings in one dataset.
    INSTRUCTIONS = ["Rotate the peg by 30°.", "Rotate the peg by 45°.", "Rotate the peg by 30°."]

    @pytest.fixture(scope="module")
    def npz_task(tmp_path_factory: pytest.TempPathFactory) -> Path:
        root = tmp_path_factory.mktemp("lerobot")
        return write_synthetic_task(
            root / "data_npz", ENV_ID, LENGTHS, instruction=INSTRUCTIONS, seed=11
        )

    @pytest.fixture(scope="module")
    def from_npz(npz_task: Path) -> lr.ConversionResult:
        return lr.convert_npz_to_lerobot(npz_task, npz_task.parent.parent / "data_lerobot")

    @pytest.fixture(scope="module")
    def from_rlds(npz_task: Path) -> lr.ConversionResult:
        root = npz_task.parent.parent
        r = rlds.convert_npz_to_rlds(npz_task, root / "data_rlds")
        return lr.convert_rlds_to_lerobot(r.path.parent, root / "data_lerobot_from_rlds")

    def test_meta_matches_spec(npz_task: Path, from_npz: lr.ConversionResult) -> None:
        root = from_npz.path
        assert root == npz_task.parent.parent / "data_lerobot" / NAME
        info = json.loads((root / "meta" / "info.json").read_text())
        assert info["codebase_version"] == "v3.0"
        assert (info["robot_type"], info["fps"]) == ("mikasa_robo", 10)
        assert (info["total_episodes"], info["total_frames"]) == (3, sum(LENGTHS))
        assert info["total_tasks"] == 2
        feats = info["features"]
        for key in (lr.TOP_KEY, lr.WRIST_KEY):
            assert feats[key]["dtype"] == "video"
            assert feats[key]["shape"] == [128, 128, 3]
            assert feats[key]["names"] == ["height", "width", "channel"]
            assert feats[key]["info"]["video.codec"] == "av1"  # pinned (DEFAULT_VCODEC)
            assert feats[key]["info"]["video.fps"] == 10
        assert feats[lr.STATE_KEY]["shape"] == [7] and feats[lr.ACTION_KEY]["shape"] == [7]
        for key in (
            lr.REWARD_KEY,
            lr.SUCCESS_KEY,
            lr.DONE_KEY,
            "timestamp",
            "frame_index",
            "episode_index",
            "index",
            "task_index",
        ):
            assert key in feats
        assert (root / "meta" / "stats.json").is_file() and (
            root / "meta" / "tasks.parquet"
        ).is_file()
        assert list((root / "meta" / "episodes").glob("chunk-000/file-000.parquet"))
        assert list((root / "data").glob("chunk-000/file-000.parquet"))
        assert list((root / "videos" / lr.TOP_KEY).glob("chunk-000/file-000.mp4"))
        # source metadata copied (spec §7.2); nothing else left next to the dataset
        assert (root / lr.SOURCE_METADATA_NAME).read_bytes() == (
            npz_task / "metadata.json"
        ).read_bytes()
        assert [p.name for p in root.parent.iterdir()] == [NAME]

    def test_round_trip(npz_task: Path, from_npz: lr.ConversionResult) -> None:
        source = load_episodes(npz_task)
        back = load_episodes(from_npz.path)  # auto-detected as LeRobot
        assert len(back) == len(source)
        worst = []
        for i, (a, b) in enumerate(zip(source, back, strict=True)):
            for key in a:
                assert a[key].dtype == b[key].dtype and a[key].shape == b[key].shape, (i, key)
                if key != "rgb":  # exact: state, action, reward, success, done, instruction, ...
                    assert np.array_equal(a[key], b[key]), f"episode {i} {key} differs"
            for cam in (slice(0, 3), slice(3, 6)):
                worst.append(lr.psnr(a["rgb"][..., cam], b["rgb"][..., cam]))
        assert min(worst) >= MIN_PSNR_DB, f"video PSNR per camera-episode {worst}"

    def test_image_stats_are_the_frames_stats(
        npz_task: Path, from_npz: lr.ConversionResult
    ) -> None:
        """lerobot 0.4.4 squares uint8 pixels in uint8 (wrapping) and wrote a wrong image
        std; stats.json's camera entries are recomputed from all frames."""
        stats = json.loads((from_npz.path / "meta" / "stats.json").read_text())
        source = load_episodes(npz_task)
        for key, cam in ((lr.TOP_KEY, slice(0, 3)), (lr.WRIST_KEY, slice(3, 6))):
            pixels = np.concatenate([e["rgb"][..., cam].reshape(-1, 3) for e in source])
            expected = {
                "mean": pixels.mean(0) / 255.0,
                "std": (pixels / 255.0).std(0),
                "min": pixels.min(0) / 255.0,
                "max": pixels.max(0) / 255.0,
                **{
                    f"q{int(q * 100):02d}": np.quantile(pixels, q, axis=0, method="inverted_cdf")
                    / 255.0
                    for q in (0.01, 0.10, 0.50, 0.90, 0.99)
                },
            }
            assert set(stats[key]) == {*expected, "count"}
            assert stats[key]["count"] == [sum(LENGTHS)]
            for name, value in expected.items():
                got = np.asarray(stats[key][name])
                assert got.shape == (3, 1, 1), (key, name)
                np.testing.assert_allclose(got.ravel(), value, rtol=1e-9, err_msg=f"{key} {name}")

    def test_video_files_are_cut_and_still_load(
        npz_task: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
    ) -> None:
        # A tiny file size: every episode starts a new video file (no whole-file re-mux).
        monkeypatch.setattr(lerobot_write, "VIDEO_FILE_SIZE_IN_MB", 1e-6)
        r = lr.convert_npz_to_lerobot(npz_task, tmp_path)
        for key in (lr.TOP_KEY, lr.WRIST_KEY):
            assert len(list((r.path / "videos" / key).rglob("*.mp4"))) == len(LENGTHS)
        a, b = load_episodes(npz_task), load_episodes(r.path)
        for x, y in zip(a, b, strict=True):
            assert np.array_equal(x["proprio"], y["proprio"])
            assert lr.psnr(x["rgb"], y["rgb"]) >= MIN_PSNR_DB
        dataset = lr.lerobot_dataset_class()(NAME, root=r.path)
        last = dataset[len(dataset) - 1]
        frame = (last[lr.TOP_KEY].numpy().transpose(1, 2, 0) * 255).round().astype(np.uint8)
        assert lr.psnr(frame, a[-1]["rgb"][-1, ..., :3]) > 30.0

    def test_episode_videos_are_joined_up_to_the_file_size(
        npz_task: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
    ) -> None:
        # Written one file per episode, then joined: a size that holds episodes 0 and 1.
        monkeypatch.setattr(lerobot_write, "VIDEO_FILE_SIZE_IN_MB", 1e-6)
        apart = lr.convert_npz_to_lerobot(npz_task, tmp_path / "apart")
        sizes = {
            key: [f.stat().st_size for f in sorted((apart.path / "videos" / key).rglob("*.mp4"))]
            for key in (lr.TOP_KEY, lr.WRIST_KEY)
        }
        pair = max(s[0] + s[1] for s in sizes.values()) * 1.01
        assert all(sum(s) >= pair for s in sizes.values())  # all three fit in no camera
        pair /= 2**20
        monkeypatch.setattr(lerobot_write, "VIDEO_FILE_SIZE_IN_MB", pair)
        joined = lr.convert_npz_to_lerobot(npz_task, tmp_path / "joined")
        for key in (lr.TOP_KEY, lr.WRIST_KEY):
            assert len(list((joined.path / "videos" / key).rglob("*.mp4"))) == 2
        _, episodes, _, _ = lr.read_tables(joined.path)
        col = f"videos/{lr.TOP_KEY}/"
        assert list(episodes[col + "file_index"]) == [0, 0, 1]
        assert episodes[col + "from_timestamp"][1] == episodes[col + "to_timestamp"][0] > 0
        assert episodes[col + "from_timestamp"][2] == 0.0
        info = json.loads((joined.path / "meta" / "info.json").read_text())
        assert info["video_files_size_in_mb"] == pair
        for a, b in zip(load_episodes(apart.path), load_episodes(joined.path), strict=True):
            for key in a:
                assert np.array_equal(a[key], b[key]), key  # the same packets, moved
        dataset = lr.lerobot_dataset_class()(NAME, root=joined.path)
        first_of_ep1 = dataset[LENGTHS[0]]
        assert int(first_of_ep1["episode_index"]) == 1 and int(first_of_ep1["frame_index"]) == 0
        frame = (first_of_ep1[lr.TOP_KEY].numpy().transpose(1, 2, 0) * 255).round().astype(np.uint8)
        assert lr.psnr(frame, load_episodes(apart.path)[1]["rgb"][0, ..., :3]) > 40.0

    @pytest.mark.parametrize("vcodec", ["h264", "libsvtav1"])
    def test_every_episode_video_decodes_on_its_own(
        npz_task: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, vcodec: str
    ) -> None:
        """lerobot encodes every episode with an encoder of its own: with one episode per
        file, each file is a whole video that starts on a keyframe."""
        import av

        monkeypatch.setattr(
            lerobot_write, "VIDEO_FILE_SIZE_IN_MB", 1e-6
        )  # left one file per episode
        r = lr.convert_npz_to_lerobot(npz_task, tmp_path / vcodec, vcodec=vcodec)
        source = load_episodes(npz_task)
        for key, cam in ((lr.TOP_KEY, slice(0, 3)), (lr.WRIST_KEY, slice(3, 6))):
            files = sorted((r.path / "videos" / key).rglob("*.mp4"))
            assert len(files) == len(LENGTHS)
            for episode, path in zip(source, files, strict=True):
                with av.open(str(path)) as container:
                    frames = list(container.decode(video=0))
                assert len(frames) == int(episode["episode_length"]) and frames[0].key_frame
                decoded = np.stack([f.to_ndarray(format="rgb24") for f in frames])
                assert lr.psnr(decoded, episode["rgb"][..., cam]) >= MIN_PSNR_DB
        info = json.loads((r.path / "meta" / "info.json").read_text())
        assert info["features"][lr.TOP_KEY]["info"]["video.codec"] == (
            "av1" if vcodec == "libsvtav1" else "h264"
        )

    def test_loads_offline_with_lerobot_dataset(from_npz: lr.ConversionResult) -> None:
        import os

        assert os.environ.get("HF_HUB_OFFLINE") == "1"  # set before lerobot was imported
        dataset = lr.lerobot_dataset_class()(NAME, root=from_npz.path)
        assert len(dataset) == sum(LENGTHS) and dataset.meta.total_episodes == 3
        ours = load_episodes(from_npz.path)
        flat_state = np.concatenate([e["proprio"] for e in ours])
        flat_top = np.concatenate([e["rgb"][..., :3] for e in ours])
        tasks = [
            str(e["language_instruction"]) for e in ours for _ in range(int(e["episode_length"]))
        ]
        for i in range(len(dataset)):  # iterates through lerobot's own video decoding
            item = dataset[i]
            assert np.array_equal(item[lr.STATE_KEY].numpy(), flat_state[i])
            assert item["task"] == tasks[i]
            frame = (item[lr.TOP_KEY].numpy().transpose(1, 2, 0) * 255).round().astype(np.uint8)
            assert frame.shape == (128, 128, 3)
            # torchcodec (system FFmpeg) and PyAV decode the same stream
            assert lr.psnr(frame, flat_top[i]) > 40.0

    def test_rlds_to_lerobot_equals_npz_to_lerobot(
        from_npz: lr.ConversionResult, from_rlds: lr.ConversionResult
    ) -> None:
        assert from_rlds.path.name == NAME
        a, b = load_episodes(from_npz.path), load_episodes(from_rlds.path)
        assert len(a) == len(b) == 3
        for x, y in zip(a, b, strict=True):
            for key in x:
                assert np.array_equal(x[key], y[key]), (
                    key
                )  # same frames in, same encoder: identical
        assert (from_rlds.path / lr.SOURCE_METADATA_NAME).is_file()

    def test_no_videos_is_exact(npz_task: Path, tmp_path: Path) -> None:
        r = lr.convert_npz_to_lerobot(npz_task, tmp_path, use_videos=False, max_episodes=1)
        info = json.loads((r.path / "meta" / "info.json").read_text())
        assert info["features"][lr.TOP_KEY]["dtype"] == "image"
        (a,), (b,) = load_episodes(npz_task)[:1], load_episodes(r.path)
        for key in a:
            assert np.array_equal(a[key], b[key]), key
        from mikasa_datasets.validate import validate_path

        assert validate_path(r.path).frames == LENGTHS[0]

    def test_env_id_folder_and_version_flag(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]
    ) -> None:
        """Published RLDS releases name task folders by env id (spec §8): both spellings work."""
        task = write_synthetic_task(tmp_path / "data_npz", ENV_ID, [10])
        r = rlds.convert_npz_to_rlds(task, tmp_path / "data_rlds")
        r.path.parent.rename(tmp_path / "data_rlds" / ENV_ID)
        args = ["to-lerobot", "--root", str(tmp_path), "--task", ENV_ID, "--version", "1.0.0"]
        assert cli.main(args) == 0
        assert f"to-lerobot {NAME}: 1 episodes, 10 frames" in capsys.readouterr().out
        assert (tmp_path / "data_lerobot" / NAME / "meta" / "info.json").is_file()
        assert cli.main([*args[:-1], "9.9.9", "--overwrite"]) == 1
        assert "9.9.9: no such RLDS version directory" in capsys.readouterr().err

    def test_existing_output_needs_overwrite_or_resume(npz_task: Path, tmp_path: Path) -> None:
        r = lr.convert_npz_to_lerobot(npz_task, tmp_path, max_episodes=1)
        with pytest.raises(OutputExistsError, match=re.escape(str(r.path))):
            lr.convert_npz_to_lerobot(npz_task, tmp_path, max_episodes=1)
        assert lr.convert_npz_to_lerobot(npz_task, tmp_path, max_episodes=1, resume=True).skipped
        # a different episode count no longer matches: resume converts again
        redone = lr.convert_npz_to_lerobot(npz_task, tmp_path, max_episodes=2, resume=True)
        assert not redone.skipped and redone.episodes == 2
        again = lr.convert_npz_to_lerobot(npz_task, tmp_path, max_episodes=1, overwrite=True)
        assert again.episodes == 1 and len(load_episodes(again.path)) == 1
        assert [p.name for p in tmp_path.iterdir()] == [NAME]  # no staging or old copies

    def test_repo_id_template(npz_task: Path, tmp_path: Path) -> None:
        r = lr.convert_npz_to_lerobot(
            npz_task, tmp_path, repo_id_template="mikasa/{task}", max_episodes=1
        )
        assert r.path == tmp_path / "mikasa" / NAME
        with pytest.raises(ValueError, match="must contain"):
            lr.convert_npz_to_lerobot(npz_task, tmp_path, repo_id_template="fixed")

    def test_parallel_writers_write_the_same_episodes(npz_task: Path, tmp_path: Path) -> None:
        """Two writer processes, joined by lerobot's aggregation, write the same data as
        one: every loaded array identical (frames included: lerobot encodes each episode
        on its own), the same frame and task tables, the same image statistics, and
        lerobot's combined statistics of the other features equal up to rounding."""
        one = lr.convert_npz_to_lerobot(npz_task, tmp_path / "one", workers=1)
        seen: list[tuple[int, int]] = []
        r = lr.convert_npz_to_lerobot(
            npz_task, tmp_path / "two", workers=2, progress=lambda d, n: seen.append((d, n))
        )
        assert (r.episodes, r.frames) == (3, sum(LENGTHS)) and seen[-1] == (3, 3)
        single, parallel = load_episodes(one.path), load_episodes(r.path)
        assert len(parallel) == len(single) == 3
        for a, b in zip(single, parallel, strict=True):
            for key in a:
                assert np.array_equal(a[key], b[key]), key
        info_1, episodes_1, frames_1, tasks_1 = lr.read_tables(one.path)
        info_2, episodes_2, frames_2, tasks_2 = lr.read_tables(r.path)
        assert tasks_1 == tasks_2 and len(tasks_2) == 2
        assert frames_1.columns.equals(frames_2.columns)
        for column in frames_1.columns:
            assert np.array_equal(
                np.stack(frames_1[column].to_numpy()), np.stack(frames_2[column].to_numpy())
            ), column
        for column in ("episode_index", "length", "dataset_from_index", "dataset_to_index"):
            assert list(episodes_1[column]) == list(episodes_2[column]), column
        for key in ("total_episodes", "total_frames", "total_tasks", "features", "fps"):
            assert info_1[key] == info_2[key], key
        assert info_2["video_files_size_in_mb"] == lr.VIDEO_FILE_SIZE_IN_MB
        stats_1, stats_2 = (
            json.loads((p / "meta" / "stats.json").read_text()) for p in (one.path, r.path)
        )
        assert stats_1.keys() == stats_2.keys()
        for key in (lr.TOP_KEY, lr.WRIST_KEY):
            assert stats_1[key] == stats_2[key], key  # from pixel counts: exact
        for key in (lr.STATE_KEY, lr.ACTION_KEY, lr.REWARD_KEY):
            assert stats_2[key]["count"] == [sum(LENGTHS)]
            for name in ("min", "max", "mean", "std"):
                np.testing.assert_allclose(stats_1[key][name], stats_2[key][name], rtol=1e-6)
        assert (r.path / lr.SOURCE_METADATA_NAME).is_file()
        dataset = lr.lerobot_dataset_class()(NAME, root=r.path)
        assert len(dataset) == sum(LENGTHS) and dataset[len(dataset) - 1]["episode_index"] == 2
        from mikasa_datasets.validate import validate_path

        assert validate_path(r.path).frames == sum(LENGTHS)
        assert sorted(p.name for p in (tmp_path / "two").iterdir()) == [NAME]  # no parts left

    @pytest.mark.parametrize(("workers", "use_videos"), [(1, True), (2, True), (1, False)])
    def test_finished_dataset_holds_only_its_own_files(
        tmp_path: Path, capsys: pytest.CaptureFixture[str], workers: int, use_videos: bool
    ) -> None:
        """A user's report: six episodes converted with ``--from npz`` left six empty
        ``tmp*`` folders (one per episode) in the finished dataset. A finished dataset
        holds lerobot's files and the copied source metadata, nothing else."""
        env_id = "RememberColor3-VLA-v0"
        write_synthetic_task(tmp_path / "data_npz", env_id, [10, 11, 12, 13, 14, 15])
        args = ["to-lerobot", "--root", str(tmp_path), "--task", env_id, "--from", "npz"]
        args += ["--workers", str(workers)] + ([] if use_videos else ["--no-videos"])
        assert cli.main(args) == 0
        assert "6 episodes, 75 frames" in capsys.readouterr().out
        root = tmp_path / "data_lerobot" / "remember_color_3_vla_v0"
        assert [p.name for p in root.parent.iterdir()] == [root.name]
        expected = [
            r"data/chunk-\d{3}/file-\d{3}\.parquet",
            r"meta/episodes/chunk-\d{3}/file-\d{3}\.parquet",
            r"meta/(info\.json|stats\.json|tasks\.parquet)",
            re.escape(lr.SOURCE_METADATA_NAME),
        ]
        if use_videos:
            cameras = "|".join(re.escape(k) for k in (lr.TOP_KEY, lr.WRIST_KEY))
            expected.append(rf"videos/({cameras})/chunk-\d{{3}}/file-\d{{3}}\.mp4")
        files = [p.relative_to(root).as_posix() for p in root.rglob("*") if not p.is_dir()]
        strays = [f for f in files if not any(re.fullmatch(e, f) for e in expected)]
        assert strays == [], strays
        empty = [p for p in root.rglob("*") if p.is_dir() and not any(p.iterdir())]
        assert empty == [], empty  # e.g. tmp* folders, or images/ after a --no-videos write
        assert len(load_episodes(root)) == 6

    def test_writer_count() -> None:
        assert lr.writer_count(None, 1) == 1
        assert lr.writer_count(None, 10_000) == (__import__("os").cpu_count() or 1)
        assert lr.writer_count(5, 3) == 3
        with pytest.raises(ValueError, match="workers must be >= 1"):
            lr.writer_count(0, 3)

    def test_rlds_episode_ranges(tmp_path: Path) -> None:
        lengths = [5, 6, 7, 8, 9]
        task = write_synthetic_task(tmp_path / "data_npz", ENV_ID, lengths)
        r = rlds.convert_npz_to_rlds(task, tmp_path / "data_rlds")
        every = [int(e["episode_length"]) for e in rlds.iter_episodes(r.path)]
        for start, stop in ((0, None), (2, 4), (4, 5), (3, 3), (1, 99)):
            got = [int(e["episode_length"]) for e in rlds.iter_episodes(r.path, start, stop)]
            assert got == every[start:stop], (start, stop)

    def test_corrupt_input_in_a_parallel_write(tmp_path: Path) -> None:
        task = write_synthetic_task(tmp_path / "data_npz", ENV_ID, [10, 11, 12, 13])
        bad = task / "train_data_3.npz"  # in the second writer's share
        bad.write_bytes(bad.read_bytes()[:3000])
        out = tmp_path / "data_lerobot"
        with pytest.raises((DatasetFormatError, EpisodeFormatError), match=re.escape(str(bad))):
            lr.convert_npz_to_lerobot(task, out, workers=2)
        assert list(out.iterdir()) == []  # staging and the writers' parts removed

    def test_numpy_2_4_is_refused_before_writing(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch
    ) -> None:
        """lerobot 0.4's save_episode fails on numpy >= 2.4 (float() of shape-(1,) arrays,
        seen with lerobot's own environment on a machine with a GPU): the converter says so and writes nothing."""
        task = write_synthetic_task(tmp_path / "data_npz", ENV_ID, [10])
        monkeypatch.setattr(lerobot_write.np, "__version__", "2.4.6")
        with pytest.raises(RuntimeError, match=r"numpy 2\.4\.6.*numpy<2\.4"):
            lr.convert_npz_to_lerobot(task, tmp_path / "data_lerobot")
        assert not (tmp_path / "data_lerobot").exists() or not any((tmp_path / "data_lerobot").iterdir())

    def test_writer_process_error_carries_its_traceback(tmp_path: Path) -> None:
        """An error inside a writer process reaches the caller with that process's frames."""
        task = write_synthetic_task(tmp_path / "data_npz", ENV_ID, [10, 11, 12, 13])
        bad = task / "train_data_3.npz"
        bad.write_bytes(bad.read_bytes()[:3000])
        with pytest.raises((DatasetFormatError, EpisodeFormatError)) as caught:
            lr.convert_npz_to_lerobot(task, tmp_path / "data_lerobot", workers=2)
        notes = "\n".join(getattr(caught.value, "__notes__", []))
        assert "in LeRobot writer process" in notes and "Traceback" in notes

    def test_corrupt_input_names_the_file_and_writes_nothing(tmp_path: Path) -> None:
        task = write_synthetic_task(tmp_path / "data_npz", ENV_ID, [10, 11])
        bad = task / "train_data_1.npz"
        bad.write_bytes(bad.read_bytes()[:3000])
        out = tmp_path / "data_lerobot"
        with pytest.raises((DatasetFormatError, EpisodeFormatError), match=re.escape(str(bad))):
            lr.convert_npz_to_lerobot(task, out)
        assert list(out.iterdir()) == []  # the staging directory was removed

    def test_corrupt_rlds_shard_names_the_shard(tmp_path: Path) -> None:
        task = write_synthetic_task(tmp_path / "data_npz", ENV_ID, [10, 11])
        r = rlds.convert_npz_to_rlds(task, tmp_path / "data_rlds")
        shard = rlds.shard_files(r.path)[0]
        shard.write_bytes(shard.read_bytes()[: shard.stat().st_size - 500])
        with pytest.raises(DatasetFormatError, match=re.escape(str(shard))):
            lr.convert_rlds_to_lerobot(r.path, tmp_path / "data_lerobot")
        assert list((tmp_path / "data_lerobot").iterdir()) == []

    def test_cli_to_lerobot_from_auto(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
        """Straight after ``mikasa-collect`` (NPZ only) ``to-lerobot`` needs no ``--from``:
        the default ``auto`` reads NPZ and says so; once an RLDS copy exists it reads that."""
        task = write_synthetic_task(tmp_path / "data_npz", ENV_ID, [10, 12])
        args = ["to-lerobot", "--root", str(tmp_path), "--no-videos"]
        assert cli.main([*args, "--task", ENV_ID]) == 0
        out = capsys.readouterr().out
        assert f"to-lerobot {NAME}: from NPZ {task}\n" in out
        assert f"to-lerobot {NAME}: 2 episodes, 22 frames" in out
        assert len(load_episodes(tmp_path / "data_lerobot" / NAME)) == 2
        rlds.convert_npz_to_rlds(task, tmp_path / "data_rlds")
        assert cli.main([*args, "--all", "--lerobot-root", str(tmp_path / "b")]) == 0
        out = capsys.readouterr().out
        assert f"to-lerobot {NAME}: from RLDS {tmp_path / 'data_rlds' / NAME}\n" in out
        assert len(load_episodes(tmp_path / "b" / NAME)) == 2

    def test_cli_to_lerobot(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
        write_synthetic_task(tmp_path / "data_npz", ENV_ID, [10, 12])
        write_synthetic_task(tmp_path / "data_npz", "ShellGameTouch-VLA-v0", [11])
        root = ["--root", str(tmp_path)]
        assert cli.main(["to-lerobot", *root, "--all", "--from", "npz"]) == 0
        out = capsys.readouterr().out
        assert (
            f"to-lerobot {NAME}: 2 episodes, 22 frames" in out
            and "shell_game_touch_vla_v0: 1 episodes" in out
        )
        assert cli.main(["to-rlds", *root, "--all"]) == 0
        assert (
            cli.main(["to-lerobot", *root, "--task", ENV_ID, "--lerobot-root", str(tmp_path / "b")])
            == 0
        )
        assert (
            cli.main(["to-lerobot", *root, "--task", ENV_ID, "--lerobot-root", str(tmp_path / "b")])
            == 1
        )
        assert "already exists" in capsys.readouterr().err
        assert (
            cli.main(
                [
                    "to-lerobot",
                    *root,
                    "--all",
                    "--lerobot-root",
                    str(tmp_path / "b"),
                    "--resume",
                    "--fps",
                    "10",
                ]
            )
            == 0
        )
        assert "kept existing" in capsys.readouterr().out
        assert (
            cli.main(["validate", str(tmp_path / "data_lerobot"), str(tmp_path / "b" / NAME)]) == 0
        )
        assert cli.main(["to-lerobot", *root, "--task", "NoSuchTask-VLA-v0"]) == 1
        assert "no_such_task_vla_v0" in capsys.readouterr().err
