#!/usr/bin/env python3
"""Peer for the contour restoration (issue 7): OpenCV's Telea inpainting (cv2.inpaint,
INPAINT_TELEA) of the classified image in class colours, given the TRUE deterioration mask
(the pixels whose class the simulated wear changed). No user has that mask: it is an
oracle, so this peer shows what inpainting could do at best, not what it does in practice.

Inputs are the `<scene>/peer/` folders written by `restage-author eval-restore --out DIR`:
`classified.png` (class colours), `deterioration_mask.png` (255 = deteriorated) and
`colours.json`. Writes `telea.png` beside them; `eval-restore` reads it back (nearest class
colour) and scores it like ours. Run through restore_peers.sh, which installs the pinned
OpenCV into a virtualenv.
"""

import argparse
import os
import sys

import cv2


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("peer_dirs", nargs="+", help="<scene>/peer folders from eval-restore")
    ap.add_argument("--radius", type=float, default=3.0,
                    help="inpainting radius in px (default 3: the mode filter's footprint)")
    args = ap.parse_args()
    for d in args.peer_dirs:
        img = cv2.imread(os.path.join(d, "classified.png"), cv2.IMREAD_COLOR)
        mask = cv2.imread(os.path.join(d, "deterioration_mask.png"), cv2.IMREAD_GRAYSCALE)
        if img is None or mask is None:
            sys.exit(f"{d}: classified.png or deterioration_mask.png missing or unreadable")
        if img.shape[:2] != mask.shape:
            sys.exit(f"{d}: image {img.shape[:2]} and mask {mask.shape} differ in size")
        out = cv2.inpaint(img, (mask > 0).astype("uint8") * 255, args.radius, cv2.INPAINT_TELEA)
        cv2.imwrite(os.path.join(d, "telea.png"), out)
        print(f"{d}: {int((mask > 0).sum())} masked pixels inpainted (Telea, radius {args.radius:g})")


if __name__ == "__main__":
    main()
