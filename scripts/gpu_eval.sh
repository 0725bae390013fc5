#!/usr/bin/env bash
# Benchmark and evaluation runs on a lent GPU machine (the device tool), within one command:
#   scripts/gpu_eval.sh OUT BIN DATA JOBS
# OUT: folder for results (bench.txt, gpu.txt, one TAG-SIZE.tgz of meshes + logs per job group);
# BIN: a release `nkrr` built on this repo's machine; DATA: folder of the eval clouds (*-3k.ply,
# *-10k.ply); JOBS: file of lines "TAG SIZE [nkrr reconstruct options]", run in order, P at a time
# (SIZE may be SIZE:SHAPE to run one cloud, so that one shape per job spreads over the cores).
# Every job ends before DEADLINE_S seconds after the start so that packing always happens.
# Metrics are computed afterwards on the home machine (scripts/eval_metrics.py).
set -uo pipefail
OUT=$1 BIN=$2 DATA=$3 JOBS=$4
DEADLINE_S=${DEADLINE_S:-540} BENCH_S=${BENCH_S:-150} P=${P:-4}
start=$(date +%s)
if [ -d .gl ]; then for f in .gl/*.deb; do dpkg -x "$f" /; done; ldconfig; fi
icd=/usr/local/nvidia/share/vulkan/icd.d/nvidia_icd.json
[ -f "$icd" ] && export VK_DRIVER_FILES=$icd
export XDG_RUNTIME_DIR=$(mktemp -d)
nvidia-smi -L > "$OUT/gpu.txt" 2>&1
nproc >> "$OUT/gpu.txt"
"$BIN" gpu >> "$OUT/gpu.txt" 2>&1
if [ "$BENCH_S" -gt 0 ]; then
    timeout "$BENCH_S" "$BIN" bench ${BENCH_ARGS:---sizes 3000,10000,50000 --ms 500,1000 --steps 5} > "$OUT/bench.txt" 2>&1
    echo "bench exit $?" >> "$OUT/bench.txt"
fi
W=$(mktemp -d)
export BIN DATA W start DEADLINE_S
job() {
    tag=$1 size=$2 only='*'; shift 2
    case $size in *:*) only=${size#*:}; size=${size%%:*};; esac
    mkdir -p "$W/$tag-$size"
    for ply in "$DATA"/$only-"$size".ply; do
        name=$(basename "$ply" "-$size.ply")
        left=$(( start + DEADLINE_S - $(date +%s) ))
        [ "$left" -gt 5 ] || { echo "skipped: deadline" > "$W/$tag-$size/$name.log"; continue; }
        t0=$(date +%s.%N)
        timeout "$left" "$BIN" reconstruct "$ply" -o "$W/$tag-$size/$name.glb" "$@" > "$W/$tag-$size/$name.log" 2>&1
        echo "exit $? wall $(awk "BEGIN{print $(date +%s.%N) - $t0}")" >> "$W/$tag-$size/$name.log"
    done
}
export -f job
grep -v '^#' "$JOBS" | grep . | xargs -P "$P" -L1 bash -c 'job "$@"' _
for d in "$W"/*; do tar czf "$OUT/$(basename "$d").tgz" -C "$W" "$(basename "$d")"; done
ls -la "$OUT"
