"""The performer's clips planted in HD frames, tracked at full resolution and at the working
scale (docs/tracking.md, "Large faces: the working scale"). Run as a script:

    python benchmarks/tracking_scale_hd.py make DIR CLIP_DIR [CLIP_DIR ...]
    python benchmarks/tracking_scale_hd.py track VIDEO WORKING_SCALE OUT.json

``make`` writes, for each performer clip directory (``train.mp4`` + ``train.npz``), a copy of
the clip and the clip upscaled 1.5x, 2x and 2.8125x (bicubic), with and without temporal noise
(ffmpeg ``noise=alls=6:allf=t``), padded into 1920x1080 grey (H.264, crf 20), and the truth in
HD pixels ((p + 0.5) s - 0.5 + pad); ``track`` tracks one of them from its true first-frame
points with whichever ``voicepuppet`` is imported (``WORKING_SCALE``: ``auto``, a factor, or
``none`` for a copy without the option) and writes the errors in pixels of the 320x320 clip
(lips 48-67, rest 0-47, eyes 36-47), the lost fraction, the factor and the wall time of
``track_video``, and the points beside it (``OUT.points.npy``).
"""

from __future__ import annotations

import json
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

SCALES = (1.5, 2.0, 2.8125)
NOISE = (0, 6)
HD = (1920, 1080)


def make(out: Path, clips: list[Path]) -> None:
    out.mkdir(parents=True, exist_ok=True)
    for clip in clips:
        truth = np.load(clip / "train.npz")["points"]
        name = clip.name
        (out / f"{name}_native.mp4").write_bytes((clip / "train.mp4").read_bytes())
        np.save(out / f"{name}_native.npy", truth)
        for s in SCALES:
            side = round(320 * s)
            px, py = (HD[0] - side) // 2, (HD[1] - side) // 2
            for noise in NOISE:
                video = out / f"{name}_{s:g}_n{noise}.mp4"
                vf = f"scale={side}:{side}:flags=bicubic," + (f"noise=alls={noise}:allf=t," if noise else "")
                vf += f"pad={HD[0]}:{HD[1]}:{px}:{py}:color=gray"
                subprocess.run(["ffmpeg", "-loglevel", "error", "-y", "-i", str(clip / "train.mp4"), "-vf", vf,
                                "-c:v", "libx264", "-crf", "20", "-pix_fmt", "yuv420p", "-an", str(video)], check=True)
                np.save(video.with_suffix(".npy"), (truth + 0.5) * (side / 320) - 0.5 + [px, py])
                np.save(video.with_suffix(".scale.npy"), np.float64(side / 320))


def track(video: Path, working_scale: str, out: Path) -> None:
    from voicepuppet.tracking import tracker as tracking

    truth = np.load(video.with_suffix(".npy"))
    scale_file = video.with_suffix(".scale.npy")
    s = float(np.load(scale_file)) if scale_file.exists() else 1.0
    kw = {} if working_scale == "none" else {"working_scale": working_scale if working_scale == "auto"
                                             else float(working_scale)}
    t0 = time.perf_counter()
    r = tracking.track_video(video, truth[0], progress=False, **kw)
    dt = time.perf_counter() - t0
    n = min(len(r.points), len(truth))
    err = np.linalg.norm(r.points[:n] - truth[:n], axis=2) / s
    np.save(out.with_suffix(".points.npy"), r.points)
    out.write_text(json.dumps({"video": str(video), "working_scale": getattr(r, "working_scale", 1.0),
                               "lips": float(err[:, 48:].mean()), "rest": float(err[:, :48].mean()),
                               "eyes": float(err[:, 36:48].mean()), "lost": float(r.lost.mean()),
                               "seconds": dt, "frames": n}))


if __name__ == "__main__":
    if sys.argv[1] == "make":
        make(Path(sys.argv[2]), [Path(a) for a in sys.argv[3:]])
    else:
        track(Path(sys.argv[2]), sys.argv[3], Path(sys.argv[4]))
