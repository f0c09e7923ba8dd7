"""Tests of the tracker's working scale (voicepuppet.tracking.scale, ``working_scale``): a large face is
tracked on frames resized down to the size the tracker was tuned on and the points mapped back;
the pixel-centre mapping against OpenCV's resize, the factor, the option's errors, a face at or
below the reference tracked exactly as before, and the synthetic performer planted 2.5x larger
with pixel noise."""

from __future__ import annotations

import json

import numpy as np
import pytest

from voicepuppet import tracking
from voicepuppet.tracking import video

cv2 = pytest.importorskip("cv2", reason="pip install opencv-contrib-python-headless")
pytest.importorskip("skimage", reason="pip install scikit-image")

from voicepuppet.bench.tracker import ASTRONAUT_POINTS, planted_face_sequence  # noqa: E402


def _blob_centroid(img: np.ndarray) -> np.ndarray:
    w = img.astype(np.float64)
    yy, xx = np.mgrid[0:img.shape[0], 0:img.shape[1]]
    return np.array([(w * xx).sum() / w.sum(), (w * yy).sum() / w.sum()])


@pytest.mark.parametrize("f", [0.37, 0.5, 128 / 246.6, 0.81])
def test_points_map_to_the_resized_frame_as_opencv_resizes_it(f):
    # The mapping x_small = (x + 0.5) f - 0.5 against OpenCV's INTER_AREA resize: the intensity
    # centroid of a smooth blob at a known sub-pixel position lands where the mapping puts it.
    rng = np.random.default_rng(5)
    print("seed 5")
    H, W = 600, 800
    yy, xx = np.mgrid[0:H, 0:W]
    for _ in range(3):
        c = rng.uniform([150, 150], [W - 150, H - 150])
        blob = np.round(250 * np.exp(-((xx - c[0]) ** 2 + (yy - c[1]) ** 2) / (2 * 14.0**2))).astype(np.uint8)
        small = video.downscale(blob, f)
        assert small.shape == (round(H * f), round(W * f))
        got = _blob_centroid(small)
        want = tracking.points_to_working(c, f)
        assert np.abs(got - want).max() < 0.01, (f, c, got, want)
        # the naive x * f is off by (1 - f) / 2 px, which this check would see
        assert np.abs(got - c * f).max() > 0.05


def test_point_mapping_round_trip_and_fixed_values():
    p = np.random.default_rng(2).uniform(-10, 2000, size=(40, 68, 2))
    for f in (0.3, 0.5, 0.77, 1.0):
        np.testing.assert_allclose(tracking.points_to_full(tracking.points_to_working(p, f), f), p,
                                   rtol=0, atol=1e-9)
    # halving: full pixels 0 and 1 average into small pixel 0, whose centre is x = 0.5
    np.testing.assert_allclose(tracking.points_to_working([[0.5, 0.5], [0.0, 1.0]], 0.5),
                               [[0.0, 0.0], [-0.25, 0.25]])


def _face(iod: float) -> np.ndarray:
    """The performer's 68 truth points of a frame scaled about their centroid to an IOD."""
    from voicepuppet.synth import face_photo

    p = face_photo((320, 320), fallback=False).points
    c = p.mean(axis=0)
    return c + (p - c) * iod / np.linalg.norm(p[45] - p[36])


