#!/usr/bin/env bash
# Reconstructs every tests/data/eval/*-SIZE.ply with the given nkrr options and prints a
# markdown table of CD1 x100, F-score, normal consistency, watertightness and time per shape, and
# the error split at the F-score's tau (scripts/eval_metrics.py): the share of the
# reconstruction's / the truth's samples beyond tau (extra / missing surface) and the share of CD1
# those carry.
#   scripts/eval_table.sh 10k --method network
#   scripts/eval_table.sh 3k --method nkrr --m 200 --steps 30
set -euo pipefail
cd "$(dirname "$0")/.."
size=${1:?size, e.g. 10k}; shift
out=${EVAL_OUT:-target/eval}
mkdir -p "$out"
export XDG_RUNTIME_DIR=${XDG_RUNTIME_DIR:-$(mktemp -d)}
# The default binary is brought up to date (a no-op when current): one left from an older commit
# would print another commit's numbers. NKRR_BIN names a binary to use as it is.
if [ -z "${NKRR_BIN:-}" ]; then cargo build --release --bin nkrr; fi
bin=${NKRR_BIN:-target/release/nkrr}
echo "| shape | CD1 x100 | F-score | NC | watertight | time (s) | beyond tau (rec / gt) | CD1 beyond tau |"
echo "| --- | --- | --- | --- | --- | --- | --- | --- |"
for ply in tests/data/eval/*-"$size".ply; do
    name=$(basename "$ply" "-$size.ply")
    glb="$out/$name-$size.glb"
    t0=$(date +%s.%N)
    "$bin" reconstruct "$ply" -o "$glb" "$@" > "$out/$name-$size.log" 2>&1 || { echo "| $name | failed: $(tail -1 "$out/$name-$size.log") |"; continue; }
    t=$(.venv/bin/python -c "print($(date +%s.%N) - $t0)")
    .venv/bin/python scripts/eval_metrics.py "tests/data/eval/$name.obj" "$glb" | .venv/bin/python -c "
import json,sys; r=json.loads(sys.stdin.read()); print(f\"| $name | {r['cd1x100']:.3f} | {r['fscore']:.3f} | {r['nc']:.3f} | {'yes' if r['watertight'] else 'no'} | {float('$t'):.1f} | {r['precision_beyond_share']:.3f} / {r['completeness_beyond_share']:.3f} | {r['beyond_cd_share']:.2f} |\")"
done
