#!/usr/bin/env bash
# Restoration table: ours, a mode filter of the same footprint, and OpenCV Telea inpainting
# given the true deterioration mask (an oracle), on every built-in scene.
# Installs the pinned OpenCV of bench/peers/requirements.txt into bench/peers/.venv on first use.
# Usage: bash bench/peers/restore_peers.sh [OUT_DIR] [extra eval-restore args, e.g. --camera 1600x1200]
set -euo pipefail
cd "$(dirname "$0")/../.."
OUT="${1:-out/eval-restore}"
shift || true
VENV=bench/peers/.venv
if [ ! -x "$VENV/bin/python" ]; then
    python3 -m venv "$VENV"
    "$VENV/bin/pip" install -q -r bench/peers/requirements.txt
fi
cargo build -q --release --bin restage-author
BIN="${CARGO_TARGET_DIR:-target}/release/restage-author"
# First pass writes the peer inputs; a stale telea.png from an earlier run is removed first.
rm -f "$OUT"/*/peer/telea.png
"$BIN" eval-restore --out "$OUT" "$@" > /dev/null
"$VENV/bin/python" bench/peers/restore_peers.py "$OUT"/*/peer
# Second pass scores ours, the mode filter and Telea together.
"$BIN" eval-restore --out "$OUT" "$@"