def test_working_scale_factor_is_one_up_to_the_reference_and_shrinks_larger_faces():
    from voicepuppet.synth import face_photo

    performer = face_photo((320, 320), fallback=False).points
    size, large, working = tracking.face_size(performer)
    assert (large, working) == (tracking.LARGE_FACE_IOD, tracking.WORKING_IOD) == (128.0, 112.0)
    assert size < large  # the performer is tracked at full resolution
    assert tracking.working_scale_factor(performer) == 1.0
    assert tracking.working_scale_factor(_face(128.0)) == 1.0  # at the threshold: as before
    # just above it, resized to the working size (112 px between the outer eye corners)
    for iod in (128.5, 200.0, 346.0):
        assert tracking.working_scale_factor(_face(iod)) == pytest.approx(112.0 / iod, rel=1e-12)
    # Other layouts: the RMS radius of the points about their centroid. The performer's 68 points
    # give 0.635 of their IOD (the ratio the RMS thresholds are built on).
    c = performer - performer.mean(axis=0)
    rms = np.sqrt((c**2).sum(axis=1).mean())
    assert rms / size == pytest.approx(0.635, abs=0.001)
    assert tracking.face_size(ASTRONAUT_POINTS)[1:] == (tracking.LARGE_FACE_RMS_RADIUS, tracking.WORKING_RMS_RADIUS)
    assert tracking.working_scale_factor(ASTRONAUT_POINTS) == 1.0  # the 26-point planted face
    big = 3.0 * ASTRONAUT_POINTS
    c = big - big.mean(axis=0)
    assert tracking.working_scale_factor(big) == pytest.approx(
        tracking.WORKING_RMS_RADIUS / np.sqrt((c**2).sum(axis=1).mean()), rel=1e-12)
    # an explicit factor is taken as it is
    assert tracking.working_scale_factor(ASTRONAUT_POINTS, 0.5) == 0.5
    assert tracking.working_scale_factor(ASTRONAUT_POINTS, 1) == 1.0


@pytest.mark.parametrize("bad", ["big", "Auto", 0, 0.0, -0.5, 1.5, float("nan"), True, None, [0.5]])
def test_bad_working_scale_is_refused_clearly(bad):
    with pytest.raises(ValueError, match="working_scale must be 'auto' or a number in"):
        tracking.working_scale_factor(ASTRONAUT_POINTS, bad)
    frames, _, _ = planted_face_sequence(3, seed=0)
    with pytest.raises(ValueError, match="working_scale"):
        tracking.track_frames(frames, ASTRONAUT_POINTS, working_scale=bad)


def test_cli_refuses_a_bad_working_scale(tmp_path, capsys, write_avi):
    from voicepuppet.cli.main import main

    path = write_avi(tmp_path / "clip.avi", planted_face_sequence(3, seed=0)[0], fps=30.0)
    init = tmp_path / "init.json"
    init.write_text(json.dumps({"points": ASTRONAUT_POINTS.tolist()}))
    for bad in ("big", "2", "0"):
        rc = main(["track", str(path), "-o", str(tmp_path / "out.npz"), "--init", str(init),
                   "--working-scale", bad, "--quiet"])
        err = capsys.readouterr().err
        assert rc == 2
        assert "working" in err and "scale" in err and "'auto' or a number in (0, 1]" in err and repr(bad) in err
    assert not (tmp_path / "out.npz").exists()



def test_cli_tracks_at_a_working_scale_and_draws_at_full_resolution(tmp_path, capsys, write_avi):
    from voicepuppet.cli.main import main

    frames = planted_face_sequence(8, seed=4)[0]
    path = write_avi(tmp_path / "clip.avi", frames, fps=30.0)
    init = tmp_path / "init.json"
    init.write_text(json.dumps({"points": ASTRONAUT_POINTS.tolist()}))
    out, overlay = tmp_path / "out.npz", tmp_path / "overlay.avi"
    assert main(["track", str(path), "-o", str(out), "--init", str(init), "--working-scale", "0.5",
                 "--overlay", str(overlay), "--quiet"]) == 0
    assert "resized by 0.5000" in capsys.readouterr().out
    decoded, _ = video.read_grey_frames(path)
    want = tracking.track_frames(decoded, ASTRONAUT_POINTS, fps=30.0, working_scale=0.5)
    marks = tracking.load_landmarks(out)
    np.testing.assert_allclose(marks["points"], want.points, rtol=0, atol=1e-9)
    assert float(marks["working_scale"]) == 0.5
    drawn, _ = video.read_grey_frames(overlay)
    assert drawn.shape == decoded.shape  # the overlay is drawn on the full-resolution frames

