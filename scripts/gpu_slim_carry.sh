#!/usr/bin/env bash
# An offline GPU machine takes uploads of at most 64 MiB (tracked tree + extra paths), and
# .gpu/ (the simulator's wheels and caches for that machine) is ~54 MiB, which with the tracked tree
# (~10 MiB) leaves no room for a run's resume.pt. This packs .gpu/ smaller: the sapien wheel
# travels as an xz tarball of its contents (28 MB instead of 39 MB), the rest as one xz tarball.
#
#   bash scripts/gpu_slim_carry.sh pack      # here, once after gpu-carry.sh: .gpu/ -> .gpux/ (~43 MiB)
#   bash scripts/gpu_slim_carry.sh unpack    # there, first in each command (upload .gpux and .gl):
#                                            # .gpux/ -> .gpu/, then .gpu/run.sh as usual
#
# Example: `bash scripts/gpu_slim_carry.sh unpack && .gpu/run.sh <command>`, uploading
# .gpux, .gl and the run's resume.pt. .gpu/ is not kept between commands (it is git-ignored
# and not uploaded), so every command unpacks (a few seconds).
set -euo pipefail
cd "$(dirname "$0")/.."
case "${1:-}" in
  pack)
    [ -d .gpu/whl ] || { echo ".gpu/whl missing: build .gpu first (../shared/device/gpu-carry.sh)"; exit 1; }
    grep -qx '/.gpux/' .git/info/exclude 2>/dev/null || echo /.gpux/ >>.git/info/exclude
    tmp=$(mktemp -d); trap 'rm -rf "$tmp"' EXIT
    rm -rf .gpux.tmp && mkdir -p .gpux.tmp "$tmp/slim"
    cp -r .gpu "$tmp/slim/"
    for whl in .gpu/whl/sapien-*.whl; do
      name=$(basename "$whl" .whl); rm "$tmp/slim/.gpu/whl/$name.whl"
      mkdir -p "$tmp/$name" && (cd "$tmp/$name" && python3 -m zipfile -e "$OLDPWD/$whl" .)
      tar cf - -C "$tmp/$name" . | xz -T0 -9 >".gpux.tmp/$name.tar.xz"
    done
    tar cf - -C "$tmp/slim" .gpu | xz -T0 -6 >.gpux.tmp/gpu.tar.xz
    rm -rf .gpux && mv .gpux.tmp .gpux   # nothing half-written is left under .gpux
    du -sh .gpux ;;
  unpack)
    tar xJf .gpux/gpu.tar.xz
    for t in .gpux/*.tar.xz; do
      [ "$t" = .gpux/gpu.tar.xz ] && continue
      name=$(basename "$t" .tar.xz); dir=/tmp/unpack_$name
      rm -rf "$dir" && mkdir -p "$dir" && tar xJf "$t" -C "$dir"
      # A wheel is a zip of its files; pip checks them against the RECORD inside, not the zip.
      python3 - "$dir" ".gpu/whl/$name.whl" <<'PY'
import os, sys, zipfile
src, out = sys.argv[1], sys.argv[2]
with zipfile.ZipFile(out, "w", zipfile.ZIP_STORED) as archive:
    for base, _, files in os.walk(src):
        for f in files:
            path = os.path.join(base, f)
            archive.write(path, os.path.relpath(path, src))
PY
    done ;;
  *) echo "usage: bash scripts/gpu_slim_carry.sh pack|unpack (got '${1:-}')"; exit 2 ;;
esac
