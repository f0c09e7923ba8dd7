"""Re-acquisition measured on the synthetic performer's clips (docs/tracking.md, "Re-acquiring a
lost face"). Usage: python benchmarks/tracking_reacquire_clips.py [--poses] CORPUS_DIR [CORPUS_DIR ...]

Each clip (train.mp4 + train.npz "points" of a synth corpus) is placed in a larger plain canvas
(its background grey); for a stretch of frames the face is gone (the plain canvas, or a card of
seeded smooth noise where it was), then it comes back translated by a whole-pixel offset, the
truth moved exactly with it. Tracked with and without the search (``reacquire=False`` is the
tracker before it), two passes; errors in px against the truth, after re-acquisition, beside the
unmodified clip tracked over the same frames. With ``--poses``: the face comes back (absent
60-89, shift (90, 60)) rotated or scaled about its centre, truth mapped alike.
"""

from __future__ import annotations

import sys

import cv2
import numpy as np

from voicepuppet import tracking
from voicepuppet.bench.tracker import REACQUIRE_CASES, planted
from voicepuppet.tracking import reacquire
from voicepuppet.tracking import video

def scores(points, truth, frames):
    e = np.linalg.norm(points[frames] - truth[frames], axis=2)
    return e[:, 48:].mean(), e[:, :48].mean()


def main(dirs) -> None:
    print("| clip | absent | shift px | cover | search | re-acquired at | lost while absent | lost after "
          "| lips / rest after (px) | lips / rest before absence (px) | uninterrupted clip, same frames after |")
    print("|---|---|---|---|---|---|---|---|---|---|---|")
    for d in dirs:
        frames, fps = video.read_grey_frames(f"{d}/train.mp4")
        truth = np.load(f"{d}/train.npz")["points"]
        n = min(len(frames), len(truth))
        frames, truth = frames[:n], truth[:n]
        plain = tracking.track_frames(frames, truth[0], fps=fps, passes=2)
        for a, b, sx, sy, cover in REACQUIRE_CASES:
            canvas, moved = planted(frames, truth, (a, b), (sx, sy), cover)
            for on in (False, True):
                r = tracking.track_frames(canvas, moved[0], fps=fps, passes=2, reacquire=on)
                after = slice(r.reacquired[0] if r.reacquired else b, n)
                la, ra = scores(r.points, moved, after)
                lb, rb = scores(r.points, moved, slice(1, a))
                lu, ru = scores(plain.points, truth, after)
                print(f"| {d.rstrip('/').split('/')[-1]} | {a}-{b - 1} | {sx}, {sy} | {cover} | {'on' if on else 'off'} "
                      f"| {r.reacquired if on else '-'} | {r.lost[a:b].mean():.3f} | {r.lost[b:].mean():.3f} "
                      f"| {la:.2f} / {ra:.2f} | {lb:.2f} / {rb:.2f} | {lu:.2f} / {ru:.2f} |", flush=True)


POSES = ((5, 1.0), (10, 1.0), (15, 1.0), (20, 1.0), (0, 0.85), (0, 1.15), (0, 1.3))


def poses(dirs) -> None:
    print("| clip | returned face | coarse peak | re-acquired at | lost after | lips / rest after (px) |")
    print("|---|---|---|---|---|---|")
    for d in dirs:
        frames, fps = video.read_grey_frames(f"{d}/train.mp4")
        truth = np.load(f"{d}/train.npz")["points"]
        n = min(len(frames), len(truth))
        canvas, moved = planted(frames[:n], truth[:n], (60, 90), (90, 60), "plain")
        bg = int(canvas[0, 0, 0])
        for angle, scale in POSES:
            c, m = canvas.copy(), moved.copy()
            centre = moved[90].mean(axis=0)
            M = cv2.getRotationMatrix2D((float(centre[0]), float(centre[1])), angle, scale)
            for t in range(90, n):
                c[t] = cv2.warpAffine(canvas[t], M, canvas.shape[2:0:-1], flags=cv2.INTER_LINEAR, borderValue=bg)
                m[t] = moved[t] @ M[:, :2].T + M[:, 2]
            peak = reacquire.FaceSearch(c[0], m[0]).peak(c[95])[0]
            r = tracking.track_frames(c, m[0], fps=fps, passes=2)
            after = slice(r.reacquired[0] if r.reacquired else 90, n)
            la, ra = scores(r.points, m, after)
            what = f"rotated {angle}°" if angle else f"scaled {scale}"
            print(f"| {d.rstrip('/').split('/')[-1]} | {what} | {peak:.3f} | {r.reacquired} | {r.lost[90:].mean():.3f} "
                  f"| {la:.2f} / {ra:.2f} |", flush=True)


if __name__ == "__main__":
    args = sys.argv[1:]
    if not [a for a in args if a != "--poses"]:
        sys.exit(__doc__)
    (poses if "--poses" in args else main)([a for a in args if a != "--poses"])
