"""NPZ -> RLDS export (mikasa_datasets.rlds): layout, TFDS readability, exact round trip,
output protocol (--overwrite / --resume, staging + rename), corrupt input, CLI.

Needs tensorflow-datasets: in the main environment this file contributes one test that
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
ENV_ID = "RememberColor3-VLA-v0"
NAME = "remember_color_3_vla_v0"

if not IN_DATASETS_ENV:
    from test_validate import run_suite_in_datasets_env

    def test_rlds_suite_in_datasets_env() -> None:
        """Every test below, run inside `.venv-datasets`."""
        run_suite_in_datasets_env(__file__)

else:
    import tensorflow_datasets as tfds
    from mikasa_datasets import cli, rlds
    from mikasa_datasets.loaders import (
        DatasetFormatError,
        OutputExistsError,
        load_episodes,
        write_synthetic_task,
    )
    from mikasa_datasets.npz import EpisodeFormatError

    LENGTHS = [10, 17, 33, 12]
    INSTRUCTIONS = [
        "Remember the colour of the cube, then touch the matching one.",
        "Rotate the peg by 37° — then stop.",  # non-ASCII survives the Text feature
        "Touch the red cube.",
        "Touch the blue cube.",
    ]

    @pytest.fixture
    def npz_task(tmp_path: Path) -> Path:
        return write_synthetic_task(
            tmp_path / "data_npz", ENV_ID, LENGTHS, instruction=INSTRUCTIONS, seed=5
        )

    @pytest.fixture
    def converted(npz_task: Path) -> rlds.ConversionResult:
        return rlds.convert_npz_to_rlds(npz_task, npz_task.parent.parent / "data_rlds")

    def _assert_same_episode(a: dict, b: dict, where: str) -> None:
        assert set(a) == set(b), where
        for key in a:
            assert a[key].dtype == b[key].dtype, f"{where} {key}: {a[key].dtype} != {b[key].dtype}"
            assert a[key].shape == b[key].shape, f"{where} {key}: {a[key].shape} != {b[key].shape}"
            assert np.array_equal(a[key], b[key]), f"{where} {key} differs"

    def test_layout_matches_spec(npz_task: Path, converted: rlds.ConversionResult) -> None:
        vdir = npz_task.parent.parent / "data_rlds" / NAME / "1.0.0"
        assert converted.path == vdir
        assert (converted.episodes, converted.frames) == (4, sum(LENGTHS))
        names = sorted(p.name for p in vdir.iterdir())
        shards = [n for n in names if "tfrecord" in n]
        assert shards and all(
            re.fullmatch(r"mikasa_dataset-train\.tfrecord-\d{5}-of-\d{5}", n) for n in shards
        )
        assert {"dataset_info.json", "features.json", "metadata.json"} <= set(names)
        # metadata.json is the NPZ task's file, verbatim
        assert (vdir / "metadata.json").read_bytes() == (npz_task / "metadata.json").read_bytes()
        info = json.loads((vdir / "dataset_info.json").read_text())
        assert (info["name"], info["version"]) == ("mikasa_dataset", "1.0.0")
        # nothing but the task directory was left in the RLDS root (no staging)
        assert [p.name for p in vdir.parent.parent.iterdir()] == [NAME]

    def test_readable_with_builder_from_directory(
        npz_task: Path, converted: rlds.ConversionResult
    ) -> None:
        builder = tfds.builder_from_directory(str(converted.path))
        assert builder.name == "mikasa_dataset" and str(builder.version) == "1.0.0"
        feats = builder.info.features
        obs = feats["steps"]["observation"]
        assert obs["image"].shape == (128, 128, 3) and obs["wrist_image"].shape == (128, 128, 3)
        assert obs["proprio"].shape == (7,) and obs["proprio"].np_dtype == np.float32
        assert feats["steps"]["action"].shape == (7,)
        for key in (
            "reward",
            "discount",
            "is_first",
            "is_last",
            "is_terminal",
            "language_instruction",
        ):
            assert key in feats["steps"].feature
        for key in (
            "file_path",
            "env_id",
            "episode_seed",
            "episode_length",
            "episode_index",
            "success_once",
        ):
            assert key in feats["episode_metadata"]
        assert builder.info.splits["train"].num_examples == 4
        episodes = list(tfds.as_numpy(builder.as_dataset(split="train")))
        assert len(episodes) == 4
        for i, ep in enumerate(episodes):  # stored in NPZ index order (shuffling disabled)
            steps = list(ep["steps"])
            assert len(steps) == LENGTHS[i]
            assert ep["episode_metadata"]["file_path"].decode() == f"train_data_{i}.npz"
            assert ep["episode_metadata"]["env_id"].decode() == ENV_ID
            assert int(ep["episode_metadata"]["episode_seed"]) == 5 + i
            assert [bool(s["is_first"]) for s in steps] == [t == 0 for t in range(LENGTHS[i])]
            assert [bool(s["is_last"]) for s in steps] == [
                t == LENGTHS[i] - 1 for t in range(LENGTHS[i])
            ]
            assert [bool(s["is_terminal"]) for s in steps] == [
                t == LENGTHS[i] - 1 for t in range(LENGTHS[i])
            ]
            assert all(float(s["discount"]) == 1.0 for s in steps)
            assert steps[0]["language_instruction"].decode() == INSTRUCTIONS[i]
            assert steps[0]["observation"]["image"].dtype == np.uint8

    def test_round_trip_is_exact(npz_task: Path, converted: rlds.ConversionResult) -> None:
        source = load_episodes(npz_task)
        back = load_episodes(converted.path)  # auto-detected as RLDS
        assert len(back) == len(source) == 4
        for i, (a, b) in enumerate(zip(source, back, strict=True)):
            _assert_same_episode(a, b, f"episode {i}")
        # and via the task directory (latest version) too
        _assert_same_episode(source[2], load_episodes(converted.path.parent)[2], "task dir")

    def test_tfrecord_reader_equals_tensorflows(converted: rlds.ConversionResult) -> None:
        import tensorflow as tf

        for shard in rlds.shard_files(converted.path):
            ours = list(rlds.read_tfrecords(shard))
            theirs = [r.numpy() for r in tf.data.TFRecordDataset([str(shard)])]
            assert ours == theirs and len(ours) > 0
            assert list(rlds.read_tfrecords(shard, skip=1, take=1)) == theirs[1:2]

    def test_png_encoder_is_lossless_standard_png() -> None:
        import tensorflow as tf

        rng = np.random.default_rng(0)
        for image in (
            rng.integers(0, 256, (128, 128, 3), dtype=np.uint8),
            np.zeros((128, 128, 3), np.uint8),
        ):
            decoded = tf.io.decode_png(rlds.encode_png(image)).numpy()
            assert np.array_equal(decoded, image)

    def test_png_decoder_equals_pil(tmp_path: Path) -> None:
        """Our PNGs ("Sub" rows; with some rows "None") are decoded here; PNGs with other
        filters (PIL's adaptive ones) and other colour types go to PIL; a corrupt one is
        an error."""
        import io
        import struct
        import zlib

        from PIL import Image

        rng = np.random.default_rng(4)
        images = rng.integers(0, 256, size=(3, 16, 20, 3), dtype=np.uint8)
        images[1] //= 16  # smooth enough for PIL's encoder to pick other filters
        ours = [rlds.encode_png(image) for image in images]
        assert np.array_equal(rlds.decode_pngs(ours), images)
        rows, _, _ = rlds.png_rows(ours[0])
        none_rows = bytearray(rows.tobytes())
        for r in range(0, 16, 2):  # filter byte 0 and the raw pixels on even rows
            start = r * rows.shape[1]
            none_rows[start : start + rows.shape[1]] = b"\x00" + images[0, r].tobytes()
        idat = zlib.compress(bytes(none_rows))
        mixed = ours[0][:33] + struct.pack(">I", len(idat)) + b"IDAT" + idat
        mixed += struct.pack(">I", zlib.crc32(b"IDAT" + idat)) + ours[0][-12:]
        assert np.array_equal(rlds.decode_pngs([mixed])[0], images[0])

        def pil_png(image: np.ndarray, mode: str = "RGB") -> bytes:
            buffer = io.BytesIO()
            Image.fromarray(image).convert(mode).save(buffer, format="PNG")
            return buffer.getvalue()

        theirs = [pil_png(image) for image in images]
        assert any(rlds.png_rows(p)[0][:, 0].max() > 1 for p in theirs)
        assert np.array_equal(rlds.decode_pngs(theirs), images)
        rgba = rlds.decode_pngs([pil_png(images[2], "RGBA")])
        assert rgba.shape == (1, 16, 20, 4) and np.array_equal(rgba[0, ..., :3], images[2])
        broken = bytearray(ours[2])
        broken[40] ^= 0xFF  # inside IDAT
        with pytest.raises(ValueError, match="CRC"):
            rlds.decode_pngs([bytes(broken)])

    def test_existing_output_needs_overwrite_or_resume(
        npz_task: Path, converted: rlds.ConversionResult
    ) -> None:
        rlds_root = converted.path.parent.parent
        with pytest.raises(OutputExistsError, match=re.escape(str(rlds_root / NAME))):
            rlds.convert_npz_to_rlds(npz_task, rlds_root)
        kept = rlds.convert_npz_to_rlds(npz_task, rlds_root, resume=True)
        assert kept.skipped and kept.frames == 0
        shard = rlds.shard_files(converted.path)[0]
        before = shard.stat().st_mtime_ns
        again = rlds.convert_npz_to_rlds(npz_task, rlds_root, overwrite=True)
        assert not again.skipped and rlds.shard_files(again.path)[0].stat().st_mtime_ns != before
        assert sorted(p.name for p in rlds_root.iterdir()) == [NAME]  # no staging or old copies
        with pytest.raises(ValueError, match="mutually exclusive"):
            rlds.convert_npz_to_rlds(npz_task, rlds_root, overwrite=True, resume=True)

    def test_resume_redoes_an_output_that_no_longer_matches(
        npz_task: Path, converted: rlds.ConversionResult
    ) -> None:
        rlds_root = converted.path.parent.parent
        write_synthetic_task(npz_task.parent, ENV_ID, LENGTHS + [15], seed=5)  # the source grew
        redone = rlds.convert_npz_to_rlds(npz_task, rlds_root, resume=True)
        assert not redone.skipped and redone.episodes == 5
        assert len(load_episodes(redone.path)) == 5

    def test_stale_staging_is_cleaned(npz_task: Path, tmp_path: Path) -> None:
        rlds_root = tmp_path / "data_rlds"
        stale = rlds_root / f".{NAME}.tmp-1-deadbeef"
        (stale / "_tfds").mkdir(parents=True)
        rlds.convert_npz_to_rlds(npz_task, rlds_root)
        assert not stale.exists()

    def test_corrupt_input_names_the_file_and_writes_nothing(
        npz_task: Path, tmp_path: Path
    ) -> None:
        bad = npz_task / "train_data_2.npz"
        bad.write_bytes(bad.read_bytes()[: bad.stat().st_size // 2])
        rlds_root = tmp_path / "data_rlds"
        with pytest.raises((DatasetFormatError, EpisodeFormatError), match=re.escape(str(bad))):
            rlds.convert_npz_to_rlds(npz_task, rlds_root)
        assert list(rlds_root.iterdir()) == []  # neither an output nor a staging directory

    def test_invalid_episode_names_the_file(npz_task: Path, tmp_path: Path) -> None:
        from mikasa_datasets.npz import read_episode, write_episode

        f = npz_task / "train_data_1.npz"
        ep = read_episode(f)
        ep["success_once"] = np.array(False)
        write_episode(f, ep, validate=False)
        with pytest.raises(EpisodeFormatError, match=re.escape(str(f)) + ".*success_once"):
            rlds.convert_npz_to_rlds(npz_task, tmp_path / "data_rlds")

    def test_missing_source_is_clear(tmp_path: Path) -> None:
        with pytest.raises(DatasetFormatError, match="does not exist"):
            rlds.convert_npz_to_rlds(tmp_path / "data_npz" / NAME, tmp_path / "data_rlds")
        d = write_synthetic_task(tmp_path / "data_npz", ENV_ID, [10])
        (d / "metadata.json").unlink()
        with pytest.raises(DatasetFormatError, match="metadata.json"):
            rlds.convert_npz_to_rlds(d, tmp_path / "data_rlds")

    def test_max_episodes(npz_task: Path, tmp_path: Path) -> None:
        r = rlds.convert_npz_to_rlds(npz_task, tmp_path / "data_rlds", max_episodes=2)
        assert (r.episodes, r.frames) == (2, LENGTHS[0] + LENGTHS[1])
        assert len(load_episodes(r.path)) == 2

    def test_cli_to_rlds(npz_task: Path, capsys: pytest.CaptureFixture[str]) -> None:
        root = npz_task.parent.parent
        assert cli.main(["to-rlds", "--root", str(root), "--task", ENV_ID]) == 0
        out = capsys.readouterr().out
        assert f"to-rlds {NAME}: 4 episodes, {sum(LENGTHS)} frames" in out
        assert cli.main(["to-rlds", "--root", str(root), "--all"]) == 1
        assert "already exists" in capsys.readouterr().err
        assert cli.main(["to-rlds", "--root", str(root), "--all", "--resume"]) == 0
        assert "kept existing" in capsys.readouterr().out
        assert cli.main(["to-rlds", "--root", str(root), "--task", NAME, "--overwrite-dest"]) == 0
        assert cli.main(["validate", str(root / "data_rlds" / NAME)]) == 0
        assert capsys.readouterr().out.splitlines()[-1].startswith("OK rlds")
        with pytest.raises(SystemExit):
            cli.main(["to-rlds", "--root", str(root), "--all", "--resume", "--overwrite"])
