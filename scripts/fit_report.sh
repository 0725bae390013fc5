#!/usr/bin/env bash
# Regenerates docs/fit.md: nkrr and the network with and without the last fit of the mesh to the
# points, on the eval clouds at 500 / 3k / 10k points (about 40 min on the 2-core dev machine).
# Raw output in target/fit/ (git-ignored); an existing target/fit/all.json is reused.
set -euo pipefail
cd "$(dirname "$0")/.."
export XDG_RUNTIME_DIR="${XDG_RUNTIME_DIR:-$(mktemp -d)}"
cargo build --release --bin nkrr
[ -x .venv/bin/python ] || bash scripts/setup.sh python
.venv/bin/python scripts/results_clouds.py tests/data/eval target/results/data
mkdir -p target/fit
if [ ! -f target/fit/all.json ]; then
    target/release/nkrr eval target/results/data --sizes 500,3k,10k \
        --methods nkrr,nkrr-no-fit,network,network-no-fit --out target/fit/all
fi
python3 scripts/fit_report.py target/fit/all.json > docs/fit.md
echo "wrote docs/fit.md"
