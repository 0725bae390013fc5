#!/usr/bin/env bash
# Checks that the web app deploys anywhere: dist/index.html as `trunk build` leaves it, and the
# page as the README's serve command (`trunk serve`, which writes dist/ too) serves it, carry no
# trunk live-reload code. That code's websocket client, copied to another web server with its
# unfilled {{__TRUNK_ADDRESS__}} placeholders, failed every second. Run after the web build
# (scripts/test.sh does); exits non-zero, naming the file and the line, when either has it.
set -euo pipefail
cd "$(dirname "$0")/.."
ROOT=$PWD
source scripts/wasm-env.sh

# What trunk's live reload injects: its placeholders ({{__TRUNK_ADDRESS__}}, ...; the served
# copy has them filled) and its websocket endpoint (.well-known/trunk/ws).
PATTERN='__TRUNK_|trunk/ws'

check() { # $1: what, $2: file
    if grep -nEi "$PATTERN" "$2"; then
        echo "check_dist: $1 carries trunk's live-reload code (lines above)" >&2
        exit 1
    fi
    echo "check_dist: $1: no live-reload code"
}

test -f dist/index.html || { echo "check_dist: no dist/index.html: build the app first" >&2; exit 1; }
check "the built dist/index.html" dist/index.html

# The README's serve command, on a port of its own: what it serves, and the dist/ it rewrites.
PORT=${NKRR_CHECK_PORT:-18093}
LOG=$(mktemp)
trunk serve --release --offline --address 127.0.0.1 --port "$PORT" >"$LOG" 2>&1 &
PID=$!
trap 'kill $PID 2>/dev/null || true; wait $PID 2>/dev/null || true; rm -f "$LOG"' EXIT
SERVED=$(mktemp)
for _ in $(seq 1 600); do
    if curl -sf "http://127.0.0.1:$PORT/" -o "$SERVED" 2>/dev/null && grep -q '</html>' "$SERVED"; then break; fi
    if ! kill -0 $PID 2>/dev/null; then cat "$LOG" >&2; echo "check_dist: trunk serve stopped" >&2; exit 1; fi
    sleep 1
done
grep -q '</html>' "$SERVED" || { cat "$LOG" >&2; echo "check_dist: trunk serve served nothing in 10 minutes" >&2; exit 1; }
check "the page trunk serve serves" "$SERVED"
check "dist/index.html after trunk serve" dist/index.html
rm -f "$SERVED"
