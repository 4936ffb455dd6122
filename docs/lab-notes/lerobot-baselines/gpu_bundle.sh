#!/usr/bin/env bash
# The lerobot side of a machine with a GPU (offline; Python 3.12, torch 2.11 + torchvision
# 0.26 preinstalled), in two halves:
#
#   bash docs/lab-notes/lerobot-baselines/gpu_bundle.sh download     # here: the wheels, into .carry/ (~91 MB)
#   source docs/lab-notes/lerobot-baselines/gpu_bundle.sh env        # there, at the start of each command
#   bash docs/lab-notes/lerobot-baselines/gpu_bundle.sh check        # there, after env: what imports, what is missing
#
# "download" fetches lerobot 0.4.4 (--no-deps) and what its dataset, training and the two
# policies' code import beyond the image (the list below), for cp312 manylinux, into
# .carry/lerobot_wheels/ (~51 MB) and .carry/lerobot_av/ (PyAV, ~40 MB), both git-ignored:
# with the tracked tree each fits in one upload of at most 64 MiB to the offline machine, so
# each goes up in a command of its own (in either order), without .gpu.
#
# "env" (sourced, on the offline machine with the GPU) installs uploaded wheels into /tmp/lrsite
# when they came with this command, and stops with a message until both halves are there (the
# machine keeps /tmp between commands while it stays up: later commands need not upload them),
# gives torchcodec an FFmpeg, and exports the variables every command needs: the simulator's
# site from an earlier `.gpu/run.sh` command (/tmp/site, /tmp/site2; the mesh cache and
# IPython stub copied to /tmp/mikasa-gpu by that command, see README.md), Vulkan, and
# PYTHONPATH with /tmp/lrsite first (its huggingface-hub 0.35 must shadow the image's 1.x).
#
# FFmpeg: torchcodec (lerobot's default video backend) links against FFmpeg's shared
# libraries, which the image lacks. The PyAV wheel lerobot needs anyway bundles FFmpeg 7.1
# (with the dav1d AV1 decoder) under hashed file names; links under the names torchcodec's
# FFmpeg-7 core asks for (libavcodec.so.61, ...) in /tmp/avlink, on LD_LIBRARY_PATH, let it
# load them. Checked on a 2-core CPU machine: torchcodec 0.13 decodes the converter's AV1
# videos that way (`torchcodec._core.get_ffmpeg_library_versions()` -> 7.1.1).

_here=$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)
_root=$(cd "$_here/../../.." && pwd)
_wheels=$_root/.carry/lerobot_wheels
_av=$_root/.carry/lerobot_av  # PyAV alone (40 MB): with the rest, one carry would pass 64 MiB

LEROBOT_GPU_WHEELS=(
  "lerobot==0.4.4" "draccus==0.10.0" "mergedeep==1.3.4" "pyyaml-include==1.4.1" "toml==0.10.2"
  "typing-inspect==0.9.0" "mypy-extensions==1.2.0"
  "datasets==4.8.5" "dill==0.4.1" "multiprocess==0.70.19" "xxhash==4.1.0" "fsspec==2026.2.0"
  "huggingface-hub==0.35.3" "hf-xet==1.8.0"
  "av==15.1.0" "torchcodec==0.11.*"  # torchcodec 0.N is built for torch 2.N
  "diffusers==0.35.2" "regex==2026.11.19" "importlib-metadata==10.2.0" "zipp==4.1.2"
  "deepdiff==8.6.2" "orderly-set==5.5.0" "jsonlines==4.0.0" "termcolor==3.3.0" "pyserial==3.5"
  "aiohttp==3.14.5" "aiohappyeyeballs==2.7.1" "aiosignal==1.4.0" "frozenlist==1.8.0"
  "multidict==7.2.1" "propcache==0.5.4" "yarl==1.25.1" "attrs==26.1.0"
  # imported on the way (checked in the CPU machine's .venv-datasets): datasets' file utils
  # (httpx), lerobot.utils.io_utils (imageio), the GR00T policy module that the policy
  # factory imports (dm-tree and its needs)
  "httpx==0.28.1" "httpcore==1.0.9" "h11==0.16.0" "anyio==4.16.0" "imageio==2.38.1"
  "dm-tree==0.1.10" "absl-py==2.5.1" "wrapt==2.5.2"
  # The image's transformers 5.x needs huggingface-hub 1.x; lerobot imports transformers
  # whenever it is installed (lerobot.processor), so it gets the one its own
  # `transformers-dep` extra names, which works with hub 0.35
  "transformers==4.57.6" "tokenizers==0.22.2"
  # numpy 2.4 turns lerobot 0.4's float(shape-(1,) array) in save_episode (rewards, done
  # flags) into a TypeError; the image has 2.4, and mikasa-datasets' lerobot extra pins <2.4
  "numpy==2.3.5"
)

