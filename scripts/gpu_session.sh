#!/usr/bin/env bash
# One call on a lent GPU machine (the device tool's `run`), three parts inside one time budget:
#   1. the GPU benchmark's native half (scripts/gpu_bench.sh --no-page: the machine has no Node or
#      Chromium; docs/speed.md),
#   2. `nkrr eval` of the eval and falloff clouds on the GPU, to hold its meshes against the same
#      commit's on lavapipe (the kernels' only check on real hardware so far),
#   3. a prior's recipe (RECIPE, default training/train_v2.sh; its run RUN_NAME, default v2gpu)
#      on the GPU for what time is left (less EVALW_S when EVALW=1: then the trained prior is
#      exported to OUT/prior-RUN_NAME.safetensors and `nkrr eval --weights` runs it on the eval
#      clouds at EVALW_SIZES, OUT/eval-RUN_NAME.{md,json}, within EVALW_S seconds),
#   4. (PARTS=scene) each .gpubench/scene/*.laz reconstructed as a scene (tiles on) by each
#      build in SCENE_BINS (default .gpubench/nkrr): wall time, the process's peak memory, stage
#      times; OUT/NAME-BUILD.glb for clouds under 100k points.
# PARTS (default "bench eval train") picks them. Each part has its own limit, so one failing
# leaves the others their time.
#
# Here, once: cargo build --release --bin nkrr; the .gpubench/ pack (nkrr stripped, clouds/ as
# scripts/gpu_bench.sh --pack lays them out, eval/ with NAME.obj and NAME-SIZE.ply), .gl/ (the
# Vulkan loader's debs, docs/speed.md), training/cache_v2/heldout_32.npz (python -c 'from
# training.data import heldout_set; heldout_set(32, cache="training/cache_v2")'). Then:
#   run(command="BUDGET_S=560 bash scripts/gpu_session.sh 2>&1 | tee $OUT/log.txt",
#       carry=[".gpubench", ".gl", "training/cache_v2"], timeout_s=590)
# Writes OUT/gpu-bench.{md,json}, OUT/eval-gpu.{md,json}, OUT/v2gpu.tar (the run: ckpt.pt,
# metrics.jsonl, its log); export and compare here (training/export.py, training/compare.py).
set -uo pipefail
cd "$(dirname "$0")/.."
: "${OUT:?OUT: the folder that comes back}"
T0=$(date +%s)
BUDGET=${BUDGET_S:-560}
left() { echo $(( BUDGET - ($(date +%s) - T0) )); }
stamp() { echo "== $(date -u +%T) +$(( $(date +%s) - T0 ))s: $*"; }

if [ -d .gl ] && [ "$(id -u)" = 0 ] && ! ldconfig -p | grep -q libvulkan; then
    for f in .gl/*.deb; do dpkg -x "$f" /; done
    ldconfig
fi
icd=/usr/local/nvidia/share/vulkan/icd.d/nvidia_icd.json
[ -f "$icd" ] && export VK_DRIVER_FILES=$icd
egl=/usr/local/nvidia/share/glvnd/egl_vendor.d/10_nvidia.json
[ -f "$egl" ] && export __EGL_VENDOR_LIBRARY_FILENAMES=$egl
nvidia-smi -L; nproc
NKRR=.gpubench/nkrr
stamp "adapter"; timeout 30 "$NKRR" gpu
PARTS=${PARTS:-bench eval train}
want() { case " $PARTS " in *" $1 "*) return 0;; esac; return 1; }
# A command's wall time and peak resident memory (the device machine has no /usr/bin/time).
measured() {
    python3 -c 'import resource, subprocess, sys, time
t = time.time(); rc = subprocess.run(sys.argv[1:]).returncode
print(f"exit {rc}, wall {time.time() - t:.1f} s, peak RSS {resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 1024:.0f} MiB", flush=True)' "$@"
}

if want bench; then
    stamp "1. benchmark (native half)"
    timeout 170 bash scripts/gpu_bench.sh --no-page --deadline-s 150 --out "$OUT" ${BENCH_ARGS:-}
    stamp "1. done ($?)"
fi

if want eval; then
    stamp "2. eval on the GPU"
    timeout 100 "$NKRR" eval .gpubench/eval --sizes ${EVAL_SIZES:-500,3k,10k,falloff} --methods nkrr --out "$OUT/eval-gpu" >/dev/null
    stamp "2. done ($?)"
fi

if want scene; then
    # SCENE_BINS: several builds in turn on each scene (before and after a change, same run).
    for laz in .gpubench/scene/*.laz; do
        name=$(basename "$laz" .laz)
        for bin in ${SCENE_BINS:-$NKRR}; do
            out=/tmp/$name.glb
            [ "$(stat -c %s "$laz")" -lt 1000000 ] && out=$OUT/$name-$(basename "$bin").glb
            stamp "4. scene $name, $bin"
            measured timeout $(( $(left) - 10 )) "$bin" reconstruct "$laz" -o "$out" --tiles on
        done
    done
    stamp "4. done"
fi

want train || { ls -la "$OUT"; stamp "end"; exit 0; }
# 3. Training: what is left, less 80 s for the start (pool, held-out IoU) and the end, and less
# the trained prior's eval when there is one.
RECIPE=${RECIPE:-training/train_v2.sh}
NAME=${RUN_NAME:-v2gpu}
EVALW_S=${EVALW_S:-150}
[ "${EVALW:-0}" = 1 ] || EVALW_S=0
MIN=$(python3 -c "print(round(max(0.5, ($(left) - 80 - $EVALW_S) / 60), 2))")
stamp "3. training ${MIN} min: $RECIPE"
timeout $(( $(left) - 5 - EVALW_S )) env PYTHON=python3 bash "$RECIPE" "$MIN" "$NAME"
stamp "3. done ($?)"
tar -cf "$OUT/$NAME.tar" -C training/runs "$NAME" "$NAME.log" 2>/dev/null
if [ "$EVALW_S" -gt 0 ]; then
    stamp "3b. export and eval of the trained prior"
    python3 -m training.export --run "training/runs/$NAME" --out-dir /tmp/export-$NAME \
        && cp "/tmp/export-$NAME/assets/prior.safetensors" "$OUT/prior-$NAME.safetensors" \
        && timeout $(( $(left) - 5 )) "$NKRR" eval .gpubench/eval --sizes ${EVALW_SIZES:-500,3k,10k,falloff} \
            --methods nkrr --weights "$OUT/prior-$NAME.safetensors" --out "$OUT/eval-$NAME" >/dev/null
    stamp "3b. done ($?)"
fi
ls -la "$OUT"
stamp "end"
