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
KIND=3
COMMON=(--name "$NAME" --init assets/prior.safetensors --shape-kind "$KIND" --cache "$CACHE"
        --aug-falloff 0.2 --aug-outliers 0.2 --aug-onesided 0.1 --lr 1.5e-4
        --total-minutes "$MIN" --eval-every 200 --ckpt-minutes 5)
source training/launch.sh
