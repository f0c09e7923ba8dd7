"""The train and animate verbs on planted data (tones that say which face to make), the states
round trip for editing, the C++ example that animates without Python, and bad input."""
import os
import re
import subprocess
import sys
import warnings
from pathlib import Path

import numpy as np
import pytest
import soundfile as sf

from voicepuppet.cli.main import main
from voicepuppet.puppet.model import load

from support import FPS, RATE, performance


@pytest.fixture(scope="module")
def workdir(tmp_path_factory):
    d = tmp_path_factory.mktemp("cli")
    rng = np.random.default_rng(3)
    pts, audio, _ = performance(rng, 600)
    np.savez(d / "train.npz", points=pts, fps=FPS)
    sf.write(d / "train.wav", audio, RATE)
    test_pts, test_audio, test_states = performance(rng, 200)
    sf.write(d / "test.wav", test_audio, RATE)
    np.save(d / "test_states.npy", test_states)
    assert main(["train", "--landmarks", str(d / "train.npz"), "--audio", str(d / "train.wav"),
                 "-o", str(d / "p.vpp"), "--states", "6", "--iterations", "12", "--quiet"]) == 0
    return d


def test_train_and_animate(workdir, capsys):
    d = workdir
    assert main(["animate", str(d / "p.vpp"), str(d / "test.wav"), "-o", str(d / "a.npz"),
                 "--states-out", str(d / "s.csv"), "--quiet"]) == 0
    with np.load(d / "a.npz") as z:
        pts, fps = z["points"], float(z["fps"])
    assert pts.shape == (200, 10, 2) and fps == FPS
    # The tones say which shape to make: decoded states are pure with respect to the planted ones.
    states = np.loadtxt(d / "s.csv", delimiter=",", skiprows=1)[:, 2].astype(int)
    truth = np.load(d / "test_states.npy")
    purity = sum(np.bincount(truth[states == s]).max() for s in np.unique(states)) / len(truth)
    assert purity > 0.9
    # Read back with the audio, unedited states give the animation itself (the guide from the same
    # audio); without the audio, the audio's animation without the guide's evidence (Brand's solve,
    # as --guide-weight 0).
    assert main(["animate", str(d / "p.vpp"), str(d / "test.wav"), "--states-in", str(d / "s.csv"),
                 "-o", str(d / "r.npz"), "--quiet"]) == 0
    assert main(["animate", str(d / "p.vpp"), "--states-in", str(d / "s.csv"), "-o", str(d / "b.npz")]) == 0
    assert main(["animate", str(d / "p.vpp"), str(d / "test.wav"), "-o", str(d / "u.npz"), "--guide-weight", "0",
                 "--quiet"]) == 0
    with np.load(d / "r.npz") as r, np.load(d / "b.npz") as z, np.load(d / "u.npz") as u:
        np.testing.assert_array_equal(r["points"], pts)
        np.testing.assert_allclose(z["points"], u["points"], atol=1e-9)
        assert np.abs(u["points"] - pts).max() > 1e-6  # the default puppet is guided: its evidence moves the face
    # an edit (frames 50-59 held in another state) changes the face there, and little far from it
    table = np.loadtxt(d / "s.csv", delimiter=",", skiprows=1)
    table[50:60, 2] = (table[50:60, 2] + 1) % 6
    np.savetxt(d / "e.csv", table, fmt=["%d", "%.9g", "%d"], delimiter=",", header="frame,time,part0", comments="")
    assert main(["animate", str(d / "p.vpp"), str(d / "test.wav"), "--states-in", str(d / "e.csv"),
                 "-o", str(d / "e.npz"), "--quiet"]) == 0
    with np.load(d / "e.npz") as e:
        change = np.abs(e["points"] - pts).max(axis=(1, 2))
    assert change[50:60].min() > 0.5 and change[:30].max() < 0.05 * change[50:60].max()
    capsys.readouterr()
    for extra, msg in ((["--posterior"], "--posterior does not apply"), (["--adapt", "full"], "not decoded")):
        assert main(["animate", str(d / "p.vpp"), str(d / "test.wav"), "--states-in", str(d / "s.csv"),
                     "-o", str(d / "x.npz"), *extra]) == 2
        assert msg in capsys.readouterr().err
    assert main(["animate", str(d / "p.vpp"), "--states-in", str(d / "s.csv"), "-o", str(d / "x.npz"),
                 "--guide-weight", "2"]) == 2
    assert "give the AUDIO the states go with" in capsys.readouterr().err
    assert not (d / "x.npz").exists()
    # a video asked of animate: the render command that makes it
    assert main(["animate", str(d / "p.vpp"), str(d / "test.wav"), "-o", str(d / "x.mp4")]) == 2
    assert "voicepuppet render anim.npz --audio" in capsys.readouterr().err and not (d / "x.mp4").exists()
    assert main(["animate", str(d / "p.vpp"), str(d / "test.wav"), "-o", str(d / "c.csv"), "--fps", "50",
                 "--posterior", "--quiet"]) == 0
    assert np.loadtxt(d / "c.csv", delimiter=",", skiprows=1).shape == (400, 22)
    assert "a .csv holds the frames only" in capsys.readouterr().out  # the rest face is not in it


