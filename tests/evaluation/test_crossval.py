"""Tests of voicepuppet.evaluation.crossval: the cross-validation harness on planted truth (faces that follow
a DPDS exactly are reproduced by the DPDS and not by per-phoneme means), the fold metrics against
a direct computation, the performer clip split at sentence pauses, and the ``evaluate`` verb on
user data (files written atomically, bad input refused)."""

from __future__ import annotations

import json
import types

import numpy as np
import pytest

from voicepuppet.phonemes import models as dpds
from voicepuppet.evaluation import corpus, report
from voicepuppet.evaluation import crossval as ev
from voicepuppet.phonemes import labels as ph
from voicepuppet.animation import neutral_landmarks
from voicepuppet.cli.main import main

SEED = 20261123
PHONE_SET = [ph.PHONE_INDEX[p] for p in ("SIL", "AA", "M", "IY", "UW", "F", "S", "OW")]


def planted_sequences(rng, n_seq=9, T=70, K=3):
    """Landmarks whose face coordinates follow a DPDS of the labels exactly."""
    P = ph.N_PHONES
    a = np.full((P, K), 0.5)
    mu = np.zeros((P, K))
    nu = np.zeros((P, K))
    for p in PHONE_SET:
        a[p] = rng.uniform(0.5, 0.9, K)
        mu[p] = rng.normal(size=K)
        nu[p] = rng.normal(size=K)
    neutral = neutral_landmarks()
    basis = rng.normal(size=(K, 68, 2)) * 2.0
    # remove the similarity directions (translation, rotation, scale) at the neutral face, which
    # the face space's Procrustes step takes out
    c = neutral - neutral.mean(axis=0)
    sim = np.stack([np.tile([1.0, 0.0], (68, 1)), np.tile([0.0, 1.0], (68, 1)), c,
                    np.stack([-c[:, 1], c[:, 0]], axis=1)]).reshape(4, -1)
    q, _ = np.linalg.qr(sim.T)
    flat = basis.reshape(K, -1)
    basis = (flat - (flat @ q) @ q.T).reshape(K, 68, 2)
    seqs = []
    for s in range(n_seq):
        lab = [ph.PHONE_INDEX["SIL"]] * 5
        while len(lab) < T:
            lab += [int(rng.choice(PHONE_SET))] * int(rng.integers(2, 7))
        lab = np.array(lab[:T], np.int64)
        Y = dpds._core.dpds_generate(a, mu, nu, lab, np.zeros(0, np.int64))
        pts = neutral + np.einsum("tk,kpc->tpc", Y, basis)
        seqs.append(corpus.Sequence(f"s{s}", pts, 30.0, lab))
    return seqs


def test_cross_validation_on_planted_dpds_faces():
    rng = np.random.default_rng(SEED)
    print("seed", SEED)
    # one face dimension: the face space's PCA then recovers it up to sign and offset, which a
    # DPDS absorbs (diagonal transitions are not invariant to rotations of several dimensions)
    seqs = planted_sequences(rng, K=1)
    res = ev.cross_validate(seqs, k=3, seed=1, peers=True, puppet=False, n_components=1, progress=False)
    models = res["models"]
    assert list(models) == list(dpds.MODELS)
    assert sorted(sum(res["config"]["folds"], [])) == sorted(s.name for s in seqs)
    # the DPDS reproduces faces that follow a DPDS; the phoneme means cannot
    print({n: (m["err"]["mean"], m["rmse_iod"]["mean"]) for n, m in models.items()})
    # (what remains is the face space's Procrustes step, not linear in the planted coordinate)
    assert models["dpds"]["err"]["mean"] < 2e-3
    assert models["dpds"]["err"]["mean"] < models["phoneme-mean"]["err"]["mean"] / 20
    assert models["dpds"]["rmse_iod"]["mean"] < models["phoneme-mean"]["rmse_iod"]["mean"] / 5
    assert models["dpds"]["loglik"]["mean"] > models["phoneme-mean"]["loglik"]["mean"]
    for m in models.values():
        for key in ("l1", "rms", "linf", "err", "lve", "rmse_iod", "loglik", "closed"):
            v = m[key]
            assert v["low"] <= v["mean"] <= v["high"] and len(v["folds"]) == 3
        assert all(0 <= f <= 1 for f in m["closed"]["folds"])
    table = report.format_table(res)
    assert table.count("\n| ") == 4 and table.startswith("| model |") and "RMSE / IOD" in table


def test_closed_is_summarised_over_the_folds_with_bilabials():
    """A fold whose test sequences hold no B, P or M has no closed share: the measure is summarised
    over the others (listed in fold_index), for the models and the paired differences alike."""
    from voicepuppet.evaluation.folds import kfold

    rng = np.random.default_rng(SEED + 2)
    seqs = planted_sequences(rng, n_seq=6, T=40)
    m, aa = ph.PHONE_INDEX["M"], ph.PHONE_INDEX["AA"]
    folds = kfold(len(seqs), 3, 0)
    for i in folds[0][1]:  # the first fold's test sequences lose their M
        seqs[i].labels[seqs[i].labels == m] = aa
    assert all(any((seqs[i].labels == m).any() for i in te) for _, te in folds[1:])
    res = ev.cross_validate(seqs, k=3, seed=0, peers=True, puppet=False, n_components=2, progress=False)
    for entry in res["models"].values():
        assert entry["closed"]["fold_index"] == [1, 2] and len(entry["closed"]["folds"]) == 2
        assert len(entry["err"]["folds"]) == 3 and "fold_index" not in entry["err"]
    assert "over the folds whose test sequences have one" in report.format_table(res)


