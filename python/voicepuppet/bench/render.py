"""Render suite: a landmark animation to an mp4 with the audio muxed, at the size the issue fixes
(30 s at 640x480, 29.97 fps; ``--quick``: 3 s). Cases: the textured mesh renderer (pyvista off
screen, EGL), the 2-D landmark fallback, and the glTF export of the same animation. No peer:
``realtime_factor`` (seconds of video per second of compute) and ``frames_per_s`` are the numbers
to watch; the target is ``ours_s`` <= 30 for the full mesh case.
"""

from __future__ import annotations

import tempfile
from pathlib import Path

import numpy as np

from voicepuppet.animation import procedural_animation
from voicepuppet.bench.runner import case, timeit_interleaved
from voicepuppet import render
from voicepuppet.render import export


def run(quick: bool = False, repeats: int = 1) -> list[dict]:
    """The render suite's cases (see the module's docstring).

    Parameters
    ----------
    quick : bool
        Small sizes, for a smoke run.
    repeats : int
        Timed repeats per case (median).

    Returns
    -------
    list of dict
        Rows made by :func:`voicepuppet.bench.runner.case`.
    """
    import soundfile as sf

    fps, seconds, (w, h) = 30000 / 1001, (3.0 if quick else 30.0), (640, 480)
    n = int(round(seconds * fps))
    anim = procedural_animation(n, fps, width=w, height=h, seed=0)
    face = export.default_face(anim)
    cases = []
    with tempfile.TemporaryDirectory() as tmp:
        wav = Path(tmp) / "speech.wav"
        rate = 16000
        t = np.arange(int(rate * seconds)) / rate
        sf.write(wav, 0.2 * np.sin(2 * np.pi * 220 * t) * (1 + np.sin(2 * np.pi * 3 * t)) / 2, rate)
        jobs = {
            "mesh": lambda: render.render(anim, Path(tmp) / "mesh.mp4", audio=wav, face=face, size=(w, h)),
            "2d": lambda: render.render(anim, Path(tmp) / "flat.mp4", audio=wav, renderer="2d", size=(w, h)),
            "glb": lambda: export.write_glb(anim, Path(tmp) / "a.glb", face=face),
        }
        times, _ = timeit_interleaved(jobs, repeats)
    size = f"{n} frames {w}x{h} @29.97"
    cases.append(case("render_mesh_mp4_audio", size, times["mesh"], None, None, None,
                      realtime_factor=seconds / times["mesh"], frames_per_s=n / times["mesh"]))
    cases.append(case("render_2d_mp4_audio", size, times["2d"], None, None, None,
                      realtime_factor=seconds / times["2d"], frames_per_s=n / times["2d"]))
    cases.append(case("export_glb_au", f"{n} frames, {len(face.vertices)} vertices", times["glb"], None, None,
                      None, frames_per_s=n / times["glb"]))
    return cases
