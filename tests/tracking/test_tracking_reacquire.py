"""Re-acquiring a face the tracker lost: the face leaves (a plain background where it was) and
comes back far from where it left, beyond every search radius of the tracker; planted truth is
moved exactly with it."""

from __future__ import annotations

import numpy as np
import pytest

from voicepuppet import _core
from voicepuppet import tracking
from voicepuppet.tracking import reacquire

cv2 = pytest.importorskip("cv2", reason="pip install opencv-contrib-python-headless")
pytest.importorskip("skimage", reason="pip install scikit-image")

from voicepuppet.bench.tracker import ASTRONAUT_POINTS, planted_face_sequence  # noqa: E402

ABSENT = (16, 28)       # frames [start, stop) without the face
START = (10, 10)        # top-left of the face crop in the canvas before the absence
SHIFT = (90, 70)        # px: where it comes back, relative to START (a search radius is ~10 px)


def _returning(cover: str):
    """The planted astronaut's face (a crop around its 26 points, moving and deforming smoothly)
    in a plain canvas: there, then absent (``cover="plain"``: the plain canvas; ``"card"``: a
    textured card, seeded smooth noise, where the face was), then back SHIFT px away. Returns
    frames, truth."""
    from voicepuppet.bench.tracker import planted

    frames, truth, _ = planted_face_sequence(48, seed=0, occlusion=None, blur=None)
    x0, y0, x1, y1 = 170, 60, 400, 270  # the face with > 30 px around its points at all times
    crop = frames[:, y0:y1, x0:x1]
    bg = int(np.median(np.concatenate([crop[0, 0], crop[0, -1]])))
    return planted(crop, truth - [x0, y0], ABSENT, SHIFT, cover, start=START,
                   margin=(SHIFT[0] + 10, SHIFT[1] + 10), bg=bg)


@pytest.fixture(scope="module")
def returning():
    return _returning("plain")


def test_every_point_is_lost_while_a_card_covers_the_face():
    # A few points find something to match on the card (main flags them found, and the springs
    # re-estimated for the second pass learn from them); once the face has been lost for
    # REACQUIRE_FRAMES frames all its points are.
    frames, truth = _returning("card")
    a, b = ABSENT
    result = tracking.track_frames(frames, truth[0], passes=2)
    assert result.lost[a:b].all()
    assert result.reacquired == [b]
    assert np.linalg.norm(result.points[b:] - truth[b:], axis=2).mean() < 0.5
    per_point = tracking.track_frames(frames, truth[0], passes=1, reacquire=False)
    assert not per_point.lost[a:b].all()


def test_a_face_that_comes_back_elsewhere_is_found_again(returning):
    frames, truth = returning
    result = tracking.track_frames(frames, truth[0], passes=2)
    err = np.linalg.norm(result.points - truth, axis=2)
    a, b = ABSENT
    # Found on the frame it returns (the search starts after 3 frames lost), in both passes.
    assert result.reacquired == [b]
    assert [row["reacquired"] for row in result.passes] == [[b], [b]]
    # While it is absent every point is lost; before and after it is tracked as well.
    assert result.lost[a:b].all()
    assert not result.lost[b:].any()
    assert err[b:].mean() < 0.5 and err[b:].max() < 2.0
    assert err[1:a].mean() < 0.5
    # Without the search the points stay where the face was (main's behaviour).
    stuck = tracking.track_frames(frames, truth[0], passes=1, reacquire=False)
    assert stuck.reacquired == []
    assert np.linalg.norm(stuck.points[b:] - truth[b:], axis=2).mean() > 50


def test_a_face_that_never_leaves_is_tracked_exactly_as_without_the_search():
    frames, truth, _ = planted_face_sequence(120, seed=0, occlusion=(70, 80))
    on = tracking.track_frames(frames, ASTRONAUT_POINTS, passes=2)
    off = tracking.track_frames(frames, ASTRONAUT_POINTS, passes=2, reacquire=False)
    assert on.reacquired == [] and all(row["reacquired"] == [] for row in on.passes)
    np.testing.assert_array_equal(on.points, off.points)
    np.testing.assert_array_equal(on.confidence, off.confidence)
    np.testing.assert_array_equal(on.lost, off.lost)


