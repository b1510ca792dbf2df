#!/usr/bin/env bash
# Runs on the lent GPU machine, from the repository root (README.md beside this file).
#   bash tools/gpu/remote.sh unpack [CORPUS ...]  # call 1 (carry .dev/a): keep the wheels, start the corpus caches
#   bash tools/gpu/remote.sh run COMMAND ...      # call 2 (carry .dev/b): install, then run COMMAND
set -u
export PYTHONUNBUFFERED=1 MUJOCO_GL=egl PYTHONPATH=/tmp/site:$PWD
install() {  # $1: the wheels to install
  python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade --target /tmp/site $1
}
case "${1:-}" in
unpack)
  shift; mkdir -p /tmp/dev && cp .dev/a/* /tmp/dev/ || exit 3
  install "/tmp/dev/mujoco-*.whl /tmp/dev/mujoco_core-*.whl /tmp/dev/gymnasium-*.whl /tmp/dev/farama*.whl" || exit 4
  # The corpora are generated on the CPU (minutes each) while the next call starts: a new
  # process session outlives this call, while the machine stays warm.
  for spec in "$@"; do
    setsid nohup python3 -c "from smpl_envs.motion.library import MotionLib; MotionLib.load('$spec', progress=False)" \
      > "/tmp/dev/corpus_${spec//[:\/]/_}.log" 2>&1 < /dev/null &
  done
  nvidia-smi --query-gpu=name,driver_version,memory.total --format=csv ;;
run)
  shift
  install "/tmp/dev/*.whl" || exit 4
  tar -xJf /tmp/dev/warp_py.tar.xz -C /tmp/site || exit 5
  cat /tmp/dev/warp.so.xz.part_a .dev/b/warp.so.xz.part_b | xz -d -T0 > /tmp/site/warp/bin/warp.so || exit 6
  "$@" ;;
*) echo "usage: $0 unpack [CORPUS ...] | run COMMAND ..." >&2; exit 2 ;;
esac