def test_fold_metrics_equal_direct_computation():
    from voicepuppet.face import FaceSpace

    rng = np.random.default_rng(SEED + 1)
    seqs = planted_sequences(rng, n_seq=3, T=40)
    fs = FaceSpace.fit([s.points for s in seqs], n_components=3)
    Yt = [fs.encode(s.points)[0] for s in seqs]
    Yp = [y + rng.normal(scale=0.1, size=y.shape) for y in Yt]
    got = ev._fold_metrics(Yp, Yt, fs, loglik=-50.0)
    d = np.concatenate(Yp) - np.concatenate(Yt)
    assert got["l1"] == pytest.approx(np.mean(np.abs(d)))
    assert got["rms"] == pytest.approx(np.sqrt(np.mean(d ** 2)))
    assert got["linf"] == pytest.approx(np.max(np.abs(d)))
    assert got["loglik"] == pytest.approx(-50.0 / 120)
    Pp, Pt = fs.decode(np.concatenate(Yp)), fs.decode(np.concatenate(Yt))
    lve = np.mean(np.max(np.sum((Pp[:, 48:68] - Pt[:, 48:68]) ** 2, axis=2), axis=1))
    assert got["lve"] == pytest.approx(lve)
    assert "closed" not in got  # no must-close frames given
    # the closed share pools the runs of all sequences (runs do not join across sequences)
    from voicepuppet.evaluation import metrics

    must = [s.labels[:40] == ph.PHONE_INDEX["M"] for s in seqs]
    counts = [metrics.closures(fs.decode(p), fs.decode(t), m) for p, t, m in zip(Yp, Yt, must)]
    assert sum(n for _, n in counts) > 0
    want = sum(c for c, _ in counts) / sum(n for _, n in counts)
    assert ev._fold_metrics(Yp, Yt, fs, None, must)["closed"] == pytest.approx(want)


def test_closures_count_the_runs_the_prediction_closes():
    """metrics.closures: of the runs of must-close frames, those in which the prediction's lip gap
    (points 62-66) gets to at most 1 % of the true inter-ocular distance, in any frame of the run."""
    from voicepuppet.evaluation import metrics

    truth = np.repeat(neutral_landmarks()[None], 20, axis=0)
    iod = np.linalg.norm(truth[0, 36] - truth[0, 45])
    pred = truth.copy()
    gap = np.full(20, 10.0)  # open everywhere ...
    gap[4] = 0.0             # ... but shut in the first run,
    gap[11] = 0.01 * iod     # just at the threshold in the second,
    gap[16] = 0.011 * iod    # just over it in the third
    pred[:, 66] = pred[:, 62] + np.stack([np.zeros(20), gap], axis=1)
    must = np.zeros(20, bool)
    must[[3, 4, 5, 10, 11, 12, 16, 17, 19]] = True  # four runs: 3-5, 10-12, 16-17, 19
    assert metrics.closures(pred, truth, must) == (2, 4)
    assert metrics.closures(pred, truth, np.zeros(20, bool)) == (0, 0)
    assert metrics.closures(truth, truth, must) == (0, 4)  # this rest face's lips are 2.2 px (0.023 IOD) apart
    with pytest.raises(ValueError, match="one entry per frame"):
        metrics.closures(pred, truth, must[:-1])
    with pytest.raises(ValueError, match="needs points"):
        metrics.closures(pred[:, :40], truth[:, :40], must)


def test_split_clip_at_sentence_pauses():
    from voicepuppet.synth import speech
    from voicepuppet.synth.articulation import articulate

    u1 = speech.speak("Please remember to feed the fish.")
    u2 = speech.speak("Who knows where the ferry goes?")
    u = speech.concatenate([u1, u2], [0.4, 0.3])
    fps = 30000 / 1001
    art = articulate(u.phones, u.samples, u.rate, neutral_landmarks(), fps=fps, seed=1)
    clip = types.SimpleNamespace(points=art.points, fps=fps, rate=u.rate, samples=u.samples,
                                 phones=u.phones, source=u.source, text=u.text)
    seqs = corpus.split_clip(clip, name="c")
    assert len(seqs) == 2
    assert sum(len(s.points) for s in seqs) == len(art.points)
    # the cut lies inside the 0.4 s pause after the first sentence
    cut = len(seqs[0].points) / fps
    assert u1.duration < cut < u1.duration + 0.4
    assert seqs[0].labels[-1] == ph.PHONE_INDEX["SIL"] and seqs[1].labels[0] == ph.PHONE_INDEX["SIL"]
    assert abs(len(seqs[0].samples) / u.rate - cut) < 1.0 / u.rate + 1e-9


def write_user_data(folder, seqs):
    for s in seqs:
        np.savez(folder / f"{s.name}.npz", points=s.points, fps=s.fps)
        ph.write_hts(ph.label_intervals(s.labels, s.fps), folder / f"{s.name}.lab")


