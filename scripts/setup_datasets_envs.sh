#!/usr/bin/env bash
# Create the optional LeRobot/RLDS environment `.venv-datasets`: dataset conversion (RLDS +
# LeRobot) and LeRobot policies on the MIKASA tasks (`mikasa-bench run --policy lerobot:DIR`,
# `lerobot-eval --env.type=mikasa`).
#
# Why a separate environment: lerobot 0.4.x (the line that writes LeRobotDataset v3.0 on
# Python 3.11) pins torch<2.11, while this repository's dev environment runs torch 2.13.0
# CPU (a CUDA torch would pull multi-GB wheels). TensorFlow and lerobot *can* share one environment, so RLDS and LeRobot live
# together here: the RLDS -> LeRobot converter needs both in one process.
#
# What it installs (see packages/mikasa-datasets/README.md, "Conversion environment", and
# packages/mikasa-bench/README.md, "LeRobot policies and lerobot-eval"):
#   * FFmpeg shared libraries (Debian `ffmpeg`): torchcodec, the decoder LeRobotDataset uses
#     to read videos back, links against them. Encoding uses PyAV's bundled FFmpeg.
#   * tensorflow-cpu + tensorflow-datasets           (mikasa-datasets[rlds])
#   * torch 2.13.0 CPU, torchvision 0.28.0, torchcodec 0.13.0 (the torchcodec built for
#     torch 2.13), lerobot 0.4.4 with --no-deps plus exactly the runtime dependencies its
#     dataset code imports                            (mikasa-datasets[lerobot])
#   * mikasa-datasets itself, editable, with --no-deps: the converters import only numpy,
#     mikasa_datasets and the format libraries, never mikasa-envs / ManiSkill.
#   * mikasa-envs, mikasa-wrappers, mikasa-oracles, mikasa-bench, editable, with their
#     dependencies (mani-skill==3.0.1, sapien==3.0.3, gymnasium, ...), and the runtime
#     dependencies of lerobot's policy and evaluation code (draccus, deepdiff, diffusers for
#     Diffusion Policy, imageio, jsonlines), resolved in one pip run together with the pins
#     above so the CPU torch 2.13.0 and numpy<2.4 stay (lerobot's own metadata would ask
#     for torch<2.11). Then `python -m mikasa_envs.setup_assets`, as scripts/setup.sh does:
#     the envs use only the robot assets shipped in the mani-skill wheel plus the light
#     meshes generated from them, so ManiSkill never prompts for or starts a download.
#   * baselines/memory (the memory_gru LeRobot policy plugin), editable, with --no-deps.
#   * a start-up hook that makes `import torchvision` work in every Python process of the
#     environment (plain `lerobot-train`, `lerobot-eval`, `python -c "import torchvision"`):
#     PyPI's torchvision 0.28.0 is a CUDA build whose `_C` ops library cannot load next to
#     the CPU torch, and its import then dies with "operator torchvision::nms does not
#     exist". packages/mikasa-datasets/src/mikasa_datasets/torchvision_cpu.py is copied into
#     site-packages as `_mikasa_torchvision_cpu.py` with `_mikasa_torchvision_cpu.pth`, whose
#     line installs a lazy import hook (nothing is imported at start-up; see that module).
#
# Idempotent: a stamp file records the pinned set; re-running with the same pins is a no-op
# apart from refreshing the editable installs and the torchvision hook when they changed.
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
  "absl-py>=1.0"
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
# The MIKASA envs and mikasa-bench (editable), and what lerobot's policy / eval code imports
# beyond PINS (lerobot.policies.factory, lerobot.envs.factory, lerobot.scripts.lerobot_eval;
# the bounds are lerobot 0.4.4's). Installed with PINS in one resolver run (step 3).
ENV_PACKAGES=(
  "-e" "packages/mikasa-envs"
  "-e" "packages/mikasa-wrappers"
  "-e" "packages/mikasa-oracles"
  "-e" "packages/mikasa-bench"
)
# The memory baseline, a LeRobot policy plugin (baselines/memory/README.md): editable and
# --no-deps, like mikasa-datasets (its lerobot requirement would drag in lerobot's pins).
MEMORY_BASELINE=("-e" "baselines/memory")
LEROBOT_RUNTIME=(
  "draccus==0.10.0"
  "gymnasium>=1.1.1,<2"
  "deepdiff>=7.0.1,<9"
  "diffusers>=0.27.2,<0.36"
  "imageio[ffmpeg]>=2.34,<3"
  "jsonlines>=4,<5"
  "termcolor>=2.4,<4"
  "einops>=0.8,<0.9"
  # lerobot.envs.configs imports lerobot.robots, whose motor buses import `serial`.
  "pyserial>=3.5,<4"
)
stamp_text="$(printf '%s\n' "${PINS[@]}" "$LEROBOT" "${ENV_PACKAGES[@]}" "${LEROBOT_RUNTIME[@]}")"
stamp="$VENV/.mikasa-datasets-env"

# 1. FFmpeg shared libraries (torchcodec dlopens libavcodec & co.).
if ! ldconfig -p 2>/dev/null | grep -q 'libavcodec\.so\.'; then
  echo "[datasets-env] installing FFmpeg shared libraries (apt: ffmpeg)"
  t0=$SECONDS
  $SUDO apt-get update -qq
  DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq --no-install-recommends ffmpeg >/dev/null
  echo "[datasets-env] ffmpeg: $((SECONDS - t0)) s"