def test_train_switches_for_voices_never_heard(workdir, capsys):
    d = workdir
    assert main(["train", "--landmarks", str(d / "train.npz"), "--audio", str(d / "train.wav"),
                 "-o", str(d / "other.vpp"), "--states", "6", "--iterations", "12", "--quiet",
                 "--vocal-features", "projected", "--vocal-covariance", "tied"]) == 0
    # The summary counts states and arcs in whole numbers (the metadata holds them as floats).
    assert re.search(r"^part face: \d+ states \(from 6\), \d+ arcs, ", capsys.readouterr().out, re.M)
    puppet = load(d / "other.vpp")
    opts = puppet.metadata["training"]["options"]
    assert (opts["vocal_features"], opts["vocal_covariance"]) == ("projected", "tied")
    assert puppet._core.projected and puppet._core.n_vocal == puppet.face_space.n_dims
    assert main(["animate", str(d / "other.vpp"), str(d / "test.wav"), "-o", str(d / "o.npz"), "--quiet",
                 "--adapt", "full"]) == 0
    with np.load(d / "o.npz") as z:
        assert z["points"].shape == (200, 10, 2)


def _example_exe() -> Path:
    exe = Path(__file__).resolve().parents[2] / "build" / "example" / "voicepuppet_animate"
    if not exe.exists():
        pytest.skip("build examples/cpp first (bash .ci/test does): " + str(exe))
    return exe


def _assert_cpp_animates_like_python(exe, puppet_path, wav, folder):
    """The C++ example animates the features of ``wav`` as Python's ``Puppet.animate`` does (its
    most probable trajectory: full motion is Python's widening of it)."""
    from voicepuppet.puppet.model import load

    p = load(puppet_path)
    feats = p.audio_features(str(wav))
    np.savetxt(folder / "f.csv", feats, delimiter=",", header=",".join(f"c{i}" for i in range(feats.shape[1])))
    out = subprocess.run([str(exe), str(puppet_path), str(folder / "f.csv"), str(folder / "cpp.csv")],
                         capture_output=True, text=True)
    assert out.returncode == 0, out.stderr
    cpp = np.loadtxt(folder / "cpp.csv", delimiter=",", skiprows=1)[:, 2:]
    py = p.animate(features=feats, full_motion=False).animation.points.reshape(len(feats), -1)
    np.testing.assert_allclose(cpp, py, rtol=1e-9, atol=1e-9)


def test_cpp_example_animates_like_python(workdir):
    exe = _example_exe()
    d = workdir
    _assert_cpp_animates_like_python(exe, d / "p.vpp", d / "test.wav", d)
    bad = subprocess.run([str(exe), str(d / "f.csv"), str(d / "f.csv"), str(d / "x.csv")],
                         capture_output=True, text=True)
    assert bad.returncode == 2 and "not a voicepuppet puppet file" in bad.stderr
    assert not (d / "x.csv").exists()