def test_evaluate_verb_on_user_data(tmp_path, capsys):
    rng = np.random.default_rng(SEED + 2)
    data = tmp_path / "data"
    data.mkdir()
    write_user_data(data, planted_sequences(rng, n_seq=4, T=40))
    md, js = tmp_path / "r.md", tmp_path / "r.json"
    rc = main(["evaluate", "--data", str(data), "--folds", "2", "--peers", "--no-puppet",
               "--components", "3", "-o", str(md), "--json", str(js), "-q"])
    assert rc == 0
    out = capsys.readouterr().out
    assert "| dpds |" in out and f"wrote {md}" in out
    result = json.loads(js.read_text())
    assert set(result["models"]) == set(dpds.MODELS)
    assert result["command"].startswith("voicepuppet evaluate --data")
    assert "| slds |" in md.read_text()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["data", "r.json", "r.md"]


def test_evaluate_bad_input(tmp_path, capsys):
    rng = np.random.default_rng(SEED + 3)
    data = tmp_path / "data"
    data.mkdir()
    write_user_data(data, planted_sequences(rng, n_seq=3, T=30))
    md = tmp_path / "r.md"
    assert main(["evaluate", "--data", str(data), "--folds", "10", "--peers", "--no-puppet",
                 "-o", str(md), "-q"]) == 2
    assert "cannot make 10 non-empty folds from 3 sequences" in capsys.readouterr().err
    assert not md.exists()
    (data / "s0.lab").unlink()
    assert main(["evaluate", "--data", str(data), "--peers", "--no-puppet", "-q"]) == 2
    assert "no phone labels" in capsys.readouterr().err
    ph.write_hts([("sil", 0, 0.5)], data / "s0.lab")  # 30 frames = 1 s: labels too short
    assert main(["evaluate", "--data", str(data), "--peers", "--no-puppet", "-q"]) == 2
    assert "must cover the audio" in capsys.readouterr().err
    with pytest.raises(ValueError, match="nothing to evaluate"):
        ev.cross_validate(planted_sequences(rng, n_seq=3, T=30), k=2, peers=False, puppet=False)


def espeak_sequences():
    """Four espeak-ng sentences articulated by the performer, with their audio and phone labels."""
    from voicepuppet.synth import speech
    from voicepuppet.synth.articulation import articulate

    fps = 30000 / 1001
    seqs = []
    texts = ["Please remember to feed the fish before you leave.",
             "Who knows where the old ferry will take us tomorrow?",
             "Before breakfast, Bill went for a brisk walk by the beach.",
             "You can hear the waves when the wind blows from the west."]
    for i, text in enumerate(texts):
        u = speech.speak(text, voice="en-us", rate=150)
        art = articulate(u.phones, u.samples, u.rate, neutral_landmarks(), fps=fps, seed=i)
        lab = ph.frame_labels(u.phones, len(art.points), fps, alphabet="espeak")
        n = int(round(len(art.points) / fps * u.rate))
        x = np.zeros(n, np.float32)
        x[:min(n, len(u.samples))] = u.samples[:n]
        seqs.append(corpus.Sequence(f"u{i}", art.points, fps, lab, x, u.rate))
    return seqs


def test_voice_puppet_on_the_same_folds():
    """The puppet hears only the audio; on held-out utterances it must beat the mean face
    (Err 1) and its rows carry no phone-conditioned log-likelihood."""
    seqs = espeak_sequences()
    res = ev.cross_validate(seqs, k=2, seed=0, peers=False, puppet=True, n_states=8, progress=False)
    m = res["models"]["voice-puppet"]
    print({k: v["mean"] for k, v in m.items() if isinstance(v, dict)})
    assert "loglik" not in m
    assert m["err"]["mean"] < 0.95  # 0.81 at this seed; the mean face scores 1
    assert sum(m["frames"]) == sum(len(s.points) for s in seqs)
    assert "| voice-puppet |" in report.format_table(res)
    # its baselines on the same folds, from the features computed from each sequence's audio, and
    # the same (guided) puppet without its guide
    assert list(res["models"]) == ["voice-puppet", "ridge", "mean-face", ev.MOST_PROBABLE, ev.UNGUIDED]
    assert res["models"][ev.UNGUIDED]["frames"] == m["frames"]
    assert res["models"][ev.UNGUIDED]["err"]["folds"] != m["err"]["folds"]
    assert f"| {ev.UNGUIDED} |" in report.format_table(res)
    # and its most probable trajectory, not widened to the training motion, paired with it
    assert res["models"][ev.MOST_PROBABLE]["frames"] == m["frames"]
    assert res["models"][ev.MOST_PROBABLE]["err"]["folds"] != m["err"]["folds"]
    assert ev.MOST_PROBABLE in res["differences"]["voice-puppet"]
    np.testing.assert_allclose(res["models"]["mean-face"]["err"]["folds"], 1.0, atol=1e-12)
    assert {"err", "lve", "rmse_iod", "closed"} <= set(res["differences"]["voice-puppet"]["ridge"])
    # a fold without B, P, M (its labels made AA): one fold left has a closed share, too few to
    # summarise, so the measure is not reported, for the models or their differences
    from voicepuppet.evaluation.folds import kfold

    _, te = kfold(len(seqs), 2, 0)[1]
    for i in te:
        seqs[i].labels[corpus.bilabial_mask(seqs[i].labels)] = ph.PHONE_INDEX["AA"]
    res = ev.cross_validate(seqs, k=2, seed=0, peers=False, puppet=True, n_states=8, progress=False)
    assert "closed" not in res["models"]["voice-puppet"] and "err" in res["models"]["voice-puppet"]
    assert "closed" not in res["differences"]["voice-puppet"]["ridge"]


