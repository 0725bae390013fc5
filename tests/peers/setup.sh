#!/usr/bin/env bash
# Makes .venv-peers (the Open3D peer baseline's Python, apart from the main .venv) from
# tests/peers/requirements.txt, idempotently: a venv that already imports the pinned
# open3d is left as it is.   usage: tests/peers/setup.sh   (from anywhere)
set -euo pipefail
cd "$(dirname "$0")/../.."
PY=${PYTHON:-python3.11}
log() { printf '[peers] %s\n' "$*" >&2; }
if [ ! -x .venv-peers/bin/python ]; then
    log "creating .venv-peers with $PY"
    "$PY" -m venv .venv-peers
fi
want=$(sed -n 's/^open3d-cpu==//p' tests/peers/requirements.txt)
# laspy and lazrs too: scripts/scene_spsr.py reads LAZ scenes.
have=$(.venv-peers/bin/python -c 'import open3d, laspy, lazrs; print(open3d.__version__)' 2>/dev/null || true)
if [ "$have" = "$want" ]; then
    log "open3d $have present"
else
    log "installing tests/peers/requirements.txt (open3d-cpu $want, a 105 MB wheel)"
    start=$(date +%s)
    .venv-peers/bin/pip install -q --disable-pip-version-check -r tests/peers/requirements.txt
    log "installed in $(( $(date +%s) - start )) s"
fi