def test_a_region_that_is_only_background_is_not_taken_for_the_face(returning):
    # The search's acceptance: a plain frame has no correlation peak at all; the face region
    # (deformed by the planted motion) correlates far above the threshold wherever it is, and
    # the points it maps there are the truth's within 3 px (the pyramid's reach is more).
    frames, truth = returning
    search = reacquire.FaceSearch(frames[0], truth[0])
    for t in range(ABSENT[0], ABSENT[1]):
        assert search.find(frames[t], truth[0]) is None
    for t in range(ABSENT[1], len(frames), 4):
        points, ncc = search.find(frames[t], truth[0])
        assert ncc > reacquire.REACQUIRE_NCC + 0.15
        np.testing.assert_allclose(points.mean(axis=0), truth[t].mean(axis=0), atol=3.0)  # within the pyramid's reach


@pytest.mark.parametrize("angle, scale", [(15.0, 1.0), (-8.0, 0.85), (0.0, 1.2)])
def test_a_face_that_comes_back_turned_or_scaled_is_found_again(returning, angle, scale):
    # In-plane rotations and scales between the search's hypotheses (0, +-10, +-20 degrees;
    # 0.8-1.25): the nearest one finds the face, the tracker's pose follows from there.
    frames, truth = returning
    b = ABSENT[1]
    centre = truth[b].mean(axis=0)
    M = cv2.getRotationMatrix2D((float(centre[0]), float(centre[1])), angle, scale)
    frames, truth = frames.copy(), truth.copy()
    bg = int(frames[0, 0, 0])
    for t in range(b, len(frames)):
        frames[t] = cv2.warpAffine(frames[t], M, frames.shape[2:0:-1], flags=cv2.INTER_LINEAR, borderValue=bg)
        truth[t] = truth[t] @ M[:, :2].T + M[:, 2]
    result = tracking.track_frames(frames, truth[0], passes=1)
    assert result.reacquired == [b]
    err = np.linalg.norm(result.points[b:] - truth[b:], axis=2)
    assert err.mean() < 0.6 and not result.lost[b:].any()


def test_the_landmarks_file_records_where_the_face_was_found_again(returning, tmp_path):
    frames, truth = returning
    result = tracking.track_frames(frames, truth[0], passes=1)
    tracking.save_landmarks(tmp_path / "marks.npz", result, csv=False)
    z = tracking.load_landmarks(tmp_path / "marks.npz")
    assert z["reacquired"].dtype == np.int64 and z["reacquired"].tolist() == [ABSENT[1]]
    assert float(z["working_scale"]) == 1.0
    np.testing.assert_array_equal(z["lost"], result.lost)


def test_relocate_refuses_a_wrong_shape():
    frames, truth = planted_face_sequence(2, seed=0, occlusion=None, blur=None)[:2]
    pts = np.ascontiguousarray(truth[0])
    tracker = _core.SpringMeshTracker(frames[0], pts, _core.springs_from_points(pts, tracking.delaunay_edges(pts)))
    with pytest.raises(ValueError, match=r"shape \(26, 2\)"):
        tracker.relocate(pts[:5])
    with pytest.raises(ValueError, match="points"):
        tracker.relocate(np.full_like(pts, np.nan))
    tracker.relocate(pts + 3.0)
    np.testing.assert_array_equal(tracker.points, pts + 3.0)


def test_cli_prints_the_frames_where_the_face_was_found_again(tmp_path, returning, capsys, write_avi):
    import json

    from voicepuppet.cli.main import main

    frames, truth = returning
    vid = write_avi(tmp_path / "returning.avi", frames)
    init = tmp_path / "points.json"
    init.write_text(json.dumps({"points": truth[0].tolist()}))
    rc = main(["track", str(vid), "-o", str(tmp_path / "landmarks.npz"), "--init", str(init), "--quiet",
               "--passes", "1"])
    assert rc == 0
    assert f"face lost and found again (mesh restarted) at frame {ABSENT[1]} ({ABSENT[1] / 25:.2f} s)" \
        in capsys.readouterr().out
    rc = main(["track", str(vid), "-o", str(tmp_path / "landmarks.npz"), "--init", str(init), "--quiet",
               "--passes", "1", "--no-reacquire"])
    assert rc == 0
    assert "found again" not in capsys.readouterr().out
    assert np.load(tmp_path / "landmarks.npz")["lost"][-1].mean() > 0.5  # left where the face was lost