def test_evaluate_compare_training_verb(tmp_path, capsys):
    """``--compare-training`` with two ``--variant``s on user data: the paired table and JSON are
    written (atomically, nothing else), the variants' options reach training, bad variants are
    refused."""
    import soundfile

    rng = np.random.default_rng(SEED + 4)
    data = tmp_path / "data"
    data.mkdir()
    seqs = planted_sequences(rng, n_seq=4, T=60)
    write_user_data(data, seqs)
    for s in seqs:  # a tone whose pitch follows the first face coordinate: the audio carries the face
        t = np.arange(int(len(s.points) / s.fps * 16000)) / 16000
        f0 = 200 + 50 * np.interp(t * s.fps, np.arange(len(s.points)), s.points[:, 48, 1] - s.points[:, 48, 1].mean())
        soundfile.write(data / f"{s.name}.wav", 0.3 * np.sin(2 * np.pi * np.cumsum(f0) / 16000), 16000)
    md, js = tmp_path / "c.md", tmp_path / "c.json"
    rc = main(["evaluate", "--data", str(data), "--folds", "2", "--components", "3", "--compare-training",
               "--variant", "few:n_states=3,n_iter=4", "--variant", "ml:n_states=3,n_iter=4,prior=\"ml\"",
               "-o", str(md), "--json", str(js), "-q"])
    assert rc == 0
    out = capsys.readouterr().out
    assert "| few − ml |" in out and f"wrote {js}" in out
    result = json.loads(js.read_text())
    assert result["config"]["options"] == {"few": {"n_states": 3, "n_iter": 4},
                                           "ml": {"n_states": 3, "n_iter": 4, "prior": "ml"}}
    assert result["variants"]["few"]["states"]["mean"] <= 3
    assert len(result["differences"]["few"]["err"]["folds"]) == 2
    assert all(0 <= v <= 1 for v in result["variants"]["few"]["closed"]["folds"])  # the data's M
    assert len(result["differences"]["few"]["closed"]["folds"]) == 2
    assert "--compare-training --variant" in result["command"]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["c.json", "c.md", "data"]
    assert main(["evaluate", "--data", str(data), "--folds", "2", "--compare-training",
                 "--variant", "a:n_states", "--variant", "b", "-q"]) == 2
    assert "expected key=value" in capsys.readouterr().err
    assert main(["evaluate", "--data", str(data), "--folds", "2", "--compare-training",
                 "--variant", "a:n_iter=3", "-q"]) == 2
    assert "at least two" in capsys.readouterr().err


def test_cross_validation_learns_from_train_points():
    """The phoneme peers and the fold's face space learn from ``train_points`` (a copy of the
    truth changes nothing; landmarks whose motion is time-reversed, out of step with the labels,
    make the DPDS lose what it had), and are measured against the true ``points``."""
    from dataclasses import replace

    rng = np.random.default_rng(SEED)
    seqs = planted_sequences(rng, K=1)

    def run(ss):
        return ev.cross_validate(ss, k=3, seed=1, peers=True, puppet=False, n_components=1,
                                 progress=False)["models"]["dpds"]

    plain = run(seqs)
    same = run([replace(s, train_points=s.points.copy()) for s in seqs])
    np.testing.assert_allclose(same["err"]["folds"], plain["err"]["folds"], rtol=1e-9)
    rev = run([replace(s, train_points=s.points[::-1].copy()) for s in seqs])
    print(plain["err"]["mean"], rev["err"]["mean"])
    assert plain["err"]["mean"] < 2e-3 and rev["err"]["mean"] > 0.1
    with pytest.raises(ValueError, match="sequence s0: train_points must have the shape"):
        run([replace(s, train_points=s.points[:, :60]) for s in seqs])


def _performer_clip(tmp_path, stem, texts, seed):
    """A short performer clip (espeak-ng speech, articulated landmarks) with a stand-in video
    file: the tracker is planted, only the file's identity matters."""
    from voicepuppet.synth import speech
    from voicepuppet.synth.articulation import articulate

    utts = [speech.speak(t) for t in texts]
    u = speech.concatenate(utts, [0.4] * len(utts)) if len(utts) > 1 else utts[0]
    fps = 30000 / 1001
    art = articulate(u.phones, u.samples, u.rate, neutral_landmarks(), fps=fps, seed=seed)
    video = tmp_path / f"{stem}.mp4"
    video.write_bytes(b"stand-in video " + stem.encode())
    return types.SimpleNamespace(video=str(video), points=art.points, fps=fps, rate=u.rate,
                                 samples=u.samples, phones=u.phones, source=u.source, text=u.text)


