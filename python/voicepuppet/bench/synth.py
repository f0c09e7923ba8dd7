"""``voicepuppet bench synth``: the synthetic performer.

Cases: the piecewise-affine photo warp of one 320x320 frame against scikit-image's
``PiecewiseAffineTransform`` + ``warp`` on the same landmarks (``agree`` = mean absolute pixel
difference over the face, relative to 255); speaking one sentence (espeak-ng in its worker
process); the articulatory model on 60 s of speech; and the whole 60 s corpus
(``make_corpus``, uncached), with real-time factors (seconds of video per second of compute).
"""

from __future__ import annotations

import tempfile
import time

import numpy as np

from voicepuppet import synth
from voicepuppet.bench.runner import case, timeit_interleaved
from voicepuppet.synth.video import pose_matrices


def _skimage():
    try:
        from skimage.transform import PiecewiseAffineTransform, warp
    except ImportError:
        raise RuntimeError("the synth benchmark's peer needs scikit-image: pip install scikit-image") from None
    return PiecewiseAffineTransform, warp


def run(quick: bool = False, repeats: int = 3) -> list[dict]:
    """The synth suite's cases (see the module's docstring).

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

    Raises
    ------
    RuntimeError
        espeak-ng or scikit-image (the peer) is missing.
    """
    if not synth.espeak_available():
        raise RuntimeError("the synth benchmark needs espeak-ng: apt-get install espeak-ng")
    PiecewiseAffineTransform, sk_warp = _skimage()
    rows = []
    photo = synth.face_photo((320, 320))
    utt = synth.speak("Peter bought a map of the bay before the boats came back.")
    art = synth.articulate(utt.phones, utt.samples, utt.rate, photo.points, seed=0)
    t = int(np.argmax(art.param("gap")))
    warper = synth.FaceWarper(photo.image, photo.points)
    dst = warper.mesh_points(art.points[t], pose_matrices(art.pose[t:t + 1], art.centre)[0])

    def ours():
        return warper.warp(dst)

    def peer():
        # output -> input coordinates: the inverse map that warp takes
        if hasattr(PiecewiseAffineTransform, "from_estimate"):
            tf = PiecewiseAffineTransform.from_estimate(dst, warper.src)
        else:
            tf = PiecewiseAffineTransform()
            tf.estimate(dst, warper.src)
        return sk_warp(photo.image, tf, output_shape=photo.image.shape[:2], order=1,
                       preserve_range=True)

    med, res = timeit_interleaved({"ours": ours, "peer": peer}, repeats)
    lo = np.floor(art.points[t].min(axis=0)).astype(int)
    hi = np.ceil(art.points[t].max(axis=0)).astype(int)
    a = res["ours"][lo[1]:hi[1], lo[0]:hi[0]].astype(np.float64)
    b = res["peer"][lo[1]:hi[1], lo[0]:hi[0]].astype(np.float64)
    rows.append(case("warp frame", "320x320, 68 landmarks + ring + border", med["ours"],
                     "skimage PiecewiseAffineTransform+warp", med["peer"],
                     float(np.mean(np.abs(a - b)) / 255.0), frames_per_s=1.0 / med["ours"]))

    med, res = timeit_interleaved({"speak": lambda: synth.speak(
        "Please remember to feed the fish before you leave.", voice="en-gb-x-rp", rate=170)}, repeats)
    rows.append(case("speak", f"one sentence, {res['speak'].duration:.1f} s", med["speak"], None, None,
                     None, realtime_factor=res["speak"].duration / med["speak"]))

    seconds = 10.0 if quick else 60.0
    long = synth.concatenate([utt] * int(np.ceil(seconds / utt.duration)),
                             [0.3] * int(np.ceil(seconds / utt.duration)))
    med, res = timeit_interleaved({"art": lambda: synth.articulate(
        long.phones, long.samples, long.rate, photo.points, seed=0)}, repeats)
    rows.append(case("articulate", f"{long.duration:.0f} s at 29.97 fps", med["art"], None, None, None,
                     realtime_factor=long.duration / med["art"]))

    with tempfile.TemporaryDirectory() as tmp:
        t0 = time.perf_counter()
        corpus = synth.make_corpus(tmp, train_seconds=seconds, n_test=3, seed=0, progress=False)
        dt = time.perf_counter() - t0
    video_s = corpus.train.duration + sum(c.duration for c in corpus.test)
    rows.append(case("make_corpus", f"train {corpus.train.duration:.1f} s + {len(corpus.test)} test clips, "
                     "320x320", dt, None, None, None, realtime_factor=video_s / dt))
    return rows
