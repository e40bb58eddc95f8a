#!/usr/bin/env bash
# Side-by-side classification table: ours and our baselines vs OpenCV (cv2.kmeans,
# cv2.pyrMeanShiftFiltering) on every built-in scene, plus speed on the 10 MP benchmark photo.
# Installs the pinned OpenCV of bench/peers/requirements.txt into bench/peers/.venv on first use.
# Usage: bash bench/peers/classify_peers.sh [OUT_DIR]   (default out/classify-peers)
set -euo pipefail
cd "$(dirname "$0")/../.."
OUT="${1:-out/classify-peers}"
VENV=bench/peers/.venv
if [ ! -x "$VENV/bin/python" ]; then
    python3 -m venv "$VENV"
    "$VENV/bin/pip" install -q -r bench/peers/requirements.txt
fi
cargo build -q --release --bin restage-author --example classify_synthetic
BIN="${CARGO_TARGET_DIR:-target}/release"
"$BIN/restage-author" eval classify --out "$OUT/scenes" > "$OUT.eval.txt"
"$BIN/examples/classify_synthetic" "$OUT/speed"
# Our time on the same photo: the classification step alone, best of 3 (as the CLI reports it).
ours=$(for _ in 1 2 3; do
    "$BIN/restage-author" classify "$OUT/speed/photo.png" --picks "$OUT/speed/picks.json" --out "$OUT/speed/ours" 2>/dev/null \
        | sed -n 's/.*; \([0-9.]*\) s$/\1/p'
done | sort -g | head -1)
"$VENV/bin/python" bench/peers/classify_peers.py "$OUT"/scenes/*/ --speed "$OUT/speed" --ours-seconds "$ours"