_download() {
  rm -rf "$_wheels.partial" && mkdir -p "$_wheels.partial"
  python3 -m pip download -q --no-deps --only-binary=:all: --python-version 3.12 --implementation cp \
    --platform manylinux_2_28_x86_64 --platform manylinux_2_17_x86_64 --platform manylinux2014_x86_64 \
    -d "$_wheels.partial" "${LEROBOT_GPU_WHEELS[@]}" 2>&1 | grep -v "^WARNING: Location" || true
  [ "$(ls "$_wheels.partial" | wc -l)" -eq "${#LEROBOT_GPU_WHEELS[@]}" ] || { echo "download incomplete"; return 1; }
  rm -rf "$_wheels" "$_av" && mkdir -p "$_av" && mv "$_wheels.partial"/av-*.whl "$_av"/ \
    && mv "$_wheels.partial" "$_wheels"
  grep -qx '/.carry/' "$_root/.git/info/exclude" 2>/dev/null || grep -q '^\.carry' "$_root/.gitignore" \
    || echo "note: .carry/ is not ignored by git here"
  du -sh "$_wheels" "$_av"
}

_env() {
  local d
  for d in "$_wheels" "$_av"; do
    [ -d "$d" ] || continue
    python3 -m pip install -q --upgrade --no-index --no-deps --no-compile --target /tmp/lrsite "$d"/*.whl \
      >/tmp/lrsite-install.log 2>&1 || { echo "wheel install failed: /tmp/lrsite-install.log"; return 1; }
  done
  [ -d /tmp/lrsite/lerobot ] || { echo "no lerobot in /tmp/lrsite: carry .carry/lerobot_wheels once"; return 1; }
  [ -d /tmp/lrsite/av.libs ] || { echo "no PyAV in /tmp/lrsite: carry .carry/lerobot_av once"; return 1; }
  [ -d /tmp/site2 ] && [ -d /tmp/mikasa-gpu/cache ] || { echo "no simulator site: run the .gpu/run.sh call first (README.md)"; return 1; }
  rm -rf /tmp/avlink && mkdir -p /tmp/avlink
  local f lib
  for f in /tmp/lrsite/av.libs/*; do ln -s "$f" "/tmp/avlink/$(basename "$f")"; done
  for lib in avcodec.so.61 avformat.so.61 avutil.so.59 swresample.so.5 swscale.so.8 avdevice.so.61 avfilter.so.10; do
    ln -s /tmp/lrsite/av.libs/lib"${lib%%.so.*}"-*.so."${lib##*.so.}"* "/tmp/avlink/lib$lib"
  done
  export LD_LIBRARY_PATH=/tmp/avlink${LD_LIBRARY_PATH:+:$LD_LIBRARY_PATH}
  export VK_DRIVER_FILES=/usr/local/nvidia/share/vulkan/icd.d/nvidia_icd.json
  export __EGL_VENDOR_LIBRARY_FILENAMES=/usr/local/nvidia/share/glvnd/egl_vendor.d/10_nvidia.json
  export PYTHONPATH=/tmp/lrsite:/tmp/site2:/tmp/site:/tmp/mikasa-gpu/stub
  export PATH=/tmp/lrsite/bin:/tmp/site2/bin:/tmp/site/bin:$PATH
  export MIKASA_CACHE_DIR=/tmp/mikasa-gpu/cache PYTHONUNBUFFERED=1
}

# The modules training and evaluation import, each tried on its own so that one call names
# every missing package (a module missing from the image: add its wheel to the list above).
_check() {
  "${PYTHON:-python3}" - <<'PY'
import importlib
import os

os.environ.setdefault("HF_HUB_OFFLINE", "1")
try:  # the project's torchvision guard (a no-op where torchvision matches torch)
    from mikasa_datasets.lerobot import ensure_torchvision_importable

    ensure_torchvision_importable()
except Exception as exc:  # noqa: BLE001
    print(f"FAILED  mikasa_datasets.lerobot.ensure_torchvision_importable: {exc}")

modules = [
    "torchcodec.decoders", "lerobot.datasets.lerobot_dataset", "lerobot.datasets.video_utils",
    "lerobot.policies.act.modeling_act", "lerobot.policies.diffusion.modeling_diffusion",
    "lerobot.policies.factory", "lerobot.scripts.lerobot_train", "lerobot.scripts.lerobot_eval",
    "mikasa_datasets.lerobot", "mikasa_bench.lerobot.policy", "mikasa_bench.lerobot.env",
]
missing, failed = {}, []
for name in modules:
    try:
        importlib.import_module(name)
        print(f"ok      {name}")
    except Exception as exc:  # noqa: BLE001  (report every failure, go on)
        print(f"FAILED  {name}: {type(exc).__name__}: {exc}")
        failed.append(name)
        if isinstance(exc, ModuleNotFoundError) and exc.name:
            missing.setdefault(exc.name.split(".")[0], name)
try:  # the converter's own check of the numpy it can write with
    from mikasa_datasets.lerobot_write import check_numpy_for_writing

    check_numpy_for_writing()
except Exception as exc:  # noqa: BLE001
    print(f"FAILED  numpy: {exc}")
    failed.append("numpy")
import torchcodec._core as core
print("ffmpeg:", core.get_ffmpeg_library_versions().get("ffmpeg_version"))
print("missing top-level modules:", ", ".join(missing) or "none")
raise SystemExit(f"{len(failed)} check(s) failed: {', '.join(failed)}" if failed else 0)
PY
}

case "${1:-}" in
  download) _download ;;
  env) _env ;;
  check) _check ;;
  *) echo "usage: bash $0 download | source $0 env | bash $0 check (after env)"; false ;;
esac