def test_synth_sequences_train_on_tracked_with_a_planted_tracker(tmp_path, monkeypatch):
    """``train_on="tracked"``: each clip's video is tracked once from its first true frame, the
    track cut into the same sequences as the truth (``train_points``), ``points`` untouched; the
    cache beside the corpus is hit on a second run and missed when the video's modification time
    or size changes; a track that does not fit the clip is refused."""
    import os

    from voicepuppet import synth
    from voicepuppet.tracking import tracker as tracking

    train = _performer_clip(tmp_path, "train", ["Please remember to feed the fish.",
                                                "Who knows where the ferry goes?"], 1)
    test = _performer_clip(tmp_path, "test_00", ["You can hear the waves."], 2)
    clips = types.SimpleNamespace(train=train, test=[test])
    monkeypatch.setattr(synth, "make_corpus", lambda *a, **k: clips)
    calls = []
    shift = {"train": 0.5, "test_00": -0.25}

    def planted(path, init, progress=True):
        stem = os.path.splitext(os.path.basename(path))[0]
        clip = train if stem == "train" else test
        calls.append((stem, np.array(init)))
        pts = clip.points + shift[stem] * np.sin(np.arange(len(clip.points)))[:, None, None]
        return types.SimpleNamespace(points=pts[:-1] if stem == "test_00" else pts)  # one frame dropped

    monkeypatch.setattr(tracking, "track_video", planted)
    seqs = corpus.synth_sequences(str(tmp_path), train_on="tracked", progress=False)
    assert [c[0] for c in calls] == ["train", "test_00"]
    np.testing.assert_array_equal(calls[0][1], train.points[0])
    np.testing.assert_array_equal(calls[1][1], test.points[0])
    truth = corpus.synth_sequences(str(tmp_path), progress=False)
    assert len(calls) == 2  # the second run read the cache
    assert [s.name for s in seqs] == [s.name for s in truth] == ["train_00", "train_01", "test_00"]
    assert all(s.train_points is None for s in truth)
    assert sorted(os.listdir(tmp_path / "tracked")) == ["test_00.npz", "train.npz"]
    T = len(train.points)
    want = train.points + 0.5 * np.sin(np.arange(T))[:, None, None]
    np.testing.assert_allclose(np.concatenate([s.train_points for s in seqs[:2]]), want)
    for s, t in zip(seqs, truth):
        np.testing.assert_array_equal(s.points, t.points)
        assert s.train_points.shape == s.points.shape
    # the dropped last frame is padded with the one before it
    np.testing.assert_array_equal(seqs[2].train_points[-1], seqs[2].train_points[-2])
    np.testing.assert_allclose(seqs[2].train_points[:-1], (test.points - 0.25 * np.sin(
        np.arange(len(test.points)))[:, None, None])[:-1])

    corpus.synth_sequences(str(tmp_path), train_on="tracked", progress=False)
    assert len(calls) == 2  # cache hit
    st = os.stat(train.video)
    os.utime(train.video, ns=(st.st_atime_ns, st.st_mtime_ns + 10**9))
    corpus.synth_sequences(str(tmp_path), train_on="tracked", progress=False)
    assert [c[0] for c in calls[2:]] == ["train"]  # modification time changed: re-tracked
    with open(test.video, "ab") as fh:
        fh.write(b"!")
    os.utime(test.video, ns=(st.st_atime_ns, os.stat(test.video).st_mtime_ns))
    corpus.synth_sequences(str(tmp_path), train_on="tracked", progress=False)
    assert [c[0] for c in calls[3:]] == ["test_00"]  # size changed: re-tracked
    (tmp_path / "tracked" / "train.npz").write_bytes(b"not an npz")
    again = corpus.synth_sequences(str(tmp_path), train_on="tracked", progress=False)
    assert [c[0] for c in calls[4:]] == ["train"]  # unreadable cache: tracked again, overwritten
    np.testing.assert_array_equal(again[0].train_points, seqs[0].train_points)

    with pytest.raises(ValueError, match="train_on must be one of"):
        corpus.synth_sequences(str(tmp_path), train_on="trakced", progress=False)
    monkeypatch.setattr(tracking, "track_video",
                        lambda path, init, progress=True: types.SimpleNamespace(points=np.zeros((5, 68, 2))))
    with pytest.raises(ValueError, match=r"gave landmarks of shape \(5, 68, 2\)"):
        corpus.tracked_landmarks(train, cache_dir=tmp_path / "other", progress=False)
    with pytest.raises(ValueError, match="does not exist"):
        corpus.tracked_landmarks(types.SimpleNamespace(video=str(tmp_path / "gone.mp4"), points=train.points))


