#!/usr/bin/env bash
# Create the optional dataset-conversion environment `.venv-datasets` (RLDS + LeRobot).
#
# Why a separate environment: lerobot 0.4.x (the line that writes LeRobotDataset v3.0 on
# Python 3.11) pins torch<2.11, while this repository's dev environment runs torch 2.13.0
# CPU (the only torch on this machine's local wheel cache; any other version pulls multi-GB
# CUDA wheels). TensorFlow and lerobot *can* share one environment, so RLDS and LeRobot live
# together here: the RLDS -> LeRobot converter needs both in one process.
#
# What it installs (see packages/mikasa-datasets/README.md, "Conversion environment"):
#   * FFmpeg shared libraries (Debian `ffmpeg`): torchcodec, the decoder LeRobotDataset uses
#     to read videos back, links against them. Encoding uses PyAV's bundled FFmpeg.
#   * tensorflow-cpu + tensorflow-datasets           (mikasa-datasets[rlds])
#   * torch 2.13.0 CPU, torchvision 0.28.0, torchcodec 0.13.0 (the torchcodec built for
#     torch 2.13), lerobot 0.4.4 with --no-deps plus exactly the runtime dependencies its
#     dataset code imports                            (mikasa-datasets[lerobot])
#   * mikasa-datasets itself, editable, with --no-deps: the converters import only numpy,
#     mikasa_datasets and the format libraries, never mikasa-envs / ManiSkill.
#
# Idempotent: a stamp file records the pinned set; re-running with the same pins is a no-op.
# Usage: scripts/setup_datasets_envs.sh     (env: PYTHON=python3.11, MIKASA_DATASETS_VENV=path)
set -euo pipefail
root=$(cd "$(dirname "$0")/.." && pwd)
cd "$root"
PYTHON=${PYTHON:-python3.11}
VENV=${MIKASA_DATASETS_VENV:-$root/.venv-datasets}
SUDO=""; [ "$(id -u)" -eq 0 ] || SUDO="sudo"

# Pinned set. Keep in sync with [project.optional-dependencies] of
# packages/mikasa-datasets/pyproject.toml (tests/test_validate.py checks every extra is here).
PINS=(
  "tensorflow-cpu==2.21.0"
  "tensorflow-datasets==4.9.10"
  # TFDS 4.9.10 touches importlib_resources for builders defined in an installed package
  # but does not declare it on Python >= 3.9.
  "importlib-resources>=6"
  "isal==1.9.1"
  "google-crc32c==1.9.0"
  "torch==2.13.0"
  "torchvision==0.28.0"
  "torchcodec==0.13.0"
  "av>=15,<16"
  "datasets>=4.0,<5"
  "huggingface-hub>=0.34.2,<0.36"
  "accelerate>=1.10,<2"
  "pandas>=2.2,<3"
  "numpy>=1.26,<2.4"
  "pyarrow>=15"
  "Pillow>=10"
  "pytest>=8"
)
LEROBOT="lerobot==0.4.4"
stamp_text="$(printf '%s\n' "${PINS[@]}" "$LEROBOT")"
stamp="$VENV/.mikasa-datasets-env"

# 1. FFmpeg shared libraries (torchcodec dlopens libavcodec & co.).
if ! ldconfig -p 2>/dev/null | grep -q 'libavcodec\.so\.'; then
  echo "[datasets-env] installing FFmpeg shared libraries (apt: ffmpeg)"
  t0=$SECONDS
  $SUDO apt-get update -qq
  DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq --no-install-recommends ffmpeg >/dev/null
  echo "[datasets-env] ffmpeg: $((SECONDS - t0)) s"
fi

if [ -x "$VENV/bin/python" ] && [ -f "$stamp" ] && [ "$(cat "$stamp")" = "$stamp_text" ]; then
  # Still refresh the editable install (cheap) in case the checkout moved.
  "$VENV/bin/python" -m pip install -q --no-deps -e packages/mikasa-datasets
  echo "[datasets-env] up to date: $VENV"
  exit 0
fi

# 2. The virtual environment.
if [ ! -x "$VENV/bin/python" ]; then
  echo "[datasets-env] creating $VENV"
  "$PYTHON" -m venv "$VENV"
fi
rm -f "$stamp"
"$VENV/bin/python" -m pip install -q --upgrade pip 2> >(grep -v "is ignored: it is neither" >&2)
t0=$SECONDS
# One resolver run for everything but lerobot, so torchvision/torchcodec are matched to the
# CPU torch 2.13.0 instead of dragging in another torch.
# (the grep drops pip's notes about this machine's partial local package mirrors)
"$VENV/bin/python" -m pip install -q "${PINS[@]}" 2> >(grep -v "is ignored: it is neither" >&2)
echo "[datasets-env] format libraries: $((SECONDS - t0)) s"
# lerobot without its dependency pins (torch<2.11, torchvision<0.26, wandb, ...): its dataset
# code needs only what PINS already holds.
"$VENV/bin/python" -m pip install -q --no-deps "$LEROBOT" 2> >(grep -v "is ignored: it is neither" >&2)
"$VENV/bin/python" -m pip install -q --no-deps -e packages/mikasa-datasets
printf '%s' "$stamp_text" > "$stamp"
echo "[datasets-env] done in $((SECONDS - t0)) s: $VENV/bin/mikasa-datasets --help"
