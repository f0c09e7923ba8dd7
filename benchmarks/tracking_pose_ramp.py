"""Planted head rotation and scale for the tracker (docs/tracking.md's table): the performer's
photo seen through a known similarity ramp (:func:`voicepuppet.bench.tracker.similarity_ramp`,
also the generator of the tracking test under head rotation and scale), tracked:

    python benchmarks/tracking_pose_ramp.py

It tracks with whichever ``voicepuppet`` is imported (so the same script measures an older
installed copy), with the defaults and with the image frame (``frame_points=()``), and prints
mean and max landmark error (px and inter-ocular distances), the lip error and the lost fraction.
"""

from __future__ import annotations

import numpy as np

from voicepuppet.bench.tracker import similarity_ramp


def _scores(points, truth, lost):
    err = np.linalg.norm(points - truth, axis=2)
    iod = np.linalg.norm(truth[:, 45] - truth[:, 36], axis=1)[:, None]
    return (f"{err.mean():.3f} | {err.max():.2f} | {(err / iod).mean():.4f} | {(err / iod).max():.4f} | "
            f"{err[:, 48:].mean():.3f} | {lost.mean():.4f}")


def main() -> None:
    import time

    import voicepuppet
    from voicepuppet.tracking import tracker as tracking

    ramps = [("30 deg, scale 1 -> 1.4 -> 0.75", (150, 30.0, 1.4, 0.75)),
             ("30 deg, no scale", (150, 30.0, 1.0, 1.0)),
             ("no rotation, scale 1 -> 1.4 -> 0.7", (150, 0.0, 1.4, 0.7)),
             ("45 deg, scale 1 -> 1.6 -> 0.6 (beyond the target)", (150, 45.0, 1.6, 0.6)),
             ("fast: 30 deg, scale 1 -> 1.4 -> 0.75 in 40 frames", (40, 30.0, 1.4, 0.75))]
    print(f"voicepuppet from {voicepuppet.__file__}")
    print("| ramp (seed 0) | frame | mean px | max px | mean / IOD | max / IOD | lips px | lost |")
    print("|---|---|---|---|---|---|---|---|")
    for name, args in ramps:
        frames, truth, angle, _ = similarity_ramp(*args, seed=0)
        name = f"{name} (up to {np.rad2deg(np.abs(np.diff(angle)).max()):.2f} deg/frame)"
        for label, kw in (("default", {}), ("image (frame_points=())", {"frame_points": ()})):
            t0 = time.perf_counter()
            r = tracking.track_frames(frames, truth[0], **kw)
            dt = time.perf_counter() - t0
            print(f"| {name} | {label} | {_scores(r.points, truth, r.lost)} |  ({dt:.2f} s)", flush=True)


if __name__ == "__main__":
    main()
