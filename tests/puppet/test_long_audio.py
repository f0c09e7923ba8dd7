"""Long audio in bounded memory (voicepuppet.puppet.long): the block-read features equal
extract's, the windowed animation equals the whole-utterance one away from nothing (the margins
cover the seams), and the block writer writes save_animation's files. Memory itself is a
benchmark (benchmarks/long_audio_memory.py, docs/benchmarks.md), not a test."""

import numpy as np
import pytest
import soundfile as sf

from support import FPS, RATE, performance
from voicepuppet import audio as vaudio
from voicepuppet.animation import Animation, AnimationWriter, exaggerate, load_animation, save_animation
from voicepuppet.audio.extract import extract_file
from voicepuppet.puppet import Puppet, long


@pytest.fixture(scope="module")
def setup(tmp_path_factory):
    d = tmp_path_factory.mktemp("long")
    rng = np.random.default_rng(5)
    pts, audio, _ = performance(rng, 600)
    p = Puppet.train([pts], [vaudio.prepare(audio, RATE)], fps=FPS, n_states=6, n_iter=12, seed=0)
    _, test_audio, _ = performance(rng, 1500)  # 60 s
    sf.write(d / "test.wav", test_audio, RATE, subtype="PCM_16")
    # the same speech at 22.05 kHz in stereo with a DC offset: resampled and mixed on the stream
    from scipy.signal import resample_poly
    y = resample_poly(test_audio, 441, 320)
    sf.write(d / "test22k.wav", np.column_stack([y, 0.5 * y]) + 0.02, 22050, subtype="FLOAT")
    return p, d


@pytest.mark.parametrize("name", ["test.wav", "test22k.wav"])
def test_block_read_features_equal_extract(setup, name):
    p, d = setup
    whole = vaudio.extract(d / name, fps=p.fps, features=p.feature_set)
    blocks = extract_file(d / name, fps=p.fps, features=p.feature_set, block_s=0.77)
    assert p.feature_set.settings()["level_db"] is not None  # the level from the frame sums is tested too
    assert blocks.names == whole.names and blocks.values.shape == whole.values.shape
    np.testing.assert_allclose(blocks.values, whole.values, rtol=1e-9, atol=1e-7)  # formants in Hz


def test_block_read_features_refuse_pitch(setup):
    _, d = setup
    with pytest.raises(ValueError, match="f0"):
        extract_file(d / "test.wav", features=["mfcc", "f0"])


@pytest.mark.parametrize("kw", [{}, {"fps": 30.0}, {"posterior": True}])
def test_windows_equal_whole_utterance(setup, monkeypatch, kw):
    p, d = setup
    whole = p.animate(d / "test.wav", **kw)
    monkeypatch.setattr(long, "WINDOW_S", 10.0)  # six windows on 60 s
    monkeypatch.setattr(long, "MARGIN_S", 3.0)
    chunked = p.animate(d / "test.wav", chunked=True, **kw)
    assert chunked.animation.points.shape == whole.animation.points.shape
    np.testing.assert_array_equal(chunked.states, whole.states)
    err = np.abs(chunked.animation.points - whole.animation.points).max(axis=(1, 2))
    print(f"{kw}: largest difference {err.max():.3g} px")
    assert err.max() < 1e-6
    assert np.isnan(chunked.log_likelihood)
    # without margins the seams show: the margins are what makes the windows agree
    monkeypatch.setattr(long, "MARGIN_S", 0.0)
    bare = p.animate(d / "test.wav", chunked=True, **kw)
    assert np.abs(bare.face - whole.face).max() > 1e-3


def test_windows_cover_the_frames_once():
    for n, period in [(1, 1), (1000, 1), (2997 * 3 + 5, 999), (50, 7)]:
        plan = long.plan_windows(n, 100, 20, period)
        kept = [(a, b) for _, a, b, _ in plan]
        assert kept[0][0] == 0 and kept[-1][1] == n
        assert all(b == a2 for (_, b), (a2, _) in zip(kept, kept[1:]))
        assert all(lo <= a < b <= hi and lo % period == 0 for lo, a, b, hi in plan)
    assert long.frame_period(29.97, 30.0) == (999, 1000)
    assert long.frame_period(25.0, 25.0) == (1, 1)


def test_animate_to_writes_the_animation(setup, monkeypatch, tmp_path):
    p, d = setup
    monkeypatch.setattr(long, "WINDOW_S", 10.0)
    monkeypatch.setattr(long, "MARGIN_S", 3.0)
    ref = exaggerate(p.animate(d / "test.wav").animation, 1.5)
    out = [tmp_path / "a.npz", tmp_path / "a.csv"]
    done = p.animate_to(out, d / "test.wav", exaggerate=1.5, chunked=True)
    assert done.paths == out and done.n_frames == ref.n_frames
    for f in out:
        got = load_animation(f)
        assert got.points.shape == ref.points.shape and got.fps == pytest.approx(ref.fps)
        np.testing.assert_allclose(got.points, ref.points, rtol=0, atol=1e-6)
    np.testing.assert_allclose(load_animation(out[0]).neutral, ref.neutral, atol=1e-9)
    # short audio, not chunked: today's file, byte for byte
    p.animate_to(tmp_path / "b.npz", d / "test.wav")
    save_animation(p.animate(d / "test.wav").animation, tmp_path / "c.npz")
    assert (tmp_path / "b.npz").read_bytes() == (tmp_path / "c.npz").read_bytes()


def test_chunked_refuses_states_and_adapt(setup):
    p, d = setup
    with pytest.raises(ValueError, match="whole-utterance"):
        p.animate(d / "test.wav", adapt="full", chunked=True)


@pytest.mark.parametrize("suffix", [".npz", ".csv"])
def test_writer_writes_save_animations_file(tmp_path, rng, suffix):
    pts = rng.normal(100, 20, (101, 5, 2))
    neutral = None if suffix == ".csv" else pts.mean(axis=0)
    save_animation(Animation(pts, 29.97, neutral=neutral), tmp_path / f"a{suffix}")
    with AnimationWriter(tmp_path / f"b{suffix}", 101, 5, 29.97, neutral=neutral) as w:
        for i in range(0, 101, 30):
            w.write(pts[i:i + 30])
    assert (tmp_path / f"a{suffix}").read_bytes() == (tmp_path / f"b{suffix}").read_bytes()
    np.testing.assert_array_equal(load_animation(tmp_path / f"b{suffix}").points,
                                  load_animation(tmp_path / f"a{suffix}").points)


def test_writer_leaves_nothing_when_short(tmp_path, rng):
    with pytest.raises(ValueError, match="5 frames written of the 10"):
        with AnimationWriter(tmp_path / "a.npz", 10, 5, 30.0) as w:
            w.write(rng.normal(size=(5, 5, 2)))
    assert list(tmp_path.iterdir()) == []
