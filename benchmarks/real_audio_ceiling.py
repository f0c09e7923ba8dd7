"""How much of a real speaker's mouth opening other learners find in the same audio features
(docs/results.md, "Real people"). Usage:

    python benchmarks/real_audio_ceiling.py [--json OUT.json]

The protocol of ``voicepuppet evaluate --corpus real`` (leave one of Obama's sessions out, the
recordings inside the package, the same tracks, audio-video offsets and map to the reference).
Every learner hears the default puppet's audio features as its ridge does (standardised, ±5
frames of context) and learns from the training sessions' tracked faces:

* ``ridge``: the puppet's guide and ``evaluate``'s ridge row, to all face coordinates, one α;
* ``ridge, per coordinate``: the same with an α per face coordinate (``guide_alpha=per_coordinate``);
* ``ridge, α on the lips``: one α chosen on the error of the lips' points (``guide_alpha=lips``);
* ``the same, 40 components``: in a face space of 99.5 % of the variance, at most 40 components
  (``n_components=0.995, max_components=40``) instead of the default 98 %, at most 12;
* ``ridge to the opening``: a ridge fitted to the tracked opening itself, α by the same CV;
* ``boosted trees``: gradient-boosted regression trees to the opening (scikit-learn's
  ``HistGradientBoostingRegressor``: 300 trees of at most 15 leaves, rate 0.03, L2 1, seeded);

beside the voice puppet (defaults: guided, full motion) and its most probable trajectory.
Printed: per learner the opening's Pearson r with the reference, RMSE (inter-ocular distances)
and spread (standard deviation over the truth's), each the frame-weighted mean over the ten
held-out clips, as ``evaluate``'s table; and the r at which a mouth with 0.7 of the truth's
spread would reach the ridge's RMSE (``RMSE^2 = var(t) (1 + s^2 - 2 r s)`` per clip, biases
aside).
"""

from __future__ import annotations

import argparse
import json
import sys
import warnings
from pathlib import Path

import numpy as np
from sklearn.ensemble import HistGradientBoostingRegressor

from voicepuppet.evaluation import real
from voicepuppet.face import FaceSpace
from voicepuppet.puppet.guide import RidgeBaseline, context_stack, lips_score
from voicepuppet.puppet.sources import training_sequences
from voicepuppet.puppet.sync import mouth_opening


class _Trees:
    """Boosted trees from context-stacked features to the opening."""

    def __init__(self, k: int):
        self.k = k
        self.model = HistGradientBoostingRegressor(max_iter=300, learning_rate=0.03, max_leaf_nodes=15,
                                                   l2_regularization=1.0, random_state=0)

    def fit(self, feats, openings):
        self.model.fit(np.vstack([context_stack(f, self.k) for f in feats]), np.concatenate(openings))
        return self

    def predict(self, f):
        return self.model.predict(context_stack(f, self.k))


def _learners(models, clips, track) -> dict:
    """Each learner as features -> tracked opening, fitted on ``clips`` (the training sessions)."""
    main = models.puppets["voice puppet"]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        points, sounds, _, _ = training_sequences(landmarks=[track(c) for c in clips], audio=[c.video for c in clips])
    feats = [main.ridge_input(main.audio_features(a, n_out=len(p))) for p, a in zip(points, sounds)]
    faces = [main.face_space.encode(p)[0] for p in points]
    openings = [mouth_opening(p) for p in points]
    per_coordinate = RidgeBaseline(per_target=True).fit(feats, faces)
    on_lips = RidgeBaseline(score=lips_score(main.face_space)).fit(feats, faces)
    wide = FaceSpace.fit(points, 0.995, max_components=40)
    wide_lips = RidgeBaseline(score=lips_score(wide)).fit(feats, [wide.encode(p)[0] for p in points])
    to_opening = RidgeBaseline().fit(feats, [o[:, None] for o in openings])
    trees = _Trees(models.ridge.k).fit(feats, openings)

    def via_face(ridge, space=main.face_space):
        return lambda f: mouth_opening(space.decode(ridge.predict(f)))

    return {"ridge": via_face(models.ridge), "ridge, per coordinate": via_face(per_coordinate),
            "ridge, α on the lips": via_face(on_lips), "the same, 40 components": via_face(wide_lips, wide),
            "ridge to the opening": lambda f: to_opening.predict(f)[:, 0], "boosted trees": trees.predict}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--json", metavar="OUT.json")
    args = ap.parse_args(argv)
    clips = real.real_clips(speaker="obama")
    track = real._tracker(None, False, True)
    sounds = real._in_sync(clips, track)
    rows: dict = {}
    for session in dict.fromkeys(c.session for c in clips):
        train = [c for c in clips if c.session != session]
        models = real._train(train, {}, track)
        learners = _learners(models, train, track)
        main = models.puppets["voice puppet"]
        for clip, sound in zip(clips, sounds):
            if clip.session != session:
                continue
            n = len(clip.opening)
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                f = main.ridge_input(main.audio_features(sound))
                preds = {"voice puppet": mouth_opening(main.animate(sound, fps=clip.fps).animation.points),
                         "voice puppet, most probable": mouth_opening(
                             main.animate(sound, fps=clip.fps, full_motion=False).animation.points)}
            t = np.arange(n) / clip.fps
            for name, learner in learners.items():
                preds[name] = np.interp(t, np.arange(len(f)) / models.fps, learner(f))
            for name, pred in preds.items():
                m = real.opening_measures(np.polyval(models.to_reference, real._fit_length(pred, n)), clip.opening)
                rows.setdefault(name, []).append({"clip": clip.key, "frames": n, **m})
        print(f"{session}: done", file=sys.stderr, flush=True)
    summary = {}
    print(f"{'learner':<30}{'opening r':>10}{'RMSE / IOD':>12}{'spread':>8}")
    for name, per_clip in rows.items():
        w = np.array([r["frames"] for r in per_clip], dtype=np.float64)
        summary[name] = {k: float(np.average([r[k] for r in per_clip], weights=w)) for k in ("r", "rmse", "spread")}
        s = summary[name]
        print(f"{name:<30}{s['r']:>10.3f}{s['rmse']:>12.4f}{s['spread']:>8.2f}")
    ridge = rows["ridge"]
    w = np.array([r["frames"] for r in ridge], dtype=np.float64)
    # per clip, RMSE^2 / var(t) = 1 + s^2 - 2 r s: equal the ridge's at s = 0.7
    needed = float(np.average([(0.7 ** 2 - r["spread"] ** 2 + 2 * r["r"] * r["spread"]) / (2 * 0.7) for r in ridge],
                              weights=w))
    print(f"r a mouth of spread 0.7 needs for the ridge's RMSE: {needed:.3f}")
    if args.json:  # whole or not at all
        out = Path(args.json)
        tmp = out.with_name(out.name + ".part")
        tmp.write_text(json.dumps({"rows": rows, "summary": summary, "needed_r_at_0.7": needed}, indent=1) + "\n")
        tmp.replace(out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