fi

# The editable installs are refreshed when the checkout moved or a package's pyproject.toml
# changed (entry points, ...): five editable builds cost ~20 s, and the test suite runs this
# script before each of its .venv-datasets test files.
EDITABLE_DIRS=(packages/mikasa-datasets packages/mikasa-envs packages/mikasa-wrappers
  packages/mikasa-oracles packages/mikasa-bench baselines/memory)
editable_stamp="$VENV/.mikasa-editable"
editable_text="$root $(cat "${EDITABLE_DIRS[@]/%//pyproject.toml}" | sha256sum | cut -c1-16)"
editables_current() {
  [ -f "$editable_stamp" ] && [ "$(cat "$editable_stamp")" = "$editable_text" ] &&
    "$VENV/bin/python" - "$root" <<'PY'
import importlib.util, sys
root = sys.argv[1] + "/"
names = ("mikasa_datasets", "mikasa_envs", "mikasa_wrappers", "mikasa_oracles", "mikasa_bench",
         "lerobot_policy_memory_gru")
specs = [importlib.util.find_spec(n) for n in names]  # locates, does not import
sys.exit(0 if all(s is not None and (s.origin or "").startswith(root) for s in specs) else 1)
PY
}

# The torchvision start-up hook (see the header). Compared by content, not by a stamp, on
# every run: an edited hook module, or a hook file removed from site-packages, is
# (re)installed without touching anything else.
hook_src="$root/packages/mikasa-datasets/src/mikasa_datasets/torchvision_cpu.py"
hook_pth_line="import _mikasa_torchvision_cpu; _mikasa_torchvision_cpu.install()"
install_torchvision_hook() {
  local site
  site=$("$VENV/bin/python" -I -c 'import sysconfig; print(sysconfig.get_paths()["purelib"])')
  if ! cmp -s "$hook_src" "$site/_mikasa_torchvision_cpu.py" ||
    [ "$(cat "$site/_mikasa_torchvision_cpu.pth" 2>/dev/null)" != "$hook_pth_line" ]; then
    cp "$hook_src" "$site/_mikasa_torchvision_cpu.py"
    printf '%s\n' "$hook_pth_line" > "$site/_mikasa_torchvision_cpu.pth"
    # its bytecode now, also where PYTHONDONTWRITEBYTECODE is set: every start loads it
    "$VENV/bin/python" -I -m py_compile "$site/_mikasa_torchvision_cpu.py"
    echo "[datasets-env] torchvision import hook installed: $site/_mikasa_torchvision_cpu.pth"
  fi
}

if [ -x "$VENV/bin/python" ] && [ -f "$stamp" ] && [ "$(cat "$stamp")" = "$stamp_text" ]; then
  if ! editables_current; then
    "$VENV/bin/python" -m pip install -q --no-deps -e packages/mikasa-datasets "${ENV_PACKAGES[@]}" \
      "${MEMORY_BASELINE[@]}"
    printf '%s' "$editable_text" > "$editable_stamp"
  fi
  install_torchvision_hook
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
# (the grep drops pip's notes about local package mirrors it cannot read)
"$VENV/bin/python" -m pip install -q "${PINS[@]}" 2> >(grep -v "is ignored: it is neither" >&2)
echo "[datasets-env] format libraries: $((SECONDS - t0)) s"
# lerobot without its dependency pins (torch<2.11, torchvision<0.26, wandb, ...): its dataset
# code needs only what PINS already holds.
"$VENV/bin/python" -m pip install -q --no-deps "$LEROBOT" 2> >(grep -v "is ignored: it is neither" >&2)
"$VENV/bin/python" -m pip install -q --no-deps -e packages/mikasa-datasets
# 3. The MIKASA envs + mikasa-bench and lerobot's policy/eval runtime. PINS are repeated so
# this resolver run keeps torch 2.13.0 CPU, torchvision and numpy<2.4 where they are.
t1=$SECONDS
# (the grep also drops pip's report that the --no-deps lerobot's own pins are unmet: known,
# see above; a conflict of any other package still shows)
"$VENV/bin/python" -m pip install -q "${PINS[@]}" "${LEROBOT_RUNTIME[@]}" "${ENV_PACKAGES[@]}" \
  2> >(grep -v -e "is ignored: it is neither" -e "^lerobot [0-9.]* requires " \
    -e "^ERROR: pip's dependency resolver does not currently take" >&2)
"$VENV/bin/python" -m pip install -q --no-deps "${MEMORY_BASELINE[@]}"
# The light robot meshes, generated from the mani-skill wheel's own assets (no download).
"$VENV/bin/python" -m mikasa_envs.setup_assets >/dev/null
echo "[datasets-env] envs + lerobot policy/eval runtime: $((SECONDS - t1)) s"
install_torchvision_hook
printf '%s' "$editable_text" > "$editable_stamp"
printf '%s' "$stamp_text" > "$stamp"
echo "[datasets-env] done in $((SECONDS - t0)) s: $VENV/bin/mikasa-datasets --help"
