#!/usr/bin/env bash
# Prepares a session's calls to a lent GPU machine (offline, Python 3.12, torch with CUDA, no
# MuJoCo): see README.md beside this file. Run from the repository root.
#   tools/gpu/pack.sh wheels    # .dev/a (MuJoCo, Gymnasium, MuJoCo Warp, warp.so part a), .dev/b (part b)
#   tools/gpu/pack.sh shrink    # move the large tracked files out (the tree that travels is capped at 64 MiB)
#   tools/gpu/pack.sh restore   # bring them back (run it before committing anything)
set -euo pipefail
STASH=/tmp/smpl_envs_gpu_stash
LARGE=(training docs/videos agents/pretrained tests/data)
KEEP=${KEEP:-training/recovery_basin/checkpoints/best.pt}   # files of LARGE a device command needs
case "${1:-}" in
wheels)
  grep -qx '/.dev/' .git/info/exclude || echo '/.dev/' >> .git/info/exclude
  w=/tmp/smpl_envs_gpu_wheels; mkdir -p "$w" .dev/a .dev/b
  for p in mujoco==4.0.1 mujoco-core==4.0.1 mujoco-warp==4.0.0 warp-lang==1.19.0 gymnasium farama-notifications; do
    python3 -m pip download -q --no-deps --only-binary=:all: --python-version 3.12 --implementation cp \
      --platform manylinux_2_28_x86_64 --platform manylinux_2_27_x86_64 --platform manylinux_2_17_x86_64 \
      --platform manylinux2014_x86_64 -d "$w" "$p" 2>&1 | grep -v '^WARNING: Location' || true
  done
  # warp-lang's wheel (149 MB) is over one call's cap: its Python tree travels as it is, warp.so
  # (299 MB, the CUDA compiler inside) xz-compressed in two parts, one per call; warp-clang.so
  # (Warp's CPU device only) stays behind.
  x="$w/warp"; rm -rf "$x"; mkdir -p "$x"; unzip -q "$w"/warp_lang-*.whl -d "$x"
  tar -C "$x" --exclude='warp/bin/*.so' --exclude=warp/examples --exclude=warp/tests -cJf .dev/a/warp_py.tar.xz warp
  [ -f "$w/warp.so.xz" ] || xz -T0 -9 -c "$x/warp/bin/warp.so" > "$w/warp.so.xz"
  split -b 40000000 -a 1 "$w/warp.so.xz" "$w/part_"
  mv "$w/part_a" .dev/a/warp.so.xz.part_a; mv "$w/part_b" .dev/b/warp.so.xz.part_b
  cp "$w"/mujoco-*.whl "$w"/mujoco_core-*.whl "$w"/mujoco_warp-*.whl "$w"/gymnasium-*.whl "$w"/farama*.whl .dev/a/
  du -sh .dev/a .dev/b ;;
shrink)
  mkdir -p "$STASH"
  for d in "${LARGE[@]}"; do
    if [ -e "$d" ]; then mkdir -p "$STASH/$(dirname "$d")"; mv "$d" "$STASH/$d"; fi
  done
  for f in $KEEP; do mkdir -p "$(dirname "$f")"; cp "$STASH/$f" "$f"; done
  git ls-files '*.png' | while read -r f; do
    if [ -e "$f" ]; then mkdir -p "$STASH/png/$(dirname "$f")"; mv "$f" "$STASH/png/$f"; fi
  done
  (git ls-files; git ls-files --others --exclude-standard) | sort -u | xargs du -cb 2>/dev/null | tail -1 || true ;;
restore)
  for f in $KEEP; do rm -f "$f"; done
  for d in "${LARGE[@]}"; do
    if [ -e "$STASH/$d" ]; then rm -rf "$d"; mv "$STASH/$d" "$d"; fi
  done
  if [ -d "$STASH/png" ]; then
    (cd "$STASH/png" && find . -type f -name '*.png' -print0 | xargs -0 -I{} mv {} "$OLDPWD/{}")
  fi
  find "$STASH" -type f | grep -q . || rm -rf "$STASH"
  git status --short | grep -v '^??' || echo "tree restored" ;;
*) echo "usage: $0 wheels|shrink|restore" >&2; exit 2 ;;
esac
