#!/usr/bin/env python3
"""Peers for the colour classification (issue 6): OpenCV's cv2.kmeans and
cv2.pyrMeanShiftFiltering (+ cv2.kmeans on the filtered image) on the same photos ours runs on.

Inputs are folders written by `restage-author eval classify --out DIR`: per scene `photo.png`
(16-bit linear RGB), `truth.png` (8-bit class index, 255 = not object) and `metrics.json`
(ours and our baselines). Accuracy uses the truth's object pixels and, for every clustering
without picks, the one-to-one cluster-to-class map that maximises it (as our eval does).

With --speed DIR (from `cargo run --release --example classify_synthetic -- DIR`) it times
cv2.kmeans with k = 5 on the 10 MP synthetic photo the criterion bench uses.
Run through classify_peers.sh, which installs the pinned OpenCV into a virtualenv.
"""

import argparse
import itertools
import json
import os
import sys
import time

import cv2
import numpy as np


def load_photo_srgb8(path):
    """16-bit linear PNG -> 8-bit sRGB BGR, as one would hand the photo to OpenCV."""
    raw = cv2.imread(path, cv2.IMREAD_UNCHANGED)
    if raw is None:
        sys.exit(f"cannot read {path}")
    lin = raw.astype(np.float64) / (65535.0 if raw.dtype == np.uint16 else 255.0)
    if raw.dtype != np.uint16:  # 8-bit files are already sRGB-encoded
        return raw[:, :, :3]
    srgb = np.where(lin <= 0.0031308, lin * 12.92, 1.055 * np.power(lin, 1 / 2.4) - 0.055)
    return np.clip(np.round(srgb * 255.0), 0, 255).astype(np.uint8)[:, :, :3]


def best_accuracy(truth, clusters, k):
    """Accuracy and per-class recall under the best one-to-one cluster -> class map."""
    conf = np.zeros((k, k), dtype=np.int64)
    np.add.at(conf, (truth, clusters), 1)
    perm = max(itertools.permutations(range(k)), key=lambda p: sum(conf[p[c], c] for c in range(k)))
    right = sum(conf[perm[c], c] for c in range(k))
    recall = [0.0] * k
    for c in range(k):
        recall[perm[c]] = conf[perm[c], c] / max(conf[perm[c]].sum(), 1) * 100
    return right / truth.size, recall


def kmeans(samples, k, seed):
    cv2.setRNGSeed(seed)
    criteria = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 100, 1e-4)
    t0 = time.perf_counter()
    _, labels, _ = cv2.kmeans(samples, k, None, criteria, 1, cv2.KMEANS_PP_CENTERS)
    return labels.ravel(), time.perf_counter() - t0


def scene_row(folder, seed):
    bgr = load_photo_srgb8(os.path.join(folder, "photo.png"))
    truth_img = cv2.imread(os.path.join(folder, "truth.png"), cv2.IMREAD_UNCHANGED)
    with open(os.path.join(folder, "metrics.json")) as f:
        ours = json.load(f)
    obj = truth_img != 255
    truth = truth_img[obj].astype(np.int64)
    k = int(truth.max()) + 1
    samples = bgr[obj].astype(np.float32)
    km, km_s = kmeans(samples, k, seed)
    t0 = time.perf_counter()
    shifted = cv2.pyrMeanShiftFiltering(bgr, sp=10, sr=20)
    ms_s = time.perf_counter() - t0
    ms, _ = kmeans(shifted[obj].astype(np.float32), k, seed)
    km_acc, km_recall = best_accuracy(truth, km, k)
    ms_acc, ms_recall = best_accuracy(truth, ms, k)
    return {
        "scene": os.path.basename(os.path.normpath(folder)),
        "classes": ours.get("classes", [str(c) for c in range(k)]),
        "recall": {"cv2.kmeans": km_recall, "cv2.pyrMeanShift+kmeans": ms_recall, **ours.get("recall", {})},
        "k": k,
        "ours": ours["ours"] * 100,
        "kmeans++ RGB (ours)": ours["k-means++ RGB"] * 100,
        "kmeans++ Lab (ours)": ours["k-means++ Lab"] * 100,
        "cv2.kmeans": km_acc * 100,
        "cv2.pyrMeanShift+kmeans": ms_acc * 100,
        "cv2.kmeans s": km_s,
        "meanshift s": ms_s,
    }


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("scenes", nargs="*", help="folders written by `restage-author eval classify --out`")
    ap.add_argument("--speed", help="folder from the classify_synthetic example (10 MP photo)")
    ap.add_argument("--ours-seconds", type=float, help="our time on the --speed photo, for the ratio")
    ap.add_argument("--seed", type=int, default=1)
    args = ap.parse_args()
    print(f"OpenCV {cv2.__version__}, {cv2.getNumThreads()} threads")
    rows = [scene_row(s, args.seed) for s in args.scenes]
    if rows:
        cols = ["ours", "kmeans++ RGB (ours)", "kmeans++ Lab (ours)", "cv2.kmeans", "cv2.pyrMeanShift+kmeans"]
        print("\naccuracy on object pixels vs the deteriorated label map (%):")
        print(f"{'scene':<8} {'k':>2} " + " ".join(f"{c:>24}" for c in cols))
        for r in rows:
            print(f"{r['scene']:<8} {r['k']:>2} " + " ".join(f"{r[c]:>24.2f}" for c in cols))
        print("\nper-class recall (%):")
        for r in rows:
            methods = list(r["recall"].keys())
            print(f"{r['scene']:<8} {'class':<10} " + " ".join(f"{m:>24}" for m in methods))
            for c, name in enumerate(r["classes"]):
                print(f"{'':<8} {name:<10} " + " ".join(f"{r['recall'][m][c]:>24.2f}" for m in methods))
        print("\nOpenCV times (s): " + ", ".join(
            f"{r['scene']} kmeans {r['cv2.kmeans s']:.3f} meanshift {r['meanshift s']:.3f}" for r in rows))
    if args.speed:
        bgr = load_photo_srgb8(os.path.join(args.speed, "photo.png"))
        samples = bgr.reshape(-1, 3).astype(np.float32)
        times = [kmeans(samples, 5, args.seed)[1] for _ in range(3)]
        best = min(times)
        print(f"\nspeed, {bgr.shape[1]}x{bgr.shape[0]} ({bgr.shape[0] * bgr.shape[1] / 1e6:.1f} MP), k = 5: "
              f"cv2.kmeans best of 3 {best:.3f} s (runs {', '.join(f'{t:.3f}' for t in times)})")
        if args.ours_seconds:
            print(f"ours {args.ours_seconds:.3f} s: cv2.kmeans / ours = {best / args.ours_seconds:.1f}x")


if __name__ == "__main__":
    main()
