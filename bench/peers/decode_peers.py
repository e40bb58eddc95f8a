#!/usr/bin/env python3
"""Compare restage's Gray-code decoder with OpenCV's structured_light.GrayCodePattern on the
same real capture: how many camera pixels each decodes, and whether they agree.

Usage (from the repository root):
    python3 -m venv bench/peers/.venv
    bench/peers/.venv/bin/pip install -r bench/peers/requirements.txt
    cargo run --release --bin restage-author -- decode \
        ../shared/data/real/procam-graycode-plane/capture --opencv-order --projector-size 1024x768 \
        --out out/real-decode
    bench/peers/.venv/bin/python bench/peers/decode_peers.py \
        ../shared/data/real/procam-graycode-plane/capture out/real-decode --projector-size 1024x768

OpenCV is run with its default thresholds (black 40, white 5), pixel by pixel through
getProjPixel where white - black > black threshold, as OpenCV's procam examples do.
Prints a JSON summary; restage's maps are proj0_x.png / proj0_y.png (16 * coord + 1, 0 = none).
Needs OpenCV (contrib, for structured_light) and numpy, as pinned in requirements.txt; with
--opencv-cache FILE.npz OpenCV's maps are decoded once and read back on later runs.

Consistency ("inconsistent_pct_*"): the share of decoded pixels more than 2 projector px from the
median of the decoded pixels in their 5x5 window (restage's `inconsistent` in decode.json), for
the pixels both decode (the baseline) and those only restage decodes, in restage's map; and for
OpenCV's own map. restage's decode.json gives the same figure split by its own criterion (pixels
read with no weak bit vs pixels kept with one: "decode_json_inconsistent_pct_*"); on a capture
where OpenCV decodes exactly restage's no-weak-bit pixels the two splits agree.
"""
import argparse
import glob
import json
import os
import sys
import time

import cv2
import numpy as np


def opencv_decode(files, pw, ph, black_thr, white_thr):
    imgs = [cv2.imread(f, cv2.IMREAD_GRAYSCALE) for f in files]
    pattern = cv2.structured_light.GrayCodePattern.create(pw, ph)
    pattern.setBlackThreshold(black_thr)
    pattern.setWhiteThreshold(white_thr)
    seq = imgs[:-2]
    white, black = imgs[-2].astype(np.int32), imgs[-1].astype(np.int32)
    h, w = white.shape
    xs = np.full((h, w), np.nan, np.float32)
    ys = np.full((h, w), np.nan, np.float32)
    lit = (white - black) > black_thr
    t0 = time.time()
    for y, x in zip(*np.nonzero(lit)):
        err, proj = pattern.getProjPixel(seq, int(x), int(y))
        if not err:
            xs[y, x], ys[y, x] = proj
    return xs, ys, int(lit.sum()), time.time() - t0


def inconsistent(x, y):
    """Decoded pixels further than 2 projector px (on either axis) from the median of the decoded
    pixels in the 5x5 window around them, the centre excluded; a decoded pixel with no decoded
    neighbour counts too. The same figure as restage's `decode::inconsistent_pixels`."""
    import warnings
    h, w = x.shape
    ok = np.isfinite(x) & np.isfinite(y)
    def med(a):
        pad = np.pad(np.where(ok, a, np.nan), 2, constant_values=np.nan)
        stack = np.stack([pad[dy:dy + h, dx:dx + w] for dy in range(5) for dx in range(5)
                          if (dy, dx) != (2, 2)])
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            return np.nanmedian(stack, axis=0)
    mx, my = med(x), med(y)
    near = (np.abs(x - mx) <= 2.0) & (np.abs(y - my) <= 2.0)  # False where the median is NaN
    return ok & ~near