def test_evaluate_verb_train_on_tracked(tmp_path, capsys, monkeypatch):
    """``--train-on tracked`` and ``--corpus-seed`` reach the performer's sequences and the command
    line that reproduces the run; with user data they are refused, naming the option."""
    rng = np.random.default_rng(SEED + 5)
    seqs = planted_sequences(rng, n_seq=4, T=40)
    got = {}

    def fake(out_dir=None, train_seconds=60.0, n_test=3, seed=0, progress=True, train_on="truth",
             speech="espeak"):
        got.update(seed=seed, train_on=train_on, speech=speech)
        return seqs

    monkeypatch.setattr(corpus, "synth_sequences", fake)
    js = tmp_path / "r.json"
    assert main(["evaluate", "--train-on", "tracked", "--seed", "1", "--corpus-seed", "0", "--folds", "2",
                 "--peers", "--no-puppet", "--components", "3", "--json", str(js), "-q"]) == 0
    assert got == {"seed": 0, "train_on": "tracked", "speech": "espeak"}
    command = json.loads(js.read_text())["command"]
    assert "--corpus-seed 0 --train-on tracked" in command and "--seed 1" in command
    assert "--train-seconds 60 --n-test 3" in command
    assert main(["evaluate", "--speech", "real", "--folds", "2", "--peers", "--no-puppet", "--components", "3",
                 "--json", str(js), "-q"]) == 0
    assert got["speech"] == "real"
    command = json.loads(js.read_text())["command"]
    assert "--speech real" in command and "--train-seconds" not in command
    capsys.readouterr()
    assert main(["evaluate", "--speech", "real", "--train-seconds", "30", "--peers", "--no-puppet", "-q"]) == 2
    assert "--speech real) has its fixed recordings" in capsys.readouterr().err
    data = tmp_path / "data"
    data.mkdir()
    write_user_data(data, seqs)
    assert main(["evaluate", "--data", str(data), "--train-on", "tracked", "--peers", "--no-puppet", "-q"]) == 2
    assert "--train-on is for the synthetic performer" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        main(["evaluate", "--train-on", "video", "-q"])
    assert "invalid choice: 'video'" in capsys.readouterr().err
    assert main(["evaluate", "--corpus-seed", "-1", "--peers", "--no-puppet", "-q"]) == 2
    assert "--corpus-seed must be a non-negative integer" in capsys.readouterr().err


def test_with_landmark_noise_adds_seeded_gaussian_noise_to_the_learnt_landmarks_only():
    """Noise of sigma px lands on the landmarks models learn from (on top of tracked ones where
    set), with the planted spread, fixed by the seed; the measured-against points stay clean."""
    rng = np.random.default_rng(SEED + 6)
    seqs = planted_sequences(rng, n_seq=3, T=200)
    tracked = seqs[1].points + 0.5
    seqs[1] = corpus.Sequence(seqs[1].name, seqs[1].points, 30.0, seqs[1].labels, train_points=tracked)
    noisy = corpus.with_landmark_noise(seqs, 2.0, seed=3)
    for a, b in zip(seqs, noisy):
        assert b.points is a.points and b.name == a.name
    d = np.concatenate([(b.train_points - corpus.learnt_points(a)).ravel() for a, b in zip(seqs, noisy)])
    assert d.size == 3 * 200 * 68 * 2
    assert np.std(d) == pytest.approx(2.0, rel=0.02) and abs(np.mean(d)) < 0.02
    assert abs(np.mean(noisy[1].train_points - tracked)) < 0.05  # on the tracked ones, not the truth
    # independent across sequences and fixed by the seed
    assert abs(np.corrcoef((noisy[0].train_points - seqs[0].points).ravel(),
                           (noisy[2].train_points - seqs[2].points).ravel())[0, 1]) < 0.02
    again = corpus.with_landmark_noise(seqs, 2.0, seed=3)
    other = corpus.with_landmark_noise(seqs, 2.0, seed=4)
    assert all(np.array_equal(a.train_points, b.train_points) for a, b in zip(noisy, again))
    assert not np.allclose(noisy[0].train_points, other[0].train_points)
    assert corpus.with_landmark_noise(seqs, 0.0)[0].train_points is None
    for bad in (-1.0, float("nan"), float("inf")):
        with pytest.raises(ValueError, match="finite number of pixels >= 0"):
            corpus.with_landmark_noise(seqs, bad)


def test_evaluate_verb_landmark_noise(tmp_path, capsys, monkeypatch):
    """``--landmark-noise PX`` trains on noisy landmarks (seeded by --seed), measures against the
    clean ones, and is written into the reproducing command; a negative value is refused."""
    rng = np.random.default_rng(SEED + 7)
    seqs = planted_sequences(rng, n_seq=4, T=40)
    monkeypatch.setattr(corpus, "synth_sequences", lambda *a, **k: seqs)
    seen = {}

    def fake_cv(sequences, **kw):
        seen["seqs"] = sequences
        return real_cv(sequences, **kw)

    real_cv = ev.cross_validate
    monkeypatch.setattr(ev, "cross_validate", fake_cv)
    js = tmp_path / "r.json"
    assert main(["evaluate", "--landmark-noise", "1.5", "--seed", "2", "--folds", "2", "--peers",
                 "--no-puppet", "--components", "3", "--json", str(js), "-q"]) == 0
    assert "--landmark-noise 1.5 --folds 2 --seed 2" in json.loads(js.read_text())["command"]
    want = corpus.with_landmark_noise(seqs, 1.5, seed=2)
    for got, w, clean in zip(seen["seqs"], want, seqs):
        assert np.array_equal(got.train_points, w.train_points) and got.points is clean.points
    capsys.readouterr()
    assert main(["evaluate", "--landmark-noise", "-2", "--peers", "--no-puppet", "-q"]) == 2
    assert "landmark noise must be a finite number of pixels >= 0" in capsys.readouterr().err


