#!/usr/bin/env bash
# Continue training the prior on a CUDA machine (used with the lent H100), starting from the CPU
# run's weights (training/runs/main/ckpt.pt) and generating shapes in background processes.
#   bash training/train_gpu.sh [MINUTES] [RUN_NAME]
# Needs: python3 with torch (CUDA), numpy, scikit-image; training/cache/heldout_32.npz (the CPU
# run's held-out set, so held-out IoU stays comparable). Writes training/runs/<RUN_NAME>/.
set -euo pipefail
cd "$(dirname "$0")/.."
MIN=${1:-8}
NAME=${2:-gpu}
CACHE=${NKRR_GPU_CACHE:-/tmp/nkrr_cache}
PY=${PYTHON:-python3}
mkdir -p "$CACHE"
cp -n training/cache/heldout_32.npz "$CACHE/"
WORKERS=$(( $(nproc) > 3 ? $(nproc) - 2 : 1 ))
nvidia-smi -L || true
PYTHONUNBUFFERED=1 "$PY" -m training.train --name "$NAME" --init training/runs/main/ckpt.pt \
  --device cuda --batch 32 --gen-workers "$WORKERS" --gen-chunks 4000 --min-pool 64 \
  --cache "$CACHE" --total-minutes "$MIN" --threads 2 --eval-every 250 --ckpt-minutes 2
