#!/usr/bin/env bash
# Generates docs/results.md and docs/img/results-*.png (nkrr vs the network vs screened Poisson on
# the eval clouds at 500 / 3k / 10k points, ablations at 3k, a re-run check, time and memory vs
# cloud size, and the generated room and street in tiles against screened Poisson) on this machine, in one command:
#
#     scripts/results.sh [results.py options, e.g. --fresh, --redo scaling, --ablation-shapes A,B]
#
# Idempotent: each phase keeps its raw output in target/results/ (git-ignored) and is skipped when
# that is already there, so a second run only rewrites the report (--fresh reruns everything).
# Needs: target/release/nkrr (built here, or brought up to date), the main .venv
# (trimesh, pillow: the 500-point clouds and the renders; scripts/setup.sh makes it) and
# .venv-peers (Open3D for the SPSR peer, made by tests/peers/setup.sh) plus matplotlib pinned in
# scripts/results-requirements.txt. About an hour from nothing on the 2-core dev machine; seconds once done.
set -euo pipefail
cd "$(dirname "$0")/.."
log() { printf '[results.sh %s] %s\n' "$(date -u +%H:%M:%S)" "$*" >&2; }
start=$(date +%s)

# Always through cargo (a no-op when the binary is current): a binary left from an older commit
# would report another commit's defaults under this one's name.
log "building target/release/nkrr (cargo: nothing to do when it is current)"
cargo build --release --bin nkrr
if ! .venv/bin/python -c 'import trimesh, PIL' 2>/dev/null; then
    log "making .venv (scripts/setup.sh)"
    scripts/setup.sh python
fi
tests/peers/setup.sh
if ! .venv-peers/bin/python -c 'import matplotlib; assert matplotlib.__version__ == "3.11.2"' 2>/dev/null; then
    log "installing scripts/results-requirements.txt into .venv-peers"
    .venv-peers/bin/pip install -q --disable-pip-version-check -r scripts/results-requirements.txt
fi

log "clouds: target/results/data"
.venv/bin/python scripts/results_clouds.py tests/data/eval target/results/data
.venv-peers/bin/python scripts/results.py "$@"
log "done in $(( $(date +%s) - start )) s: docs/results.md"
