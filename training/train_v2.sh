#!/usr/bin/env bash
# The second prior (issue 14 item 6): continue from the shipped weights on the second shape stream
# (new families: surfaces of revolution, tubes, thin flaps, machined parts; a query band at 0.005)
# with degraded clouds (density falloff up to 60x, up to 10 % stray points, one-sided scans).
#   bash training/train_v2.sh [MINUTES] [RUN_NAME]
# Resumable: re-running continues training/runs/<RUN_NAME>/ckpt.pt within the same MINUTES budget
# (the learning-rate schedule follows the share of it used). On a CUDA machine it uses the GPU
# with batch 32 and background shape generation; on a CPU, batch 8 and shapes generated inline.
# Then: python -m training.compare (held-out IoU of both priors) and
#       python -m training.export --run training/runs/<RUN_NAME> --out-dir DIR.
set -euo pipefail
cd "$(dirname "$0")/.."
MIN=${1:-70}
NAME=${2:-v2}
PY=${PYTHON:-.venv/bin/python}
CACHE=${NKRR_V2_CACHE:-training/cache_v2}
COMMON=(--name "$NAME" --init assets/prior.safetensors --shape-kind 3 --cache "$CACHE"
        --aug-falloff 0.2 --aug-outliers 0.2 --aug-onesided 0.1 --lr 1.5e-4
        --total-minutes "$MIN" --eval-every 200 --ckpt-minutes 5)
mkdir -p training/runs
if "$PY" -c 'import torch, sys; sys.exit(not torch.cuda.is_available())' 2>/dev/null; then
    WORKERS=$(( $(nproc) > 3 ? $(nproc) - 2 : 1 ))
    PYTHONUNBUFFERED=1 "$PY" -m training.train "${COMMON[@]}" --device cuda --batch 32 \
        --gen-workers "$WORKERS" --gen-chunks 4000 --min-pool 64 --threads 2 \
        2>&1 | tee -a "training/runs/$NAME.log"
else
    "$PY" -m training.gen_cache --shapes 320 --workers 2 --kind 3 --cache "$CACHE"
    PYTHONUNBUFFERED=1 "$PY" -m training.train "${COMMON[@]}" --batch 8 --gen-every 4 --threads 2 \
        2>&1 | tee -a "training/runs/$NAME.log"
fi
