#!/usr/bin/env python3
"""OpenCV's CSRT tracker on the real footage, scored by `pftrack eval` as pftrack's tracks are.

Makes a throwaway virtual environment under /tmp with opencv-contrib-python-headless (CSRT
lives in OpenCV's contrib modules) and numpy (the project itself never depends on Python),
then tracks girl and car4 from ../shared/data with cv2.TrackerCSRT single-threaded, started
from the ground truth's box on each of K frames spread over the sequence (segment i from
frame floor(i N / K), or the next frame showing the target, to the end: OTB's temporal
robustness evaluation, as `scripts/eval_seeds.sh tre` runs pftrack). Each track is written
as a pose CSV (the box's inscribed ellipse, no angles) and scored with
`pftrack eval --segment`, so both trackers meet the same scorer. Prints, per sequence, the
success AUC from the first frame (OTB's one-pass evaluation), the AUC over the segments'
frames pooled, and CSRT's frames per second on one thread.

Boxes: OTB's are 1-based; OpenCV's Rect counts pixels from 0, so CSRT starts from
(x - 1, y - 1, w, h), and its Rect (x, y, w, h) is the box (x - 0.5, y - 0.5, w, h) in the
README's pixel coordinates (the top-left pixel's centre at 0, 0).

Usage: scripts/compare_csrt.py [--pftrack PATH] [--segments K] [--sequences "girl car4"]
                               [--venv DIR] [--data DIR] [--out DIR]
  PATH defaults to the release build in $CARGO_TARGET_DIR or ./target.
"""

import argparse
import json
import os
import subprocess
import sys
import tempfile

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)

from opencv_venv import default_data, ensure_venv


# Runs inside the venv: one CSRT track from `start` to the end, written as a pose CSV.
INNER = r'''
import json, os, sys, time
import cv2
cfg = json.loads(sys.argv[1])
cv2.setNumThreads(1)
frames = cfg["frames"]
x, y, w, h = cfg["box"]
tracker = cv2.TrackerCSRT_create()
first = cv2.imread(frames[cfg["start"]])
tracker.init(first, (int(round(x)) - 1, int(round(y)) - 1, int(round(w)), int(round(h))))
rows = []
def row(k, r):
    bx, by, bw, bh = r
    rows.append("%d,%.6f,%.6f,%.6f,%.6f,0,0,0" % (k, bx - 0.5 + bw / 2, by - 0.5 + bh / 2, bw / 2, bh / 2))
row(cfg["start"], (x - 1, y - 1, w, h))
spent = 0.0
for k in range(cfg["start"] + 1, len(frames)):
    img = cv2.imread(frames[k])
    t0 = time.perf_counter()
    ok, r = tracker.update(img)
    spent += time.perf_counter() - t0
    if ok:
        row(k, r)
    # A frame CSRT gives up on has no row: `pftrack eval` counts it as a failure.
with open(cfg["csv"], "w") as f:
    f.write("frame,cx,cy,a,b,rx,ry,rz\n" + "\n".join(rows) + "\n")
print(json.dumps({"updates": len(frames) - cfg["start"] - 1, "seconds": spent}))
'''


def otb_boxes(path):
    boxes = []
    with open(path) as f:
        for line in f:
            line = line.strip()
            if line:
                boxes.append([float(v) for v in line.replace("\t", ",").replace(" ", ",").split(",") if v])
    return boxes


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    target = os.environ.get("CARGO_TARGET_DIR", os.path.join(ROOT, "target"))
    ap.add_argument("--pftrack", default=os.path.join(target, "release", "pftrack"))
    ap.add_argument("--segments", type=int, default=20)
    ap.add_argument("--sequences", default="girl car4")
    ap.add_argument("--venv", default="/tmp/pftrack-csrt-venv")
    ap.add_argument("--data", default=default_data())
    ap.add_argument("--out", default=None)
    args = ap.parse_args()
    if args.segments < 1:
        sys.exit("compare_csrt: --segments must be at least 1")
    if not os.access(args.pftrack, os.X_OK):
        sys.exit(f"compare_csrt: no pftrack binary at {args.pftrack} (cargo build --release, or --pftrack PATH)")
    py = ensure_venv(args.venv, ["opencv-contrib-python-headless", "numpy"])
    out = args.out or tempfile.mkdtemp(prefix="pftrack-csrt.")
    os.makedirs(out, exist_ok=True)
    print(f"OpenCV CSRT (one thread) scored by {args.pftrack} eval --segment; tracks in {out}")
    print("| sequence | success AUC from the first frame | over %d starts, pooled | CSRT frames/s |" % args.segments)
    print("|---|---|---|---|")
    for q in args.sequences.split():
        img = os.path.join(args.data, q, "img")
        truth = os.path.join(args.data, q, "groundtruth_rect.txt")
        frames = sorted(os.path.join(img, f) for f in os.listdir(img) if f.lower().endswith((".jpg", ".png")))
        boxes = otb_boxes(truth)
        n = len(boxes)
        pooled, weight, ope = 0.0, 0, None
        updates, seconds = 0, 0.0
        for i in range(args.segments):
            start = next((k for k in range(i * n // args.segments, n) if boxes[k][2] > 0 and boxes[k][3] > 0), None)
            if start is None:
                sys.exit(f"compare_csrt: {q}: no frame showing the target from segment {i} on")
            csv = os.path.join(out, f"{q}-{i}.csv")
            cfg = {"frames": frames, "box": boxes[start][:4], "start": start, "csv": csv}
            run = subprocess.run([py, "-c", INNER, json.dumps(cfg)], check=True, capture_output=True, text=True)
            timing = json.loads(run.stdout)
            updates += timing["updates"]
            seconds += timing["seconds"]
            ev = subprocess.run([args.pftrack, "eval", "--segment", truth, csv, "--json"],
                                check=True, capture_output=True, text=True)
            r = json.loads(ev.stdout)
            scored = r["truth_frames"] - r["absent"]
            pooled += r["success_auc"] * scored
            weight += scored
            if i == 0:
                ope = r["success_auc"]
        print(f"| {q} | {ope:.3f} | {pooled / weight:.3f} | {updates / seconds:.1f} |")


if __name__ == "__main__":
    main()