def test_a_face_at_or_below_the_reference_is_tracked_exactly_as_before():
    frames, _, _ = planted_face_sequence(30, seed=1)
    auto = tracking.track_frames(frames, ASTRONAUT_POINTS)
    full = tracking.track_frames(frames, ASTRONAUT_POINTS, working_scale=1.0)
    assert auto.working_scale == full.working_scale == 1.0
    for name in ("points", "confidence", "lost", "rest_length", "stiffness"):
        assert np.array_equal(getattr(auto, name), getattr(full, name)), name
    assert auto.passes == full.passes


def test_tracking_at_a_working_scale_is_the_tracker_on_resized_frames():
    # The orchestration, exactly: frames resized by hand and init points mapped in, tracked at
    # full resolution, give the working-scale result once mapped back; springs in full-res px.
    frames, truth, _ = planted_face_sequence(30, seed=2)
    f = 0.6
    small = [video.downscale(g, f) for g in frames]
    by_hand = tracking.track_frames(small, tracking.points_to_working(ASTRONAUT_POINTS, f), working_scale=1.0)
    ours = tracking.track_frames(frames, ASTRONAUT_POINTS, working_scale=f)
    assert ours.working_scale == f
    np.testing.assert_allclose(ours.points, tracking.points_to_full(by_hand.points, f), rtol=0, atol=1e-9)
    assert np.array_equal(ours.lost, by_hand.lost) and np.array_equal(ours.confidence, by_hand.confidence)
    np.testing.assert_allclose(ours.rest_length, by_hand.rest_length / f, rtol=1e-12)
    np.testing.assert_allclose(ours.stiffness, by_hand.stiffness * f**2, rtol=1e-12)
    assert ours.passes[1]["mean_point_change"] == pytest.approx(by_hand.passes[1]["mean_point_change"] / f)
    # the result is in full-resolution pixels: near the truth there
    assert np.linalg.norm(ours.points - truth, axis=2)[:, :20].mean() < 1.5


def test_track_video_caches_the_resized_frames(tmp_path, monkeypatch, write_avi):
    path = write_avi(tmp_path / "clip.avi", planted_face_sequence(12, seed=3)[0], fps=30.0)
    decoded, _ = video.read_grey_frames(path)
    want = tracking.track_frames(decoded, ASTRONAUT_POINTS, fps=30.0, working_scale=0.5)
    # The cache holds resized frames: 12 frames of 320x240 fit in 12 * 320 * 240 bytes (the
    # full-resolution ones would need 4 times that), so the video is decoded once for the
    # cache (after the first frame) rather than once per pass.
    opened = []
    iter_frames = video.iter_frames
    monkeypatch.setattr(video, "iter_frames", lambda *a, **kw: opened.append(kw.get("scale", 1.0)) or iter_frames(*a, **kw))
    small = 12 * 320 * 240
    cached = tracking.track_video(path, ASTRONAUT_POINTS, progress=False, working_scale=0.5, cache_bytes=small)
    assert opened == [1.0, 0.5]
    opened.clear()
    streamed = tracking.track_video(path, ASTRONAUT_POINTS, progress=False, working_scale=0.5, cache_bytes=small - 1)
    assert opened == [1.0, 0.5, 0.5]
    for r in (cached, streamed):
        assert r.working_scale == 0.5
        assert np.array_equal(r.points, want.points) and np.array_equal(r.lost, want.lost)


UPSCALE = 2.5


