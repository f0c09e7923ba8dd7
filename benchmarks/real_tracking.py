"""The tracker on real recordings of people talking, against an independent reference
(docs/tracking.md, "Real recordings"). Usage:

    python benchmarks/real_tracking.py [REAL_DIR] [--json OUT.json]

REAL_DIR (default ``../shared/data/real`` beside the repository) holds the clips and, in
``reference/``, MediaPipe Face Mesh's 478 points for every frame (SOURCES.md there). Each clip is
tracked from dlib's points on its first frame (``voicepuppet track --init auto``), and compared in
layout-free measures per frame: the mouth's opening (inner lips' middle points) and width (mouth
corners) over the inter-ocular distance, correlated with the reference's (Pearson r), and the
share of frames whose inner lips cross (an upper inner-lip point more than 0.01 inter-ocular
distances below its lower partner, along the face's own vertical: from the eyes' midpoint to the
lower lip). Beside it, OpenCV's pyramidal Lucas-Kanade from the same first-frame points with the
same patch and pyramid (:func:`voicepuppet.bench.tracker.track_lk`), the peer to beat, and dlib's
shape predictor alone on every frame, each in the box its previous frame's points give
(:func:`voicepuppet.tracking.detect.landmarks_near`), the detector the tracker's lips are
anchored to; ``--no-anchors`` tracks without those anchors.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
import warnings
from pathlib import Path

import numpy as np

from voicepuppet.bench.tracker import track_lk
from voicepuppet.layout import crossed_lips
from voicepuppet.tracking import track_video
from voicepuppet.tracking.detect import landmarks_near
from voicepuppet.tracking.video import read_grey_frames

#: MediaPipe Face Mesh indices: outer eye corners, inner lips' middles, mouth corners.
MP_EYES, MP_LIPS, MP_CORNERS = (33, 263), (13, 14), (61, 291)


def measures(op_a, op_b):
    ok = np.isfinite(op_a) & np.isfinite(op_b)
    return float(np.corrcoef(op_a[ok], op_b[ok])[0, 1]) if ok.sum() > 2 else float("nan")


def ours(points):
    """Opening, width (over the inter-ocular distance) and crossed inner lips of 68-point tracks."""
    iod = np.linalg.norm(points[:, 36] - points[:, 45], axis=1)
    opening = np.linalg.norm(points[:, 62] - points[:, 66], axis=1) / iod
    width = np.linalg.norm(points[:, 48] - points[:, 54], axis=1) / iod  # outer corners, as MP_CORNERS
    return opening, width, crossed_lips(points)


def reference(ref):
    iod = np.linalg.norm(ref[:, MP_EYES[0]] - ref[:, MP_EYES[1]], axis=1)
    opening = np.linalg.norm(ref[:, MP_LIPS[0]] - ref[:, MP_LIPS[1]], axis=1) / iod
    width = np.linalg.norm(ref[:, MP_CORNERS[0]] - ref[:, MP_CORNERS[1]], axis=1) / iod
    return opening, width


def clips(real: Path):
    for index in sorted((real / "reference").rglob("index.json")):
        folder = index.parent.relative_to(real / "reference")
        for name, info in json.loads(index.read_text())["clips"].items():
            yield f"{folder}/{name}", real / folder / info["file"], index.parent / f"{name}.npy"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("real", nargs="?", default=str(Path(__file__).resolve().parents[2] / "shared" / "data" / "real"))
    ap.add_argument("--json", metavar="OUT.json")
    ap.add_argument("--no-anchors", action="store_true", help="track without the detector's anchors")
    args = ap.parse_args(argv)
    real = Path(args.real)
    if not (real / "reference").is_dir():
        print(f"no reference landmarks in {real / 'reference'}", file=sys.stderr)
        return 2
    rows = []
    print(f"{'clip':<28}{'frames':>7}{'crossed %':>10}{'opening r':>10}{'width r':>9}{'s':>7}"
          f"{'LK crossed %':>14}{'LK opening r':>13}{'LK width r':>11}{'dlib opening r':>15}{'dlib width r':>13}")
    for name, video, ref_path in clips(real):
        t0 = time.perf_counter()
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            res = track_video(video, init="auto", progress=False, detector_anchors=not args.no_anchors)
        seconds = time.perf_counter() - t0
        ref = np.load(ref_path).astype(np.float64)
        n = min(len(ref), len(res.points))
        o, w, crossed = ours(res.points[:n])
        ro, rw = reference(ref[:n])
        frames, _ = read_grey_frames(video)
        lk = track_lk(frames[:n], res.points[0])
        lo, lw, lcrossed = ours(lk)
        alone = [res.points[0]]
        for frame in frames[1:n]:
            alone.append(landmarks_near(frame, alone[-1]))
        do, dw, _ = ours(np.stack(alone))
        row = {"clip": name, "frames": n, "crossed": float(crossed.mean()), "opening_r": measures(o, ro),
               "width_r": measures(w, rw), "seconds": seconds, "lk_crossed": float(lcrossed.mean()),
               "lk_opening_r": measures(lo, ro), "lk_width_r": measures(lw, rw),
               "dlib_opening_r": measures(do, ro), "dlib_width_r": measures(dw, rw)}
        rows.append(row)
        print(f"{name:<28}{n:>7}{100 * row['crossed']:>10.1f}{row['opening_r']:>10.2f}{row['width_r']:>9.2f}"
              f"{seconds:>7.1f}{100 * row['lk_crossed']:>14.1f}{row['lk_opening_r']:>13.2f}{row['lk_width_r']:>11.2f}")
    if args.json:
        Path(args.json).write_text(json.dumps(rows, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
