#!/usr/bin/env bash
# The lerobot side of the lent GPU machine (offline; Python 3.12, torch 2.11 + torchvision
# 0.26 preinstalled), in two halves:
#
#   bash baselines/lerobot/gpu_bundle.sh download     # here: the wheels, into .carry/lerobot_wheels/ (~56 MB)
#   source baselines/lerobot/gpu_bundle.sh env        # there, in each call's command
#
# "download" fetches lerobot 0.4.4 (--no-deps) and what its dataset, training and the two
# policies' code import beyond the image (the list below), for cp312 manylinux. The folder
# is git-ignored (.carry/); carried alone with the tracked tree it stays under the 64 MiB a
# call may carry, so it travels in a call of its own, without .gpu.
#
# "env" (sourced, on the GPU machine) installs carried wheels into /tmp/lrsite when they
# came with this call (a warm machine keeps /tmp between calls: later calls need not carry
# them), gives torchcodec an FFmpeg, and exports the variables every call needs: the
# simulator's site from an earlier `.gpu/run.sh` call (/tmp/site, /tmp/site2; the mesh cache
# and IPython stub copied to /tmp/mikasa-gpu by that call, see README.md), Vulkan, and
# PYTHONPATH with /tmp/lrsite first (its huggingface-hub 0.35 must shadow the image's 1.x).
#
# FFmpeg: torchcodec (lerobot's default video backend) links against FFmpeg's shared
# libraries, which the image lacks. The PyAV wheel lerobot needs anyway bundles FFmpeg 7.1
# (with the dav1d AV1 decoder) under hashed file names; links under the names torchcodec's
# FFmpeg-7 core asks for (libavcodec.so.61, ...) in /tmp/avlink, on LD_LIBRARY_PATH, let it
# load them. Checked on the 2-core machine: torchcodec 0.13 decodes the converter's AV1
# videos that way (`torchcodec._core.get_ffmpeg_library_versions()` -> 7.1.1).

_here=$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)
_root=$(cd "$_here/../.." && pwd)
_wheels=$_root/.carry/lerobot_wheels

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
)

_download() {
  rm -rf "$_wheels.partial" && mkdir -p "$_wheels.partial"
  python3 -m pip download -q --no-deps --only-binary=:all: --python-version 3.12 --implementation cp \
    --platform manylinux_2_28_x86_64 --platform manylinux_2_17_x86_64 --platform manylinux2014_x86_64 \
    -d "$_wheels.partial" "${LEROBOT_GPU_WHEELS[@]}" 2>&1 | grep -v "^WARNING: Location" || true
  [ "$(ls "$_wheels.partial" | wc -l)" -eq "${#LEROBOT_GPU_WHEELS[@]}" ] || { echo "download incomplete"; return 1; }
  rm -rf "$_wheels" && mv "$_wheels.partial" "$_wheels"
  grep -qx '/.carry/' "$_root/.git/info/exclude" 2>/dev/null || grep -q '^\.carry' "$_root/.gitignore" \
    || echo "note: .carry/ is not ignored by git here"
  du -sh "$_wheels"
}

_env() {
  if [ -d "$_wheels" ]; then
    rm -rf /tmp/lrsite
    python3 -m pip install -q --no-index --no-deps --no-compile --target /tmp/lrsite "$_wheels"/*.whl \
      >/tmp/lrsite-install.log 2>&1 || { echo "lerobot wheel install failed: /tmp/lrsite-install.log"; return 1; }
  fi
  [ -d /tmp/lrsite/av.libs ] || { echo "no /tmp/lrsite: carry .carry/lerobot_wheels once"; return 1; }
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

case "${1:-}" in
  download) _download ;;
  env) _env ;;
  *) echo "usage: bash $0 download | source $0 env"; false ;;
esac
