"""``voicepuppet bench pipeline``: the voice puppet end to end on the synthetic performer.

Cases: training on the performer's landmarks + audio (3 minutes; target ≤ 60 s), and animating an
hour of audio (features + Viterbi + closed-form synthesis; target ≥ 300x real time on one core),
with the animation's stages timed apart. There is no peer for the whole pipeline: the stages'
peers are in the hmm, trajectory and audio suites.
"""

from __future__ import annotations

import os
import time

import numpy as np

from voicepuppet import _core, audio as vaudio, synth
from voicepuppet.bench.runner import case
from voicepuppet.puppet import Puppet


def _corpus(seconds: float):
    root = os.path.join(os.path.expanduser("~"), ".cache", "voicepuppet", f"bench-corpus-{int(seconds)}")
    return synth.make_corpus(root, train_seconds=seconds, n_test=1, real_test=False, progress=False)


def run(quick: bool = False, repeats: int = 3) -> list[dict]:
    """The pipeline suite's cases (see the module's docstring).

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
    seconds = 30.0 if quick else 180.0
    corpus = _corpus(seconds)
    train = corpus.train
    cases = []

    times = []
    for _ in range(max(1, repeats if quick else min(repeats, 2))):
        t0 = time.perf_counter()
        puppet = Puppet.train([train.points], [train.audio], fps=train.fps)
        times.append(time.perf_counter() - t0)
    part = puppet.metadata["training"]["parts"][0]
    cases.append(case("train", f"{train.duration:.0f} s of landmarks + audio, 40 initial states",
                      float(np.median(times)), None, None, None,
                      realtime_factor=train.duration / float(np.median(times)),
                      states=part["states"], face_dims=part["face_dims"], target_s=60.0))

    # An hour of audio: the training clip's sound tiled (features are computed on the whole hour).
    hour = 300.0 if quick else 3600.0
    snd = vaudio.load_audio(train.audio)
    reps = int(np.ceil(hour * snd.rate / len(snd.samples)))
    samples = np.tile(snd.samples, reps)[: int(hour * snd.rate)]
    long_audio = vaudio.prepare(samples, snd.rate)
    stage = {"features": [], "analysis": [], "synthesis": [], "total": []}
    for _ in range(max(1, repeats)):
        t0 = time.perf_counter()
        feats = puppet.audio_features(long_audio)
        t1 = time.perf_counter()
        z = puppet._core.standardize(feats)
        arr = puppet.part_arrays(0)
        _, path = _core.viterbi(puppet._core.vocal_log_density(z), arr["startprob"], arr["transmat"],
                                np.array([len(z)], dtype=np.int64))
        t2 = time.perf_counter()
        puppet.animate(states=path)
        t3 = time.perf_counter()
        stage["features"].append(t1 - t0)
        stage["analysis"].append(t2 - t1)
        stage["synthesis"].append(t3 - t2)
        stage["total"].append(t3 - t0)
    med = {k: float(np.median(v)) for k, v in stage.items()}
    cases.append(case("animate", f"{hour / 60:.0f} min of audio at {puppet.fps:g} fps ({len(feats)} frames)",
                      med["total"], None, None, None, realtime_factor=hour / med["total"],
                      features_s=med["features"], analysis_s=med["analysis"], synthesis_s=med["synthesis"],
                      analysis_synthesis_realtime_factor=hour / (med["analysis"] + med["synthesis"]),
                      target_realtime_factor=300.0))
    return cases