@pytest.fixture(scope="module")
def large_performer(tmp_path_factory):
    """The synthetic performer speaking a short sentence (the repo's own generator), planted
    2.5x larger (bicubic; IOD ~308 px) with temporal pixel noise (sigma 6, seed 7), as a webcam
    in HD sees a face: frames (T, 800, 800) uint8, truth (T, 68, 2) in their pixels."""
    synth = pytest.importorskip("voicepuppet.synth")
    if not synth.espeak_available():
        pytest.skip("the synthetic performer needs espeak-ng: apt-get install espeak-ng")
    utt = synth.speak("Open the window wide, we know the way.", rate=150)
    stem = str(tmp_path_factory.mktemp("large") / "clip")
    clip = synth.make_clip(utt, synth.face_photo((320, 320), fallback=False), stem, seed=0, progress=False)
    frames, _ = video.read_grey_frames(clip.video)
    rng = np.random.default_rng(7)
    print("seed 7")
    side = round(320 * UPSCALE)
    big = []
    for g in frames:
        up = cv2.resize(g, (side, side), interpolation=cv2.INTER_CUBIC).astype(np.float32)
        big.append(np.clip(np.round(up + rng.normal(0.0, 6.0, up.shape)), 0, 255).astype(np.uint8))
    truth = (clip.points[:len(big)] + 0.5) * UPSCALE - 0.5
    return np.stack(big), truth


def test_a_large_noisy_face_is_tracked_at_the_working_scale(large_performer):
    frames, truth = large_performer
    assert len(frames) >= 60 and np.ptp(truth[:, 66, 1]) > 10 * UPSCALE  # the mouth really opens
    ours = tracking.track_frames(frames, truth[0])
    f = tracking.WORKING_IOD / np.linalg.norm(truth[0, 45] - truth[0, 36])  # 112 px
    assert ours.working_scale == pytest.approx(f)
    full = tracking.track_frames(frames, truth[0], working_scale=1.0)  # main's behaviour
    err = np.linalg.norm(ours.points - truth, axis=2) / UPSCALE  # px of the 320x320 performer
    err0 = np.linalg.norm(full.points - truth, axis=2) / UPSCALE
    print(f"{len(frames)} frames, working scale {ours.working_scale:.4f}: lips {err[:, 48:].mean():.3f} px, "
          f"rest {err[:, :48].mean():.3f}, eyes {err[:, 36:48].mean():.3f}, lost {ours.lost.mean():.4f}; "
          f"full resolution: lips {err0[:, 48:].mean():.3f}, rest {err0[:, :48].mean():.3f}, "
          f"eyes {err0[:, 36:48].mean():.3f}, lost {full.lost.mean():.4f}")
    # Measured here: lips 0.984 px, rest 0.383, eyes 0.352, 3.1 % of point-frames lost at the
    # working scale (0.3653: the IOD of 308 px tracked at 112); at full resolution (main's code)
    # 0.858, 0.872, 0.488 px and 23.9 % lost: the fixed 13x13 patch sees a sixth of the face
    # area it was tuned on, and the pixel noise the finest level does not average. (The lips of
    # this 77-frame clip are the one score that full resolution wins; on the 6 s and 20 s clips
    # planted 1.5-2.8x larger the working scale wins it too: docs/tracking.md.)
    assert err[:, :48].mean() < 0.55
    assert err[:, 36:48].mean() < 0.40
    assert ours.lost.mean() < 0.09
    assert err[:, 48:].mean() < 1.2  # the lips as on the performer's own clips (1.35-1.43 px)
    # The control: the same frames at full resolution break those bounds.
    assert err0[:, :48].mean() > 0.7 and full.lost.mean() > 0.15


def test_init_points_are_checked_in_full_resolution_pixels():
    frames, _, _ = planted_face_sequence(3, seed=0)
    h, w = frames.shape[1:]
    outside = ASTRONAUT_POINTS.copy()
    outside[4] = [w + 0.25, 10]  # inside the rounded resized frame, outside the real one
    with pytest.raises(ValueError, match=r"initial point 4 = \(640.25, 10\) is outside the 640x480 first frame"):
        tracking.track_frames(frames, outside, working_scale=0.37)
    # a point on the last pixel maps past the last resized pixel (x 639 -> 236.115 in a frame
    # 237 px wide): clamped into it, not refused
    edge = ASTRONAUT_POINTS.copy()
    edge[4] = [w - 1, h - 1]
    r = tracking.track_frames(frames, edge, working_scale=0.37, passes=1)
    np.testing.assert_allclose(r.points[0, 4], [w - 1, h - 1], atol=0.5 / 0.37)