@pytest.mark.parametrize("options", [dict(vocal_covariance="tied"),
                                     dict(vocal_features="projected", vocal_covariance="tied"),
                                     dict(vocal_covariance="tied", guide="ridge", guide_context=2),
                                     dict(vocal_covariance="tied", guide="none")],
                         ids=["tied", "projected", "guided-k2", "unguided"])
def test_cpp_example_animates_a_non_default_vocal_model_like_python(workdir, tmp_path, options):
    # A tied vocal model is stored as N equal full covariances, a projected one (vocal_features=
    # "projected") as the projection of +-5 frames the C++ puppet applies to the raw feature
    # frames: the C++ program animates both as Python does.
    exe = _example_exe()
    from voicepuppet.puppet.model import Puppet

    d = workdir
    with np.load(d / "train.npz") as z:
        pts = z["points"]
    puppet = Puppet.train([pts], [str(d / "train.wav")], fps=FPS, n_states=6, n_iter=12, **options)
    vc = puppet.part_arrays(0)["vocal_covars"]
    assert vc.ndim == 3 and np.array_equal(vc, np.repeat(vc[:1], len(vc), axis=0))
    path = puppet.save(tmp_path / "puppet.vpp")
    saved = load(path)
    assert {k: saved.metadata["training"]["options"][k] for k in options} == options
    assert saved._core.projected == ("vocal_features" in options)
    if saved._core.projected:
        assert saved._core.projection_context == 5
    assert saved.guided == (options.get("guide", "ridge") == "ridge")
    if saved.guided:
        assert saved._core.guide_context == options.get("guide_context", 5)
    _assert_cpp_animates_like_python(exe, path, d / "test.wav", tmp_path)


def test_train_audio_band(workdir, tmp_path, capsys):
    """--audio-band 4000: the puppet low-passes all audio at 4 kHz (kept in the file, shown by
    info); a band the analysis cannot hold is refused before training."""
    d = workdir
    common = ["train", "--landmarks", str(d / "train.npz"), "--audio", str(d / "train.wav"), "--states", "6",
              "--iterations", "12", "--quiet", "--guide-weight", "4"]
    assert main(common + ["-o", str(tmp_path / "tel.vpp"), "--audio-band", "4000"]) == 0
    tel = load(tmp_path / "tel.vpp")
    assert tel.feature_set.settings()["band_hz"] == 4000
    capsys.readouterr()
    assert main(["info", str(tmp_path / "tel.vpp")]) == 0
    assert "band-limited to 4000 Hz" in capsys.readouterr().out
    for bad in ("-3", "9000"):
        assert main(common + ["-o", str(tmp_path / "bad.vpp"), "--audio-band", bad]) == 2
        assert "band_hz must be a frequency" in capsys.readouterr().err
    assert not (tmp_path / "bad.vpp").exists()
    # the speech level: -20 dBFS by default (as info says), another or none (levels as recorded)
    assert tel.feature_set.settings()["level_db"] == -20.0
    for level, want, says in (("-26", -26.0, "speech brought to -26 dBFS"), ("none", None, "levels as recorded")):
        assert main(common + ["-o", str(tmp_path / "lv.vpp"), "--audio-level", level]) == 0
        assert load(tmp_path / "lv.vpp").feature_set.settings()["level_db"] == want
        capsys.readouterr()
        assert main(["info", str(tmp_path / "lv.vpp")]) == 0
        assert says in capsys.readouterr().out
    assert main(common + ["-o", str(tmp_path / "bad.vpp"), "--audio-level", "loud"]) == 2
    assert "--audio-level takes a speech level in dBFS" in capsys.readouterr().err
    assert not (tmp_path / "bad.vpp").exists()
    # `features --puppet` gives the puppet's own features (its band included) as the C++ example reads them
    out = tmp_path / "f.csv"
    assert main(["features", str(d / "test.wav"), "--puppet", str(tmp_path / "tel.vpp"), "-o", str(out), "--quiet"]) == 0
    with open(out) as fh:
        header = fh.readline().strip().split(",")
    table = np.loadtxt(out, delimiter=",", skiprows=1)
    assert header[:2] == ["frame", "time"] and len(header) == table.shape[1]
    np.testing.assert_array_equal(table[:, 2:], tel.audio_features(str(d / "test.wav")))
    np.testing.assert_allclose(table[:, 1], table[:, 0] / tel.fps, atol=1e-6)
    assert main(["features", str(d / "test.wav"), "--puppet", str(tmp_path / "tel.vpp"), "--fps", "25",
                 "-o", str(out)]) == 2
    assert "--puppet fixes the features and their rate; drop --fps" in capsys.readouterr().err


