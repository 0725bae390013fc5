#!/usr/bin/env bash
# The speed benchmark (scripts/bench.py): nkrr's stage times on 500 / 3k / 10k / 100k points and
# the ratio to screened Poisson on the same clouds in the same run.
#     scripts/bench.sh [--sizes 500,3k,10k,100k] [--repeat 3] [--methods nkrr,network] [-- OPTIONS]
# Needs target/release/nkrr (built here), the clouds of scripts/results_clouds.py (made here with
# the main .venv) and .venv-peers (Open3D, tests/peers/setup.sh, made here).
set -euo pipefail
cd "$(dirname "$0")/.."
cargo build --release --bin nkrr
if [ ! -f target/results/data/scale/scale-100000.ply ]; then
    [ -x .venv/bin/python ] || scripts/setup.sh python
    .venv/bin/python scripts/results_clouds.py tests/data/eval target/results/data
fi
tests/peers/setup.sh
export XDG_RUNTIME_DIR=${XDG_RUNTIME_DIR:-$(mktemp -d)}
exec python3 scripts/bench.py "$@"
