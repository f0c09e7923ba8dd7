"""What users would pick instead of the puppet (voicepuppet.evaluation.rhubarb, .learned): Rhubarb's
cues mapped to planted shape means, Rhubarb missing, failing or unreadable, the learned network on a
planted audio-to-face relation, and both rows in the cross-validation tables with finite numbers.

Tests that run Rhubarb need its executable (``$VOICEPUPPET_RHUBARB`` or
``../shared/peers/rhubarb/rhubarb``, present in CI); the learned peer's need PyTorch (a test
dependency)."""

from __future__ import annotations

import os
import stat

import numpy as np
import pytest

from voicepuppet.evaluation import rhubarb as rb

SEED = 20260404
RHUBARB = rb.find_rhubarb()
needs_rhubarb = pytest.mark.skipif(RHUBARB is None, reason="Rhubarb Lip Sync not found: set VOICEPUPPET_RHUBARB "
                                                           "or put it at ../shared/peers/rhubarb/rhubarb")


def test_shape_map_recovers_planted_shape_means():
    """Frames under each shape scatter about a planted mean: the map gives each shape its mean
    back, a shape no training frame has the overall mean, and the nearest mean the planted shape."""
    rng = np.random.default_rng(SEED)
    print("seed", SEED)
    planted = {s: rng.normal(scale=5.0, size=3) for s in "ABCDX"}
    shapes = [rng.choice(list(planted), size=n) for n in (300, 250, 400)]
    values = [np.array([planted[s] for s in ss]) + rng.normal(scale=0.3, size=(len(ss), 3)) for ss in shapes]
    m = rb.ShapeMap().fit(shapes, values)
    for s, mu in planted.items():
        np.testing.assert_allclose(m.means_[s], mu, atol=0.1)
    assert sum(m.counts_.values()) == 950
    out = m.predict(np.array(["A", "C", "G"]))
    np.testing.assert_allclose(out[:2], [m.means_["A"], m.means_["C"]])
    np.testing.assert_allclose(out[2], np.vstack(values).mean(axis=0))  # G: never seen
    assert (m.nearest(values[0]) == shapes[0]).mean() > 0.99
    opening = rb.ShapeMap().fit([np.array(["A", "A", "D"])], [np.array([0.0, 0.1, 0.4])])  # one value per frame
    assert opening.predict(np.array(["D", "A"])).tolist() == pytest.approx([0.4, 0.05])
    with pytest.raises(ValueError, match="same frames"):
        rb.ShapeMap().fit([np.array(["A"])], [np.zeros(2)])


def test_frame_shapes_and_agreement():
    cues = [{"start": 0.0, "end": 0.1, "value": "X"}, {"start": 0.1, "end": 0.25, "value": "B"},
            {"start": 0.25, "end": 0.4, "value": "A"}]
    assert "".join(rb.frame_shapes(cues, 12, 30.0)) == "XXXBBBBBAAAA"  # frame t at t / 30 s; past the end: the last
    assert "".join(rb.frame_shapes([], 3, 30.0)) == "XXX"
    a = rb.cue_agreement(np.array(list("AABX")), np.array(list("ABBX")))
    assert a["agreement"] == 0.75 and a["confusion"]["B"] == {"A": 1, "B": 1} and a["recall"]["B"] == 0.5


def _fake(tmp_path, body):
    exe = tmp_path / "rhubarb"
    exe.write_text("#!/bin/sh\n" + body)
    exe.chmod(exe.stat().st_mode | stat.S_IEXEC)
    return exe


def test_rhubarb_missing_failing_or_unreadable_is_said(tmp_path, monkeypatch):
    monkeypatch.setenv("VOICEPUPPET_RHUBARB", str(tmp_path / "nowhere"))
    with pytest.raises(rb.RhubarbError, match=r"not at .*nowhere \(from \$VOICEPUPPET_RHUBARB\)"):
        rb.Rhubarb()
    monkeypatch.delenv("VOICEPUPPET_RHUBARB")
    monkeypatch.setattr(rb, "_DEFAULT", tmp_path / "absent" / "rhubarb")
    monkeypatch.chdir(tmp_path)
    assert rb.find_rhubarb() is None
    with pytest.raises(rb.RhubarbError, match="Rhubarb Lip Sync not found: set VOICEPUPPET_RHUBARB"):
        rb.Rhubarb()
    x = np.sin(np.arange(1600) / 5.0) * 0.1
    failing = rb.Rhubarb(_fake(tmp_path, 'echo "Error: no speech" >&2; exit 3\n'))
    with pytest.raises(rb.RhubarbError, match=r"failed with exit code 3: Error: no speech"):
        failing.cues(x, 16000)
    # it writes what -o names: garbage instead of cues
    (tmp_path / "g").mkdir()
    garbage = rb.Rhubarb(_fake(tmp_path / "g", 'while [ "$1" != "-o" ]; do shift; done; echo nonsense > "$2"\n'))
    with pytest.raises(rb.RhubarbError, match="not Rhubarb's JSON cues"):
        garbage.cues(x, 16000)
    with pytest.raises(ValueError, match="recognizer must be one of"):
        garbage.cues(x, 16000, "whisper")