def test_train_noise_snrs(workdir, tmp_path, capsys):
    """--noise-snrs 20,10 reaches the training (kept in the file's options, the vocal side
    changed, the facial machine not); malformed lists are refused before training."""
    d = workdir
    common = ["train", "--landmarks", str(d / "train.npz"), "--audio", str(d / "train.wav"), "--states", "6",
              "--iterations", "12", "--quiet", "--guide-weight", "4"]
    assert main(common + ["-o", str(tmp_path / "plain.vpp")]) == 0
    assert main(common + ["-o", str(tmp_path / "noisy.vpp"), "--noise-snrs", "20,10"]) == 0
    plain, noisy = load(tmp_path / "plain.vpp"), load(tmp_path / "noisy.vpp")
    assert noisy.metadata["training"]["options"]["noise_snrs"] == [20.0, 10.0]
    np.testing.assert_array_equal(noisy.arrays["hmm/part0/transmat"], plain.arrays["hmm/part0/transmat"])
    assert not np.allclose(noisy.arrays["hmm/part0/vocal_means"], plain.arrays["hmm/part0/vocal_means"])
    capsys.readouterr()
    for bad in ("loud", ",", "20,nan"):
        assert main(common + ["-o", str(tmp_path / "bad.vpp"), "--noise-snrs", bad]) == 2
        assert "--noise-snrs takes SNRs in dB" in capsys.readouterr().err
    assert not (tmp_path / "bad.vpp").exists()

def test_cpp_example_animates_the_features_command_output(workdir, tmp_path):
    """examples/cpp fed `voicepuppet features AUDIO --puppet P.vpp -o F.csv` animates as Python."""
    exe = _example_exe()
    d = workdir
    feats = tmp_path / "f.csv"
    assert main(["features", str(d / "test.wav"), "--puppet", str(d / "p.vpp"), "-o", str(feats), "--quiet"]) == 0
    run = subprocess.run([str(exe), str(d / "p.vpp"), str(feats), str(tmp_path / "cpp.csv")],
                         capture_output=True, text=True)
    assert run.returncode == 0, run.stderr
    cpp = np.loadtxt(tmp_path / "cpp.csv", delimiter=",", skiprows=1)[:, 2:]
    py = load(d / "p.vpp").animate(str(d / "test.wav"), full_motion=False).animation.points
    np.testing.assert_allclose(cpp, py.reshape(len(py), -1), rtol=1e-9, atol=1e-9)


