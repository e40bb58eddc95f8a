#!/usr/bin/env python3
"""Compare restage's camera-response recovery (Debevec-Malik, `calibrate::response`) with
OpenCV's cv2.createCalibrateDebevec / cv2.createMergeDebevec on the same exposure brackets.

Usage (from the repository root):
    python3 -m venv bench/peers/.venv
    bench/peers/.venv/bin/pip install -r bench/peers/requirements.txt
    # Brackets of the virtual non-linear camera (23 half-stop exposures of the white pattern,
    # one folder per exposure with exposure.json, plus truth.json = the true inverse response):
    RESTAGE_WRITE_BRACKETS=out/brackets cargo test -p restage-authoring --lib \
        stage_sim::foreign::tests::the_nonlinear_virtual_camera_response -- --nocapture
    bench/peers/.venv/bin/python bench/peers/response_peers.py out/brackets \
        --restage out/brackets/response.json --truth out/brackets/truth.json

The folder layout is the one `restage-author import` reads: subfolders e*/ each holding one
8-bit image (the first in name order is used) and exposure.json {"exposure_s": t}. Any
camera's brackets of a static scene laid out that way work (without --truth).

Both responses are normalised as restage's (h(255) = 1 per channel) and judged with restage's
metric: the largest |h(z) / (s t(z)) - 1| over codes 10..245 after the best common scale s.
OpenCV's channels are BGR; they are reordered to RGB. Prints a JSON summary.
"""
import argparse
import glob
import json
import os

import cv2
import numpy as np

CODES = np.arange(10, 246)


def error(recovered, truth):
    r = np.log(np.asarray(recovered, dtype=np.float64)[CODES] / np.asarray(truth, dtype=np.float64)[CODES])
    return float(np.max(np.abs(np.exp(r - r.mean()) - 1.0)))


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("folder")
    ap.add_argument("--restage", help="restage's response.json for the same brackets")
    ap.add_argument("--truth", help="the true inverse response (same layout as response.json)")
    ap.add_argument("--samples", type=int, default=70, help="OpenCV's sample count (its default 70)")
    ap.add_argument("--lambda", dest="lam", type=float, default=10.0, help="OpenCV's lambda (default 10)")
    args = ap.parse_args()

    images, times = [], []
    for d in sorted(glob.glob(os.path.join(args.folder, "*/"))):
        files = sorted(f for f in os.listdir(d) if f.lower().endswith((".png", ".jpg", ".jpeg", ".tif", ".tiff")))
        if not files:
            continue
        with open(os.path.join(d, "exposure.json")) as f:
            times.append(json.load(f)["exposure_s"])
        images.append(cv2.imread(os.path.join(d, files[0]), cv2.IMREAD_COLOR))
    times = np.asarray(times, dtype=np.float32)

    calibrate = cv2.createCalibrateDebevec(samples=args.samples, lambda_=args.lam, random=False)
    response = calibrate.process(images, times)  # 256 x 1 x 3, BGR, linear exposure per code
    h = response[:, 0, ::-1].astype(np.float64)  # to RGB
    h = h / h[255]
    merge = cv2.createMergeDebevec()
    hdr = merge.process(images, times, response)

    out = {"brackets": len(images), "opencv_samples": args.samples, "opencv_lambda": args.lam,
           "opencv_hdr_finite_pct": float(100.0 * np.isfinite(hdr).mean())}
    truth = None
    if args.truth:
        with open(args.truth) as f:
            truth = json.load(f)["inverse"]
        out["opencv_error_pct"] = [100.0 * error(h[:, c], truth[c]) for c in range(3)]
    if args.restage:
        with open(args.restage) as f:
            ours = json.load(f)["inverse"]
        out["restage_vs_opencv_pct"] = [100.0 * error(ours[c], h[:, c]) for c in range(3)]
        if truth is not None:
            out["restage_error_pct"] = [100.0 * error(ours[c], truth[c]) for c in range(3)]
    print(json.dumps(out, indent=2))


if __name__ == "__main__":
    main()