@needs_rhubarb
def test_rhubarb_cues_of_speech_with_both_recognisers(tmp_path):
    from voicepuppet.synth import speech

    u = speech.speak("Before breakfast, Bill went for a brisk walk by the beach.", voice="en-us", rate=150)
    r = rb.Rhubarb(cache_dir=tmp_path)
    for rec in rb.RECOGNIZERS:
        cues = r.cues(u.samples, u.rate, rec)
        assert cues[0]["start"] == 0 and cues[-1]["end"] == pytest.approx(len(u.samples) / u.rate, abs=0.02)
        assert {c["value"] for c in cues} <= set(rb.SHAPES) and len({c["value"] for c in cues}) >= 4
        assert r.cues(u.samples, u.rate, rec) == cues  # kept by content
    assert len(list(tmp_path.glob("*.json"))) == 2


def test_learned_peer_beats_the_mean_face_on_a_planted_relation():
    """Audio features that say which planted face the frame shows: the network, early-stopped on a
    held-out training sequence, gets Err well below the mean face's 1, the same at the same seed."""
    pytest.importorskip("torch")
    from support import planted_puppet_data

    from voicepuppet.evaluation import metrics
    from voicepuppet.evaluation.learned import ConvRegressor
    from voicepuppet.face import FaceSpace

    data = [planted_puppet_data(np.random.default_rng(100 + s), T=240)[:2] for s in range(6)]
    fs = FaceSpace.fit([p for p, _ in data[:4]], n_components=3)
    Y = [fs.encode(p)[0] for p, _ in data]
    X = np.vstack([f for _, f in data[:4]])
    F = [(f - X.mean(axis=0)) / X.std(axis=0) for _, f in data]
    net = ConvRegressor(seed=0).fit(F[:4], Y[:4])
    pred = np.vstack([net.predict(f) for f in F[4:]])
    err = metrics.err(pred, np.vstack(Y[4:]))
    print("learned Err", err, "epochs", net.epochs_)
    assert err < 0.05 and 0 < net.best_epoch_ <= net.epochs_
    np.testing.assert_array_equal(ConvRegressor(seed=0).fit(F[:4], Y[:4]).predict(F[4]), net.predict(F[4]))
    with pytest.raises(ValueError, match="two or more training sequences"):
        ConvRegressor().fit(F[:1], Y[:1])


@needs_rhubarb
def test_cross_validation_rows_of_rhubarb_and_the_learned_peer():
    """Four espeak-ng sentences, two folds: the rhubarb and learned rows with finite measures,
    paired with the puppet, and the cue agreement tables."""
    pytest.importorskip("torch")
    from test_crossval import espeak_sequences

    from voicepuppet.evaluation import crossval as ev, report

    seqs = espeak_sequences()
    res = ev.cross_validate(seqs, k=2, seed=0, peers=False, n_states=8, progress=False,
                            rhubarb=rb.Rhubarb(), learned=True)
    assert list(res["models"])[:5] == ["voice-puppet", "ridge", "mean-face", "rhubarb", "learned"]
    for name in ("rhubarb", "learned"):
        for m in ("l1", "rms", "err", "lve", "rmse_iod"):
            assert np.isfinite(res["models"][name][m]["folds"]).all() and len(res["models"][name][m]["folds"]) == 2
        assert {"err", "lve", "rmse_iod"} <= set(res["differences"]["voice-puppet"][name])
    info = res["rhubarb"]
    assert info["recognizer"] in rb.RECOGNIZERS
    assert res["models"]["rhubarb"]["err"] == info["recognizers"][info["recognizer"]]["err"]
    assert min(v["err"]["mean"] for v in info["recognizers"].values()) == res["models"]["rhubarb"]["err"]["mean"]
    frames = sum(len(s.points) for s in seqs)
    for rec in rb.RECOGNIZERS:
        for how in ("geometry", "centroid"):
            for who in ("rhubarb", "export"):
                a = info["cues"][rec][how][who]
                assert 0 <= a["agreement"] <= 1 and len(a["folds"]) == 2
                assert sum(sum(r.values()) for r in a["confusion"].values()) == frames
    table = report.format_table(res)
    assert f"| rhubarb ({info['recognizer']}) |" in table and "| learned |" in table
    assert f"| voice-puppet − rhubarb ({info['recognizer']}) |" in table and "| voice-puppet − learned |" in table
    assert "| cue agreement with the truth-derived cues | geometry | centroid |" in table
    with pytest.raises(ValueError, match="beside the voice puppet"):
        ev.cross_validate(seqs, k=2, peers=True, puppet=False, learned=True, progress=False)


def test_evaluate_peers_says_a_missing_rhubarb(capsys):
    from voicepuppet.cli.main import main

    assert main(["evaluate", "--peers", "--rhubarb", os.devnull + "-none", "-q"]) == 2
    assert "Rhubarb Lip Sync is not at" in capsys.readouterr().err
    assert main(["evaluate", "--rhubarb", "x", "-q"]) == 2
    assert "--rhubarb is for --peers" in capsys.readouterr().err