def test_guide_switches(workdir, tmp_path, capsys):
    d = workdir
    common = ["train", "--landmarks", str(d / "train.npz"), "--audio", str(d / "train.wav"), "--states", "6",
              "--iterations", "12", "--quiet"]
    assert main(common + ["-o", str(tmp_path / "none.vpp"), "--guide", "none"]) == 0
    capsys.readouterr()
    assert main(common + ["-o", str(tmp_path / "k2.vpp"), "--guide", "ridge", "--guide-context", "2",
                          "--guide-alpha", "per_coordinate"]) == 0
    k2_out = capsys.readouterr().out
    assert main(common + ["-o", str(tmp_path / "w3.vpp"), "--guide-weight", "3"]) == 0
    none, k2, default = load(tmp_path / "none.vpp"), load(tmp_path / "k2.vpp"), load(d / "p.vpp")
    # the weight: chosen by cross-validation (and said so), or fixed by --guide-weight
    assert f"guide weight {k2.guide_weight:g}, chosen by cross-validation" in k2_out
    assert k2.metadata["training"]["guide"]["weight"] == k2.guide_weight
    w3 = load(tmp_path / "w3.vpp")
    assert w3.guide_weight == 3.0 and "weight_cv" not in w3.metadata["training"]["guide"]
    assert not none.guided and none.metadata["training"]["options"]["guide"] == "none"
    assert k2.guided and k2._core.guide_context == 2 and default.guided and default._core.guide_context == 5
    assert k2.metadata["training"]["options"]["guide_alpha"] == "per_coordinate"
    assert len(k2.metadata["training"]["guide"]["alpha"]) == k2.face_space.n_dims
    assert default.metadata["training"]["options"]["guide_alpha"] == "shared"
    assert main(common + ["-o", str(tmp_path / "one.vpp"), "--max-components", "1"]) == 0
    one = load(tmp_path / "one.vpp")
    assert one.metadata["training"]["options"]["max_components"] == 1
    assert one.face_space.n_dims == 1 < default.face_space.n_dims  # the cap bound
    capsys.readouterr()
    assert main(common + ["-o", str(tmp_path / "bad.vpp"), "--guide-alpha", "lips"]) == 2  # 10-point faces
    assert "needs the 68-point layout" in capsys.readouterr().err
    assert not (tmp_path / "bad.vpp").exists()
    # --guide-weight 0 on the default (guided) puppet is the unguided puppet's animation
    assert main(["animate", str(d / "p.vpp"), str(d / "test.wav"), "-o", str(tmp_path / "zero.npz"),
                 "--guide-weight", "0", "--quiet"]) == 0
    assert main(["animate", str(tmp_path / "none.vpp"), str(d / "test.wav"), "-o", str(tmp_path / "n.npz"),
                 "--quiet"]) == 0
    assert main(["animate", str(d / "p.vpp"), str(d / "test.wav"), "-o", str(tmp_path / "two.npz"),
                 "--guide-weight", "2", "--quiet"]) == 0
    with np.load(tmp_path / "zero.npz") as a, np.load(tmp_path / "n.npz") as b, np.load(tmp_path / "two.npz") as c:
        np.testing.assert_allclose(a["points"], b["points"], atol=1e-9)
        assert np.abs(c["points"] - a["points"]).max() > 1e-6
    capsys.readouterr()
    assert main(common + ["-o", str(tmp_path / "bad.vpp"), "--guide", "none", "--guide-context", "3"]) == 2
    assert "--guide-context" in capsys.readouterr().err
    assert main(common + ["-o", str(tmp_path / "bad.vpp"), "--guide", "none", "--guide-alpha", "shared"]) == 2
    assert "--guide-alpha" in capsys.readouterr().err
    assert main(common + ["-o", str(tmp_path / "bad.vpp"), "--guide-context", "101"]) == 2
    assert "guide_context" in capsys.readouterr().err
    # options are checked before any tracking: a missing video is never reached
    assert main(["train", str(tmp_path / "absent.mp4"), "-o", str(tmp_path / "bad.vpp"), "--max-components", "0",
                 "--quiet"]) == 2
    assert "max_components must be an integer >= 1" in capsys.readouterr().err
    assert main(common + ["-o", str(tmp_path / "bad.vpp"), "--guide-weight", "auto"]) == 2
    assert "--guide-weight must be 'cv' or a number" in capsys.readouterr().err
    assert main(common + ["-o", str(tmp_path / "bad.vpp"), "--guide-weight", "-2"]) == 2
    assert "guide_weight must be 'cv'" in capsys.readouterr().err
    assert main(common + ["-o", str(tmp_path / "bad.vpp"), "--guide", "none", "--guide-weight", "2"]) == 2
    assert "--guide-weight" in capsys.readouterr().err
    assert main(["animate", str(tmp_path / "none.vpp"), str(d / "test.wav"), "-o", str(tmp_path / "x.npz"),
                 "--guide-weight", "1", "--quiet"]) == 2
    assert "needs a guided puppet" in capsys.readouterr().err
    assert main(["animate", str(d / "p.vpp"), str(d / "test.wav"), "-o", str(tmp_path / "x.npz"),
                 "--guide-weight", "-1", "--quiet"]) == 2
    assert "guide_weight" in capsys.readouterr().err
    assert not (tmp_path / "bad.vpp").exists() and not (tmp_path / "x.npz").exists()


