"""The tracker's lips on a real face, against an independent reference (MediaPipe Face Mesh's
opening, shipped with the recordings): with ``init="auto"``, dlib's lips on every frame anchor the
spring mesh's (docs/tracking.md, "Detector anchors")."""

import numpy as np
import pytest

from voicepuppet.evaluation import real
from voicepuppet.layout import crossed_lips
from voicepuppet.tracking import track_video
from voicepuppet.tracking.detect import auto_init, landmarks_near
from voicepuppet.tracking.video import read_grey_frames

pytest.importorskip("dlib")


def _opening_r(points, clip):
    iod = np.linalg.norm(points[:, 36] - points[:, 45], axis=1)
    opening = np.linalg.norm(points[:, 62] - points[:, 66], axis=1) / iod
    n = min(len(opening), len(clip.opening))
    return float(np.corrcoef(opening[:n], clip.opening[:n])[0, 1])


@pytest.fixture(scope="module")
def reagan():
    (clip,) = real.real_clips(speaker="reagan")
    return clip


def test_detector_anchors_keep_reagans_lips_on_his_mouth(reagan):
    """Reagan's 26 s address, where the patches alone drift off his lips (opening r 0.42): with
    the anchors (the default with init="auto") 0.68, and never crossed."""
    anchored = track_video(reagan.video, init="auto", progress=False)
    alone = track_video(reagan.video, init="auto", progress=False, detector_anchors=False)
    r_anchored, r_alone = _opening_r(anchored.points, reagan), _opening_r(alone.points, reagan)
    assert r_anchored >= 0.6 and r_anchored > r_alone + 0.15, (r_anchored, r_alone)
    assert not crossed_lips(anchored.points).any()


def test_anchored_mouth_corners_follow_the_mouths_width():
    """Obama's sentence 7, where the patches slid the mouth corners along the lip contour (width
    r 0.77 against the reference with the corners anchored as the other lips and searched against
    their first frame): with stiffer corner anchors without slack and no corner search, r >= 0.85."""
    (clip,) = [c for c in real.real_clips(speaker="obama") if c.key.endswith("sentence_7")]
    pts = track_video(clip.video, init="auto", progress=False).points
    width = np.linalg.norm(pts[:, 48] - pts[:, 54], axis=1) / np.linalg.norm(pts[:, 36] - pts[:, 45], axis=1)
    n = min(len(width), len(clip.width))
    assert np.corrcoef(width[:n], clip.width[:n])[0, 1] >= 0.85


def test_given_points_track_without_anchors(reagan):
    """Points given by hand need not be in dlib's layout: no anchors unless asked for."""
    frames, _ = read_grey_frames(reagan.video)
    init = auto_init(frames[0])
    given = track_video(reagan.video, init=init, progress=False, passes=1)
    unanchored = track_video(reagan.video, init=init, progress=False, passes=1, detector_anchors=False)
    anchored = track_video(reagan.video, init=init, progress=False, passes=1, detector_anchors=True)
    np.testing.assert_array_equal(given.points, unanchored.points)
    assert np.abs(anchored.points - given.points).max() > 1.0
    # the anchors' slack is per point; one number is every point's
    one = track_video(reagan.video, init=init, progress=False, passes=1, detector_anchors=True, anchor_slack=1.5)
    each = track_video(reagan.video, init=init, progress=False, passes=1, detector_anchors=True,
                       anchor_slack=np.full(68, 1.5))
    np.testing.assert_array_equal(one.points, each.points)
    assert np.abs(one.points - anchored.points).max() > 0.1


def test_anchors_need_a_68_point_face(reagan):
    """Anchors are dlib's 68 points: another layout is refused, saying how to go on."""
    frames, _ = read_grey_frames(reagan.video)
    init = auto_init(frames[0])[:30]
    with pytest.raises(ValueError, match="detector_anchors=True needs the 68 points"):
        track_video(reagan.video, init=init, progress=False, passes=1, detector_anchors=True, lips=False,
                    eyes=False)


def test_landmarks_near_finds_the_face_its_points_say():
    """dlib's shape predictor in the box a face's points give lands where its detector's box
    does: within 3 % of the inter-ocular distance, and from points off by 5 % of it."""
    (clip,) = [c for c in real.real_clips(speaker="obama") if c.key.endswith("weekly_address_8s")]
    frames, _ = read_grey_frames(clip.video)
    detected = auto_init(frames[40])
    iod = np.linalg.norm(detected[36] - detected[45])
    for shift in ([0.0, 0.0], [0.05, -0.05]):
        near = landmarks_near(frames[40], detected + np.array(shift) * iod)
        assert np.median(np.linalg.norm(near - detected, axis=1)) < 0.03 * iod, shift
    assert landmarks_near(frames[40], np.full((68, 2), np.nan)) is None