def _direct_baselines(seqs, feats, k, seed, n_components):
    """The baselines' fold measures computed here, independently of the harness: each fold's face
    space fitted on the training sequences' learnt landmarks, the features standardised with the
    training frames' own mean and std (what the puppet does to the raw columns of its input),
    a RidgeBaseline fitted directly, and the training mean face."""
    from voicepuppet.evaluation.folds import kfold
    from voicepuppet.puppet.guide import RidgeBaseline
    from voicepuppet.face import FaceSpace

    out = {"ridge": [], "mean-face": []}
    for tr, te in kfold(len(seqs), k, seed):
        fit = [corpus.learnt_points(seqs[i]) for i in tr]
        fs = FaceSpace.fit(fit, n_components=n_components)
        Ytr = [fs.encode(p)[0] for p in fit]
        Yte = [fs.encode(seqs[i].points)[0] for i in te]
        X = np.vstack([feats[i] for i in tr])
        mu, sd = X.mean(axis=0), X.std(axis=0)
        ridge = RidgeBaseline().fit([(feats[i] - mu) / sd for i in tr], Ytr)
        out["ridge"].append(ev._fold_metrics([ridge.predict((feats[i] - mu) / sd) for i in te], Yte, fs, None))
        mean = np.vstack(Ytr).mean(axis=0)
        out["mean-face"].append(ev._fold_metrics([np.tile(mean, (len(y), 1)) for y in Yte], Yte, fs, None))
    return out


def test_cross_validation_baselines_equal_a_direct_fit_on_each_fold(tmp_path):
    """With the puppet come the ridge and the mean face, each equal fold by fold to a direct fit
    on the fold (the ridge also when the sequences have separate training landmarks: it learns
    from those, like the puppet, and is measured against the truth); the mean face scores Err 1
    exactly (eq. 7 about the true mean: any constant prediction does); the paired differences are
    the puppet's per-fold values minus the baseline's, with their t-interval; both tables and the
    JSON carry them."""
    from dataclasses import replace

    from voicepuppet.evaluation.folds import mean_ci
    from voicepuppet.puppet.guide import RIDGE_ALPHAS

    from test_split import _planted_sequences

    seqs, feats = _planted_sequences(n_seq=6, T=240)
    noise = np.random.default_rng(SEED + 6)
    # what a tracker might give: noisy, and a fixed deformation, so that the face space moves too
    offset = noise.normal(scale=1.0, size=seqs[0].points.shape[1:])
    tracked = [replace(s, train_points=s.points + offset + noise.normal(scale=3.0, size=s.points.shape))
               for s in seqs]

    def run(ss):
        return ev.cross_validate(ss, k=3, seed=0, peers=False, puppet=True, n_components=3, n_states=6,
                                 features=feats, progress=False)

    results = {}
    for label, ss in (("truth", seqs), ("tracked", tracked)):
        res = results[label] = run(ss)
        assert list(res["models"]) == ["voice-puppet", "ridge", "mean-face", ev.MOST_PROBABLE, ev.UNGUIDED]
        direct = _direct_baselines(ss, feats, 3, 0, 3)
        for name, rows in direct.items():
            for m in ("l1", "rms", "linf", "err"):
                np.testing.assert_allclose(res["models"][name][m]["folds"], [r[m] for r in rows], rtol=1e-7,
                                           err_msg=f"{label} {name} {m}")
        np.testing.assert_allclose(res["models"]["mean-face"]["err"]["folds"], 1.0, atol=1e-12)
        assert len(res["models"]["ridge"]["alpha"]) == 3 and set(res["models"]["ridge"]["alpha"]) <= set(RIDGE_ALPHAS)
        voice = res["models"]["voice-puppet"]
        for name in ("ridge", "mean-face"):
            d = res["differences"]["voice-puppet"][name]
            assert set(d) == {"l1", "rms", "linf", "err"}
            for m, v in d.items():
                want = np.subtract(voice[m]["folds"], res["models"][name][m]["folds"])
                np.testing.assert_allclose(v["folds"], want, atol=1e-12)
                assert (v["mean"], v["low"], v["high"]) == pytest.approx(mean_ci(want), abs=1e-12)
    plain, noisy = results["truth"]["models"], results["tracked"]["models"]
    print({label: {n: r["models"][n]["err"]["mean"] for n in r["models"]} for label, r in results.items()})
    # the audio says which planted state the face is in: the ridge is far better than the mean face
    assert plain["ridge"]["err"]["mean"] < 0.5
    # learnt from the other landmarks the ridge scores otherwise against the same truth, so the
    # direct fit on the train_points above is not also the one on the truth
    for m in ("l1", "rms", "err"):
        assert abs(noisy["ridge"][m]["mean"] / plain["ridge"][m]["mean"] - 1) > 0.02, m
    assert results["tracked"]["config"]["separate_training_landmarks"] is True

    table = report.format_table(results["truth"])
    assert "| ridge |" in table and "| mean-face |" in table and "| paired difference (fold by fold) |" in table
    d = results["truth"]["differences"]["voice-puppet"]["ridge"]["err"]
    row = next(line for line in table.splitlines() if line.startswith("| voice-puppet − ridge |"))
    assert row.rstrip(" |").split(" | ")[4] == f"{d['mean']:+.3g} [{d['low']:+.3g}, {d['high']:+.3g}]"  # L1, RMS, L∞, Err
    assert "| voice-puppet − mean-face |" in table
    md, js = tmp_path / "r.md", tmp_path / "r.json"
    report.write_results(results["truth"], md, js, "voicepuppet evaluate")
    back = json.loads(js.read_text())
    assert back["differences"]["voice-puppet"]["mean-face"]["err"]["folds"] == pytest.approx(
        results["truth"]["differences"]["voice-puppet"]["mean-face"]["err"]["folds"])
    assert "| voice-puppet − mean-face |" in md.read_text()
    # without the puppet: no baselines, no differences, no second table
    alone = ev.cross_validate(seqs, k=3, seed=0, peers=True, puppet=False, n_components=3, progress=False)
    assert "ridge" not in alone["models"] and alone["differences"] == {}
    assert "paired difference" not in report.format_table(alone)