def test_bad_input_is_reported_and_writes_nothing(workdir, tmp_path, capsys):
    d = workdir
    assert main(["animate", str(d / "p.vpp"), str(d / "test.wav"), "-o", str(tmp_path / "a.txt")]) == 2
    assert "animation file" in capsys.readouterr().err
    data = (d / "p.vpp").read_bytes()
    (tmp_path / "cut.vpp").write_bytes(data[: len(data) // 2])
    assert main(["animate", str(tmp_path / "cut.vpp"), str(d / "test.wav"), "-o", str(tmp_path / "a.npz")]) == 2
    assert "truncated" in capsys.readouterr().err
    assert main(["animate", str(d / "p.vpp"), "-o", str(tmp_path / "a.npz")]) == 2
    assert "AUDIO" in capsys.readouterr().err
    assert main(["train", "--landmarks", str(d / "train.npz"), "-o", str(tmp_path / "q.vpp")]) == 2
    assert "--audio" in capsys.readouterr().err
    assert main(["train", "--landmarks", str(d / "train.npz"), "--audio", str(d / "train.wav"),
                 "-o", str(tmp_path / "q.vpp"), "--states", "200", "--quiet"]) == 2
    assert "too few" in capsys.readouterr().err
    assert sorted(os.listdir(tmp_path)) == ["cut.vpp"]


def test_a_face_and_audio_of_different_lengths_are_warned_about(workdir, tmp_path, capsys):
    d = workdir
    with warnings.catch_warnings():
        warnings.simplefilter("default")  # as in a user's Python: the command prints it
        assert main(["train", "--landmarks", str(d / "train.npz"), "--audio", str(d / "test.wav"),
                     "-o", str(tmp_path / "q.vpp"), "--states", "6", "--iterations", "2", "--quiet"]) == 0
    err = capsys.readouterr().err
    assert f"the face runs {600 / FPS:.2f} s and its audio {200 / FPS:.2f} s" in err
    assert "trained on silence; check that the two belong together" in err
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # its own audio: no warning
        assert main(["train", "--landmarks", str(d / "train.npz"), "--audio", str(d / "train.wav"),
                     "-o", str(tmp_path / "r.vpp"), "--states", "6", "--iterations", "2", "--quiet"]) == 0
    assert "belong together" not in capsys.readouterr().err


def test_a_video_without_sound_fails_before_it_is_tracked(workdir, tmp_path, capsys, monkeypatch):
    import cv2

    from voicepuppet.tracking import tracker as tracking

    def no_tracking(*args, **kwargs):
        raise AssertionError("tracked a video whose sound was never going to load")

    monkeypatch.setattr(tracking, "track_video", no_tracking)
    silent_film = tmp_path / "silent.mp4"
    w = cv2.VideoWriter(str(silent_film), cv2.VideoWriter_fourcc(*"mp4v"), FPS, (64, 64))
    for _ in range(5):
        w.write(np.full((64, 64, 3), 128, np.uint8))
    w.release()
    # the second video has no sound: found before the first one is tracked
    assert main(["train", str(silent_film), str(silent_film), "--audio", str(workdir / "train.wav"),
                 str(tmp_path / "missing.wav"), "-o", str(tmp_path / "q.vpp"), "--quiet"]) == 2
    assert "missing.wav" in capsys.readouterr().err
    assert main(["train", str(silent_film), "-o", str(tmp_path / "q.vpp"), "--quiet"]) == 2
    assert "has no audio track" in capsys.readouterr().err
    assert sorted(os.listdir(tmp_path)) == ["silent.mp4"]


def test_palette_of_puppets(workdir, tmp_path, capsys):
    import shutil

    d = workdir
    pal = tmp_path / "palette"
    pal.mkdir()
    shutil.copy(d / "p.vpp", pal / "tones.vpp")
    assert main(["animate", "tones", str(d / "test.wav"), "--palette", str(pal), "-o", str(tmp_path / "a.npz"),
                 "--quiet"]) == 0
    assert main(["animate", str(d / "p.vpp"), str(d / "test.wav"), "-o", str(tmp_path / "ref.npz"), "--quiet"]) == 0
    with np.load(tmp_path / "a.npz") as z, np.load(tmp_path / "ref.npz") as ref:
        np.testing.assert_array_equal(z["points"], ref["points"])
    assert main(["animate", "nobody", str(d / "test.wav"), "--palette", str(pal), "-o", str(tmp_path / "b.npz")]) == 2
    assert "it holds: tones" in capsys.readouterr().err


def test_command_line_entry_point(workdir):
    out = subprocess.run([sys.executable, "-m", "voicepuppet.cli.main", "animate", "--help"], capture_output=True,
                         text=True)
    assert out.returncode == 0 and "--states-in" in out.stdout


def test_tiny_and_silent_audio(workdir, tmp_path, capsys):
    from voicepuppet.audio import AudioWarning
    from voicepuppet.puppet.model import load

    d = workdir
    sf.write(tmp_path / "blip.wav", 0.1 * np.sin(np.arange(100) / 3.0), RATE)  # 6 ms: under one frame
    with warnings.catch_warnings():
        warnings.simplefilter("default")  # as in a user's Python: the command prints it
        assert main(["animate", str(d / "p.vpp"), str(tmp_path / "blip.wav"), "-o", str(tmp_path / "a.npz"),
                     "--quiet"]) == 0
    err = capsys.readouterr().err
    assert "voicepuppet animate: warning: audio in" in err and "6.2 ms long, shorter than one frame" in err
    with np.load(tmp_path / "a.npz") as z:
        assert z["points"].shape == (1, 10, 2)
    sf.write(tmp_path / "silence.wav", np.zeros(RATE), RATE)
    with pytest.warns(AudioWarning, match="silent"):
        out = load(d / "p.vpp").animate(str(tmp_path / "silence.wav"))
    assert out.animation.n_frames == int(np.ceil(FPS)) and np.all(np.isfinite(out.animation.points))


def test_frames_where_the_face_is_lost_are_dropped_with_a_warning(rng):
    from voicepuppet.audio import prepare
    from voicepuppet.puppet.sources import usable_segments

    T, P = 100, 10
    pts = rng.normal(size=(T, P, 2))
    lost = np.zeros((T, P), bool)
    lost[40:55, :6] = True          # the face is lost for 15 frames
    lost[95:, :] = True             # and at the very end (a 5-frame run before it is too short)
    lost[88:90, :] = True
    snd = prepare(rng.normal(0, 0.1, 4 * RATE), RATE)
    with pytest.warns(UserWarning, match="lost in 22 of 100 frames"):
        segs = usable_segments(pts, lost, snd, FPS)
    assert [len(p) for p, _ in segs] == [40, 33]
    np.testing.assert_array_equal(segs[1][0], pts[55:88])
    assert len(segs[1][1].samples) == int(round(88 / FPS * RATE)) - int(round(55 / FPS * RATE))
    assert usable_segments(pts, None, snd, FPS)[0][0] is pts
    with pytest.raises(ValueError, match="no run of 10 usable frames"):
        usable_segments(pts, np.ones((T, P), bool), snd, FPS)
    # another tool's NaN for a point it lost: lost; whole frames of them are dropped like lost ones
    holes = pts.copy()
    holes[20:32] = np.nan
    with pytest.warns(UserWarning, match="lost in 12 of 100 frames"):
        segs = usable_segments(holes, None, snd, FPS)
    assert [len(p) for p, _ in segs] == [20, 68] and all(np.isfinite(p).all() for p, _ in segs)
    holes[70, 4, 1] = np.inf  # one point on a frame that is kept: refused, with where it is
    with pytest.raises(ValueError, match="point 4 of frame 70 is NaN or infinite"):
        usable_segments(holes, None, snd, FPS)


def test_points_of_a_variable_frame_rate_video_are_resampled_onto_the_grid():
    from voicepuppet.tracking.landmarks import on_uniform_grid

    fps = 30.0
    # 1 s at 30 fps, 1 s at 15 fps, a 0.5 s stall, 0.5 s at 30 fps
    times = np.concatenate([np.arange(30) / 30, 1 + np.arange(15) / 15, 2.5 + np.arange(15) / 30])
    T, P = len(times), 3
    slope = np.array([[1.0, -2.0], [0.5, 3.0], [-1.5, 0.25]])
    pts = 10.0 + times[:, None, None] * slope  # linear in time: interpolation is exact
    lost = np.zeros((T, P), bool)
    lost[35, 1] = True  # frame 35 is at 1 + 5/15 s = grid frame 40
    with pytest.warns(UserWarning, match=r"33\.3-566\.7 ms apart.*60 tracked frames are resampled to 90 "
                                         r"on the grid.*\(16 in gaps longer than 3 frames are lost\)"):
        out, out_lost = on_uniform_grid(pts, lost, times + 0.7, fps)  # times need not start at 0
    grid = np.arange(90) / fps
    np.testing.assert_allclose(out, 10.0 + grid[:, None, None] * slope, rtol=0, atol=1e-12)
    in_gap = (grid > times[44] + 1e-9) & (grid < times[45] - 1e-9)
    assert in_gap.sum() == 16 and out_lost[in_gap].all()
    # point 1 is lost on grid frame 40 (on source frame 35) and 39 and 41 (between it and its
    # neighbours), and nowhere else outside the gap
    assert list(np.flatnonzero(out_lost.any(axis=1) & ~in_gap)) == [39, 40, 41]
    assert not out_lost[~in_gap][:, [0, 2]].any()
    # a constant rate within a quarter frame of the grid: the points as they were
    jitter = np.arange(T) / fps + 0.2 / fps * np.sin(np.arange(T))
    same, same_lost = on_uniform_grid(pts, lost, jitter, fps)
    assert same is pts and same_lost is not None and (same_lost == lost).all()
    assert on_uniform_grid(pts, None, None, fps)[0] is pts
    # a second video at another constant rate (25 fps) joins the first's 30 fps grid
    t25 = np.arange(T) / 25.0
    with pytest.warns(UserWarning, match=r"40\.0-40\.0 ms apart.*resampled to 71 on the grid"):
        at30, _ = on_uniform_grid(10.0 + t25[:, None, None] * slope, None, t25, fps)
    np.testing.assert_allclose(at30, 10.0 + (np.arange(71) / fps)[:, None, None] * slope, atol=1e-12)
    with pytest.raises(ValueError, match="59 frame times for 60 frames"):
        on_uniform_grid(pts, lost, times[:-1], fps)
    with pytest.raises(ValueError, match="finite and increasing"):
        on_uniform_grid(pts, lost, times[::-1], fps)


def test_animation_files_are_byte_identical_across_writes(tmp_path):
    import time

    from voicepuppet.animation import Animation, load_animation, save_animation

    anim = Animation(np.arange(60, dtype=float).reshape(3, 10, 2), 25.0, names=[f"p{i}" for i in range(10)])
    save_animation(anim, tmp_path / "a.npz")
    time.sleep(2.1)  # zip timestamps have 2 s resolution
    save_animation(anim, tmp_path / "b.npz")
    assert (tmp_path / "a.npz").read_bytes() == (tmp_path / "b.npz").read_bytes()
    back = load_animation(tmp_path / "a.npz")
    np.testing.assert_array_equal(back.points, anim.points)
    assert back.fps == 25.0 and back.names == anim.names


def test_train_on_a_local_dask_cluster(workdir, tmp_path):
    from voicepuppet.puppet.model import load

    d = workdir
    assert main(["train", "--landmarks", str(d / "train.npz"), "--audio", str(d / "train.wav"),
                 "-o", str(tmp_path / "q.vpp"), "--states", "6", "--iterations", "4", "--workers", "1",
                 "--quiet"]) == 0
    q = load(tmp_path / "q.vpp")
    assert q.n_points == 10 and q.animate(str(d / "test.wav")).animation.n_frames == 200
