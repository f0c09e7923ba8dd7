"""Planted head rotation and scale for the tracker: the performer's photo seen through a known
similarity ramp (the generator of ``test_tracking.py::test_tracking_holds_under_head_rotation_and_scale``),
and, run as a script, the longer measurement of docs/tracking.md's table:

    PYTHONPATH=python python3 tests/tracking_pose_ramp.py

It tracks with whichever ``voicepuppet`` is imported (so the same script measures an older
installed copy), with the defaults and with the image frame (``frame_points=()``), and prints
mean and max landmark error (px and inter-ocular distances), the lip error and the lost fraction.
"""

from __future__ import annotations

import numpy as np


def similarity_ramp(n_frames: int, max_angle: float, max_scale: float, min_scale: float, seed: int,
                    noise: float = 2.0, canvas: int = 400):
    """The performer's photo (grey, 320x320, reflect-padded to ``canvas``) seen through a known
    similarity ramp about the face centre: rotation 0 -> ``max_angle`` degrees -> 0, scale
    1 -> ``max_scale`` -> ``min_scale`` -> 1, and a translation of up to 20 px, with Gaussian
    noise (seeded). The 68 landmarks are transformed exactly. Returns (frames [T, H, W] uint8,
    truth [T, 68, 2], angle [T] rad, scale [T])."""
    import cv2

    from voicepuppet.synth import face_photo

    photo = face_photo((320, 320), fallback=False)
    grey = cv2.cvtColor(photo.image, cv2.COLOR_RGB2GRAY)
    pad = (canvas - 320) // 2
    image = cv2.copyMakeBorder(grey, pad, pad, pad, pad, cv2.BORDER_REFLECT).astype(np.float32)
    points = photo.points + pad
    centre = points.mean(axis=0)
    u = np.linspace(0.0, 1.0, n_frames)
    angle = np.deg2rad(max_angle) * np.sin(np.pi * u)
    scale = np.interp(u, [0.0, 0.35, 0.75, 1.0], [1.0, max_scale, min_scale, 1.0])
    shift = np.stack([20 * np.sin(2 * np.pi * u), 10 * np.sin(4 * np.pi * u)], axis=1)
    rng = np.random.default_rng(seed)
    frames, truth = [], []
    for a, s, b in zip(angle, scale, shift):
        A = s * np.array([[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]])
        t = centre - A @ centre + b
        f = cv2.warpAffine(image, np.hstack([A, t[:, None]]), (canvas, canvas), flags=cv2.INTER_CUBIC,
                           borderMode=cv2.BORDER_REFLECT)
        frames.append(np.clip(np.round(f + rng.normal(0.0, noise, f.shape)), 0, 255).astype(np.uint8))
        truth.append(points @ A.T + t)
    return np.stack(frames), np.stack(truth), angle, scale


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
