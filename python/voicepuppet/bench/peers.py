"""``voicepuppet bench peers``: the voice puppet's speed beside what users would pick instead.

On the synthetic performer (60 s of training speech, three held-out sentences; 30 s and one in
``--quick``), one core each: Rhubarb Lip Sync on the held-out sound with each of its two
recognisers (``--threads 1``; its cues only, the mapping to a face is free), the learned peer
(:class:`voicepuppet.evaluation.learned.ConvRegressor`: audio features, the network and the
decoding to landmarks), both against the puppet animating the same sound (features, Viterbi,
synthesis); and training, the learned peer against the puppet, on the training clip. Inference
cases are interleaved and their medians taken; each carries ``realtime_factor`` (seconds of
audio per second of compute, the peer's as ``peer_realtime_factor``) and
``seconds_per_audio_second`` of both. ``agree`` is None: the answers are different models'.

Rhubarb is found as :func:`voicepuppet.evaluation.rhubarb.find_rhubarb` does (at
``$VOICEPUPPET_RHUBARB`` or ``../shared/peers/rhubarb/rhubarb``); the learned peer needs PyTorch.
"""

from __future__ import annotations

import os
import time

import numpy as np

from voicepuppet import audio as vaudio, data, synth
from voicepuppet.bench.runner import case, timeit_interleaved
from voicepuppet.evaluation.learned import ConvRegressor, torch_available
from voicepuppet.evaluation.rhubarb import RECOGNIZERS, Rhubarb, find_rhubarb
from voicepuppet.puppet import Puppet


def _corpus(seconds: float, n_test: int):
    root = os.path.join(data.cache_dir(), f"bench-peers-{int(seconds)}-{n_test}")
    return synth.make_corpus(root, train_seconds=seconds, n_test=n_test, real_test=False, progress=False)


def run(quick: bool = False, repeats: int = 3) -> list[dict]:
    """The peers suite's cases (see the module's docstring).

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
    ValueError
        Rhubarb Lip Sync not found, or PyTorch missing (the message says what to do).
    """
    if find_rhubarb() is None:
        raise ValueError("the peers benchmark needs Rhubarb Lip Sync: set VOICEPUPPET_RHUBARB to its 'rhubarb' "
                         "executable")
    if not torch_available():
        raise ValueError("the peers benchmark needs PyTorch for the learned peer: pip install torch==2.13.0")
    rhubarb = Rhubarb()
    corpus = _corpus(30.0 if quick else 60.0, 1 if quick else 3)
    train = corpus.train
    sound = vaudio.load_audio(train.audio)
    tests = [vaudio.load_audio(c.audio) for c in corpus.test]
    test = vaudio.prepare(np.concatenate([t.samples for t in tests]), tests[0].rate)
    seconds = len(test.samples) / test.rate
    fps = train.fps

    # training: the puppet (landmarks + audio) and the learned peer (the same features, face coordinates)
    times = {"puppet": [], "learned": []}
    for _ in range(max(1, repeats if quick else min(repeats, 2))):
        t0 = time.perf_counter()
        puppet = Puppet.train([train.points], [sound], fps=fps)
        t1 = time.perf_counter()
        feats = puppet.audio_features(sound, n_out=len(train.points))
        faces = puppet.face_space.encode(train.points)[0]
        cut = np.linspace(0, len(faces), 6).astype(int)  # five pieces: early stopping holds one out
        net = ConvRegressor(seed=0).fit([puppet.ridge_input(feats[a:b]) for a, b in zip(cut[:-1], cut[1:])],
                                        [faces[a:b] for a, b in zip(cut[:-1], cut[1:])])
        t2 = time.perf_counter()
        times["puppet"].append(t1 - t0)
        times["learned"].append(t2 - t1)
    med = {k: float(np.median(v)) for k, v in times.items()}
    train_s = len(sound.samples) / sound.rate
    cases = [case("train: learned", f"{train_s:.0f} s of landmarks + audio", med["puppet"], "learned (torch, 1 thread)",
                  med["learned"], None, realtime_factor=train_s / med["puppet"],
                  peer_realtime_factor=train_s / med["learned"], epochs=net.epochs_)]

    def learned():
        f = puppet.ridge_input(puppet.audio_features(test))
        return puppet.face_space.decode(net.predict(f))

    fns = {"puppet": lambda: puppet.animate(test, fps=fps), "learned": learned}
    fns.update({rec: (lambda rec=rec: rhubarb.cues(test.samples, test.rate, rec)) for rec in RECOGNIZERS})
    med, _ = timeit_interleaved(fns, repeats)
    size = f"{seconds:.1f} s of held-out speech ({len(tests)} sentences)"
    for peer, name in (("learned", "learned (torch, 1 thread)"),
                       *((rec, f"rhubarb 1.14.0 {rec} (1 thread)") for rec in RECOGNIZERS)):
        cases.append(case(f"animate: {peer}", size, med["puppet"], name, med[peer], None,
                          realtime_factor=seconds / med["puppet"], peer_realtime_factor=seconds / med[peer],
                          seconds_per_audio_second=med["puppet"] / seconds,
                          peer_seconds_per_audio_second=med[peer] / seconds))
    return cases