def test_cross_validation_baselines_refuse_bad_features():
    from test_split import _planted_sequences

    seqs, feats = _planted_sequences(n_seq=3, T=120)
    with pytest.raises(ValueError, match=r"features must be one \(T, A\) array per sequence \(3 sequences\)"):
        ev.cross_validate(seqs, k=2, peers=False, features=feats[:2], progress=False)
    with pytest.raises(ValueError, match="one row per frame"):
        ev.cross_validate(seqs, k=2, peers=False, features=[f[:-1] for f in feats], progress=False)
    with pytest.raises(ValueError, match="sequence s0 has no audio; the voice puppet needs it"):
        ev.cross_validate(seqs, k=2, peers=False, progress=False)


def test_evaluate_folds_readers_leaves_a_voice_out(tmp_path, monkeypatch, capsys):
    """``--folds readers``: the three folds of ``reader_folds`` (each reader left out, then the
    held-out speakers), named in the JSON and tabled fold by fold; only with ``--speech real``."""
    seqs = planted_sequences(np.random.default_rng(5), n_seq=6, T=40)
    names = ["train_00", "train_01", "train_02", "train_03", "test_00", "test_01"]
    for s, name, reader in zip(seqs, names, "AABBCD"):
        s.name, s.meta = name, {"reader": reader}
    monkeypatch.setattr(corpus, "synth_sequences", lambda *a, **k: seqs)
    md, js = tmp_path / "r.md", tmp_path / "r.json"
    assert main(["evaluate", "--speech", "real", "--folds", "readers", "--peers", "--no-puppet", "--components", "3",
                 "-o", str(md), "--json", str(js), "-q"]) == 0
    res = json.loads(js.read_text())
    assert res["config"]["fold_labels"] == ["A → B", "B → A", "both → held out (CMU ARCTIC)"]
    assert res["config"]["folds"] == [["train_02", "train_03"], ["train_00", "train_01"], ["test_00", "test_01"]]
    assert all(len(m["err"]["folds"]) == 3 for m in res["models"].values())
    text = md.read_text()
    assert "| Err (eq. 7), fold by fold | A → B | B → A | both → held out (CMU ARCTIC) |" in text
    assert "3 folds that leave a voice out (A → B; B → A;" in text and "--folds readers" in res["command"]
    capsys.readouterr()
    assert main(["evaluate", "--folds", "readers", "--peers", "--no-puppet", "-q"]) == 2
    assert "add --speech real" in capsys.readouterr().err
    assert main(["evaluate", "--folds", "five", "--peers", "--no-puppet", "-q"]) == 2
    assert "--folds takes k (an integer >= 2) or 'readers', got 'five'" in capsys.readouterr().err
    data = tmp_path / "data"
    data.mkdir()
    write_user_data(data, seqs)
    assert main(["evaluate", "--data", str(data), "--folds", "readers", "--peers", "--no-puppet", "-q"]) == 2
    assert "with --data give k" in capsys.readouterr().err


def test_a_variant_may_adapt_at_animate_time(monkeypatch):
    """A variant's ``adapt`` options reach ``Puppet.animate`` of the test audio, not training;
    other unknown options are still refused."""
    rng = np.random.default_rng(6)
    seqs = planted_sequences(rng, n_seq=4, T=60)
    feats = [rng.normal(size=(len(s.points), 4)) for s in seqs]
    seen = []
    animate = ev.Puppet.animate

    def spy(self, *a, **k):
        seen.append(k.get("adapt"))
        return animate(self, *a, **k)

    monkeypatch.setattr(ev.Puppet, "animate", spy)
    res = ev.compare_training(seqs, {"adapted": {"adapt": "full", "adapt_tau": 10.0, "n_states": 3},
                                     "plain": {"n_states": 3}}, k=2, features=feats)
    assert "full" in seen and None in seen
    assert res["config"]["options"]["adapted"]["adapt"] == "full"
    with pytest.raises(ValueError, match=r"unknown training options \['adapt_rate'\]"):
        ev.compare_training(seqs, {"a": {"adapt_rate": 3}, "b": {}}, k=2, features=feats)