def restage_maps(out_dir):
    def load(name):
        v = cv2.imread(os.path.join(out_dir, name), cv2.IMREAD_UNCHANGED).astype(np.float32)
        v[v == 0] = np.nan
        return (v - 1.0) / 16.0
    return load("proj0_x.png"), load("proj0_y.png")


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("capture")
    ap.add_argument("restage_out")
    ap.add_argument("--projector-size", default="1024x768")
    ap.add_argument("--black-threshold", type=int, default=40)
    ap.add_argument("--white-threshold", type=int, default=5)
    ap.add_argument("--opencv-cache", help="NPZ file: OpenCV's maps are loaded from it if it "
                    "exists, else decoded and saved there (the decode takes ~10 s per pose)")
    a = ap.parse_args()
    pw, ph = map(int, a.projector_size.split("x"))
    files = sorted(glob.glob(os.path.join(a.capture, "*.png")))
    if a.opencv_cache and os.path.exists(a.opencv_cache):
        c = np.load(a.opencv_cache)
        cx, cy, lit, secs = c["x"], c["y"], int(c["lit"]), float(c["seconds"])
    else:
        cx, cy, lit, secs = opencv_decode(files, pw, ph, a.black_threshold, a.white_threshold)
        if a.opencv_cache:
            np.savez_compressed(a.opencv_cache, x=cx, y=cy, lit=lit, seconds=secs)
    rx, ry = restage_maps(a.restage_out)
    cv_ok = np.isfinite(cx) & np.isfinite(cy)
    rs_ok = np.isfinite(rx) & np.isfinite(ry)
    both = cv_ok & rs_ok
    dx, dy = (rx - cx)[both], (ry - cy)[both]
    cheb = np.maximum(np.abs(dx), np.abs(dy))
    eucl = np.hypot(dx, dy)
    # Pixels only restage decodes (one weak bit, at stripe boundaries): compare with the median
    # of OpenCV's decoded neighbours in a 5x5 window, the best reference available there.
    only = rs_ok & ~cv_ok
    def neighbour_median(a):
        h, w = a.shape
        pad = np.pad(a, 2, constant_values=np.nan)
        stack = np.stack([pad[dy:dy + h, dx:dx + w] for dy in range(5) for dx in range(5)])
        return np.nanmedian(stack, axis=0)
    import warnings
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        mx, my = neighbour_median(cx), neighbour_median(cy)
    ref = only & np.isfinite(mx) & np.isfinite(my)
    dev = np.maximum(np.abs(rx - mx), np.abs(ry - my))[ref]
    # Consistency as restage's decode.json reports it (`inconsistent`), per pixel set: in restage's
    # own map, restage-only pixels against the common ones (the baseline), and OpenCV's map.
    r_bad = inconsistent(rx, ry)
    c_bad = inconsistent(cx, cy)
    pct = lambda bad, mask: round(100.0 * float(bad[mask].mean()), 4) if mask.any() else None
    common_pct, only_pct = pct(r_bad, both), pct(r_bad, only)
    # decode.json written before the split lacks these fields: reported as None.
    with open(os.path.join(a.restage_out, "decode.json")) as f:
        quality = json.load(f)[0]
    from_json = lambda key: round(100.0 * quality[key], 4) if key in quality else None
    summary = {
        "opencv_version": cv2.__version__,
        "pixels": int(cx.size),
        "lit_opencv": lit,
        "opencv_decoded": int(cv_ok.sum()),
        "restage_decoded": int(rs_ok.sum()),
        "both_decoded": int(both.sum()),
        "agree_within_1px_chebyshev": float((cheb <= 1.0).mean()),
        "agree_within_1px_euclidean": float((eucl <= 1.0).mean()),
        "agree_exact": float((cheb == 0).mean()),
        "restage_only": int(only.sum()),
        "restage_only_with_opencv_neighbours": int(ref.sum()),
        "restage_only_within_1_5px_of_neighbour_median": float((dev <= 1.5).mean()),
        "restage_over_opencv": round(int(rs_ok.sum()) / max(int(cv_ok.sum()), 1), 3),
        "inconsistent_pct_restage_all": pct(r_bad, rs_ok),
        "inconsistent_pct_common": common_pct,
        "inconsistent_pct_restage_only": only_pct,
        "restage_only_over_common": round(only_pct / common_pct, 2) if only_pct is not None and common_pct else None,
        "inconsistent_pct_opencv_own_map": pct(c_bad, cv_ok),
        "decode_json_inconsistent_pct_confident": from_json("inconsistent_confident"),
        "decode_json_inconsistent_pct_weak": from_json("inconsistent_weak"),
        "opencv_seconds": round(secs, 2),
    }
    json.dump(summary, sys.stdout, indent=2)
    print()


if __name__ == "__main__":
    main()
