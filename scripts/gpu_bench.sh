#!/usr/bin/env bash
# The GPU benchmark (issue 27; scripts/gpu_bench.py): the native CLI and the web page in headless
# Chromium on the same clouds (500 / 3k / 10k / 100k points, network and nkrr), stage times, one
# deadline (280 s); writes OUT/gpu-bench.md and OUT/gpu-bench.json. Builds nothing.
#
#   scripts/gpu_bench.sh --pack          copy what a lent GPU machine needs into .gpubench/ (the
#                                        release nkrr, dist/, the clouds); carry it there
#   scripts/gpu_bench.sh [OPTIONS]       run (on a GPU machine: the nvidia Vulkan driver)
#   scripts/gpu_bench.sh --dry-run       sizes 500 and 3k on CPU adapters (lavapipe, SwiftShader)
#
# OPTIONS (scripts/gpu_bench.py --help): --nkrr BIN --dist DIR --clouds DIR --out DIR
# --sizes 500,3k,10k,100k --methods network,nkrr --deadline-s 280 --gpu real|swiftshader
# --chromium PATH --node PATH --no-page. Environment: NKRR, DIST, CLOUDS, OUT_DIR, CHROMIUM,
# NODE, DEADLINE_S, DRY_RUN=1, NATIVE_ICD (the CLI on another Vulkan driver). Defaults: .gpubench/{nkrr,dist,clouds} when packed, else
# target/release/nkrr, dist/, target/results/data; OUT_DIR target/gpu-bench.
# The lent machine and its exact command line: docs/speed.md, "GPU benchmark (issue 27)".
set -euo pipefail
cd "$(dirname "$0")/.."

if [ "${1:-}" = --pack ]; then
    P=.gpubench
    bin=${NKRR:-target/release/nkrr} dist=${DIST:-dist} clouds=${CLOUDS:-target/results/data}
    [ -x "$bin" ] || { echo "no $bin: cargo build --release --bin nkrr" >&2; exit 1; }
    [ -f "$dist/index.html" ] || { echo "no $dist/index.html: NKRR_BUILD_ONLY=1 scripts/serve.sh" >&2; exit 1; }
    if [ ! -f "$clouds/scale/scale-100000.ply" ]; then
        [ -x .venv/bin/python ] || { echo "no $clouds/scale/scale-100000.ply and no .venv: scripts/setup.sh python" >&2; exit 1; }
        .venv/bin/python scripts/results_clouds.py tests/data/eval "$clouds"
    fi
    rm -rf "$P" && mkdir -p "$P/clouds/scale"
    cp "$bin" "$P/nkrr" && { strip --strip-debug "$P/nkrr" 2>/dev/null || true; }
    cp -r "$dist" "$P/dist"
    cp -L "$clouds"/spot-500.ply "$clouds"/spot-3k.ply "$clouds"/spot-10k.ply "$P/clouds/"
    cp -L "$clouds/scale/scale-100000.ply" "$P/clouds/scale/"
    du -sh "$P" node_modules/playwright-core 2>/dev/null || true
    echo "carry: .gpubench, node_modules/playwright-core (and .gl: docs/speed.md)"
    exit 0
fi

dry=${DRY_RUN:-0}
for x in "$@"; do [ "$x" = --dry-run ] && dry=1; done
if [ -d .gpubench ]; then
    export NKRR=${NKRR:-.gpubench/nkrr} DIST=${DIST:-.gpubench/dist} CLOUDS=${CLOUDS:-.gpubench/clouds}
fi
# The Vulkan loader, where the machine lacks one and .gl carries it (the device README's recipe).
if [ -d .gl ] && [ "$(id -u)" = 0 ] && ! ldconfig -p | grep -q libvulkan; then
    for f in .gl/*.deb; do dpkg -x "$f" /; done
    ldconfig
fi
if [ "$dry" = 1 ]; then
    for lvp in /usr/share/vulkan/icd.d/lvp_icd.*.json; do [ -f "$lvp" ] && export VK_DRIVER_FILES=$lvp; done
else
    icd=/usr/local/nvidia/share/vulkan/icd.d/nvidia_icd.json
    [ -f "$icd" ] && export VK_DRIVER_FILES=$icd
    egl=/usr/local/nvidia/share/glvnd/egl_vendor.d/10_nvidia.json
    [ -f "$egl" ] && export __EGL_VENDOR_LIBRARY_FILENAMES=$egl
    command -v nvidia-smi >/dev/null && nvidia-smi -L >&2 || true
fi
# NATIVE_ICD: the CLI on another Vulkan driver, e.g. Chromium's own SwiftShader
# (/usr/lib/chromium/vk_swiftshader_icd.json) for page/native on the same driver in a dry run.
if [ -n "${NATIVE_ICD:-}" ]; then export VK_DRIVER_FILES=$NATIVE_ICD; fi
export XDG_RUNTIME_DIR=${XDG_RUNTIME_DIR:-$(mktemp -d)}
exec python3 scripts/gpu_bench.py "$@"
