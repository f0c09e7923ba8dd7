"""Face mesh, driving (vertex / action units), off-screen rendering and video writing.

Animations are planted: a parametric neutral face with a known jaw opening and smile
(:func:`voicepuppet.animation.procedural_animation`), or action-unit activations drawn at random.
"""

import json
import os
from pathlib import Path

import numpy as np
import pytest

from voicepuppet import layout as face_layout
from voicepuppet import render as R
from voicepuppet.render import video as V
from voicepuppet.tracking import video as tracking_video
from voicepuppet.animation import Animation, load_animation, neutral_landmarks, procedural_animation, save_animation

pytest.importorskip("pyvista")


def _signed_area(pts, faces):
    a, b, c = (pts[faces[:, k]] for k in range(3))
    return (b[:, 0] - a[:, 0]) * (c[:, 1] - a[:, 1]) - (b[:, 1] - a[:, 1]) * (c[:, 0] - a[:, 0])


@pytest.fixture(scope="module")
def face():
    lm = neutral_landmarks(240, 240)
    return R.build_face_mesh(R.portrait_image(lm, 240, 240), lm)


@pytest.fixture(scope="module")
def jaw_anim():
    t = np.arange(24)
    jaw = np.clip(np.sin(np.pi * t / 12.0), 0.0, None)  # opens and closes, then stays closed
    return procedural_animation(24, 24.0, width=240, height=240, jaw=jaw, smile=0.0), jaw


def _cavity_is_the_inner_lips(face):
    """The cavity's 6 triangles (an 8-point polygon's; with the tongue's 8 and the wall's 16, the
    mouth's) lie on its own copies of the inner lip points (60-67), which move with those points
    alone; its wall joins the inner lips to them."""
    assert face.mouth.sum() == 6 + 8 + 16
    wall = face.faces[np.flatnonzero(face.mouth)[-16:]]
    assert set(wall.ravel()) == set(range(60, 68)) | set(np.unique(face.faces[np.flatnonzero(face.mouth)[:6]]))
    idx = np.unique(face.faces[np.flatnonzero(face.mouth)[:6]])
    assert len(idx) == 8 and idx.min() == len(face.vertices) - 114
    M = face.interpolation_matrix()
    np.testing.assert_array_equal(M[idx], np.eye(68)[60:68])
    np.testing.assert_array_equal(face.vertices[idx, :2], face.landmarks[60:68])
    inner = set(range(60, 68))
    assert not any(set(f) <= inner for f in face.faces[~face.flat].tolist())  # the skin's hole is it


def test_mesh_has_about_200_triangles_landmarks_first_and_no_folds(face, jaw_anim):
    anim, _ = jaw_anim
    assert 150 <= (~face.flat).sum() <= 250
    np.testing.assert_array_equal(face.vertices[:68, :2], neutral_landmarks(240, 240))
    _cavity_is_the_inner_lips(face)
    assert face.teeth.sum() == 64 and not (face.teeth & face.mouth).any()
    # every vertex used; skin triangles keep their orientation when the jaw opens fully
    assert set(np.unique(face.faces)) == set(range(len(face.vertices)))
    verts = R.mesh_animation(anim, face)["vertices"]
    skin = face.faces[~face.flat]
    for t in range(anim.n_frames):
        assert np.all(_signed_area(verts[t, :, :2], skin) < 0), f"fold at frame {t}"
    # depth: the nose tip is the highest point of the face, the frame is flat
    z = face.vertices[:, 2]
    assert np.argmax(z[:68]) == 30 and np.all(z[face.fixed] == 0)


def test_the_cavity_is_the_inner_lip_polygon_on_a_real_face():
    """The performer's photo (real landmarks, thin mouth corners): Delaunay alone skipped a corner
    of its inner lip contour (4 cavity triangles; 240 of 274 of the demo's tracked faces), so lip
    texture stretched across the opened mouth. The lips are triangulated by hand: the inner contour
    is the cavity's 6 triangles and both contours are edges, on the photo and on a frame at rest;
    articulated speech (wide vowels, closures) folds no lip triangle away from the mouth corners,
    and on the frame at rest's mesh the mouth's interior shows through the lips' opening only."""
    from voicepuppet import synth

    photo = synth.face_photo((320, 320))
    phones = [("_", 0.0, 0.2), ("a", 0.2, 0.45), ("m", 0.45, 0.55), ("o", 0.55, 0.8), ("p", 0.8, 0.9),
              ("i", 0.9, 1.1), ("_", 1.1, 1.4)]
    rate = 16000
    hum = 0.1 * np.sin(2 * np.pi * 140 * np.arange(int(1.4 * rate)) / rate)
    art = synth.articulate(phones, hum, rate, photo.points, fps=29.97, seed=3, blinks=False)
    gap = np.linalg.norm(art.points[:, 66] - art.points[:, 62], axis=1)
    assert gap.max() > 25 and gap.min() < 1
    inner, corners = set(range(60, 68)), {48, 54, 60, 64}  # the outer and inner mouth corners
    for lm in (photo.points, art.points[int(np.argmin(gap))]):
        face = R.build_face_mesh(photo.image, lm)
        if face.mouth.any():  # the photo's mouth is closed: the interior's cavity
            _cavity_is_the_inner_lips(face)
            cavity = face.flat
        else:  # open: its own, textured
            cavity = np.array([set(f.tolist()) <= inner for f in face.faces])
        assert cavity.sum() in (6, 94)
        edges = {frozenset(e) for f in face.faces.tolist() for e in ((f[0], f[1]), (f[1], f[2]), (f[2], f[0]))}
        for r in (list(range(48, 60)), list(range(60, 68))):
            assert all(frozenset((r[i], r[(i + 1) % len(r)])) in edges for i in range(len(r)))
        verts = R.mesh_animation(Animation(art.points, 29.97), face, neutral=lm)["vertices"]
        skin = face.faces[~cavity]
        for t in range(len(verts)):
            folded = skin[_signed_area(verts[t, :, :2], skin) > 1e-9]
            lips = [f for f in folded.tolist() if set(f) & set(range(48, 68))]
            assert all(set(f) & corners for f in lips), f"frame {t}: {lips}"
    # the interior in white on a black face, rendered: inside the inner lips (1 px grown) only
    import cv2
    import dataclasses

    ids = np.zeros_like(face.colours)
    ids[face.flat] = 255
    probe = dataclasses.replace(face, image=np.zeros_like(face.image), colours=ids)
    seen = 0
    with R.FaceRenderer(probe, size=face.size) as r:
        for v in verts:
            shown = r.frame(v)[..., 0] > 128
            inner_px = np.zeros(shown.shape, np.uint8)
            cv2.fillPoly(inner_px, [np.round(v[60:68, :2]).astype(np.int32)], 1)
            assert not (shown & (cv2.dilate(inner_px, np.ones((3, 3), np.uint8)) == 0)).any()
            seen += shown.sum()
    assert seen > 1000


def _closed_lips(lm):
    lm = lm.copy()
    mid = 0.5 * (lm[[61, 62, 63]] + lm[[67, 66, 65]])
    lm[[61, 62, 63]] = lm[[67, 66, 65]] = mid
    return lm


def test_the_teeth_move_with_the_skull_and_the_jaw():
    """A closed-mouth photo gets teeth and a tongue behind its lips: a motion of the whole face
    (rotation, scale, shift) carries them exactly; opening the jaw leaves the upper arch with the
    skull and takes the lower one and the tongue down, less than the lower lip; rendered, the
    closed mouth shows none of it, the opened one both arches, the upper above the lower, and only
    inside the inner lips."""
    import cv2

    lm = _closed_lips(neutral_landmarks(240, 240))
    face = R.build_face_mesh(R.portrait_image(lm, 240, 240), lm)
    assert face.teeth.sum() == 64 and face.mouth.sum() == 6 + 8 + 16
    M = face.interpolation_matrix()
    interior = np.unique(face.faces[face.flat])
    # behind the skin, in layers under its depth surface (upper teeth, lower, tongue, cavity);
    # drawn back to front
    iod = np.linalg.norm(lm[45] - lm[36])
    below = R.skin_depth(face.vertices[:, :2], lm) - face.vertices[:, 2]
    skin = np.unique(face.faces[~face.flat])
    np.testing.assert_allclose(below[skin[skin < 68 + 28]], 0.0, atol=1e-9)
    own = np.setdiff1d(interior, skin)  # the interior's own vertices (its wall meets the inner lips)
    np.testing.assert_allclose(np.unique(np.round(below[own] / iod, 9)), [0.06, 0.10, 0.14, 0.18])
    order = face.draw_order()
    first = np.flatnonzero(face.flat)[0]  # the cavity's 6, the tongue's 8, the upper teeth's, the lower's
    drawn = order[np.isin(order, first + np.arange(78))]  # the wall is edge-on: anywhere among them
    np.testing.assert_array_equal(drawn, first + np.r_[0:14, 46:78, 14:46])
    assert set(order[94:]) == set(np.flatnonzero(~face.flat))
    # the whole face rotated, scaled and shifted: the interior moves with it exactly
    a, s, t = 0.2, 1.3, np.array([5.0, -3.0])
    Rm = np.array([[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]])
    moved = lambda p: s * (p - 120.0) @ Rm.T + 120.0 + t  # noqa: E731
    np.testing.assert_allclose(face.vertices[interior, :2] + M[interior] @ (moved(lm) - lm),
                               moved(face.vertices[interior, :2]), atol=1e-9)
    # the jaw opened: upper teeth stay, lower ones go down with the jaw and part of the lip's way
    anim = procedural_animation(2, 25.0, width=240, height=240, jaw=np.array([0.0, 1.0]), smile=0.0)
    anim = Animation(np.stack([_closed_lips(p) if k == 0 else p for k, p in enumerate(anim.points)]), 25.0)
    verts = R.mesh_animation(anim, face)["vertices"]
    dv = verts[1, :, :2] - verts[0, :, :2]
    up_mask, low_mask = np.zeros_like(face.teeth), np.zeros_like(face.teeth)
    up_mask[np.flatnonzero(face.teeth)[:32]] = low_mask[np.flatnonzero(face.teeth)[32:]] = True
    upper, lower = np.unique(face.faces[up_mask]), np.unique(face.faces[low_mask])
    lip = dv[66, 1]
    assert lip > 20 and np.abs(dv[upper]).max() < 1e-9
    assert np.all(dv[lower, 1] > 0.6 * lip) and np.all(dv[lower, 1] < lip)
    tongue = np.unique(face.faces[np.flatnonzero(face.mouth)[6:14]])
    assert np.all(dv[tongue, 1] > 0.6 * lip) and np.all(dv[tongue, 1] < lip)
    # rendered: pixels in the exact flat colours (no lighting), by kind
    with R.FaceRenderer(face, size=(240, 240)) as r:
        frames = [r.frame(v) for v in verts]

    def kind(img, mask):
        key = img.reshape(-1, 3).astype(int) @ [1, 256, 65536]
        return np.isin(key, face.colours[mask].astype(int) @ [1, 256, 65536]).reshape(img.shape[:2])

    for k in (face.mouth, up_mask, low_mask):
        assert kind(frames[0], k).sum() == 0
    ys_up, ys_low = np.nonzero(kind(frames[1], up_mask))[0], np.nonzero(kind(frames[1], low_mask))[0]
    assert len(ys_up) > 30 and len(ys_low) > 30 and kind(frames[1], face.mouth).sum() > 100
    assert ys_up.mean() < ys_low.mean()
    inner = np.zeros((240, 240), np.uint8)
    cv2.fillPoly(inner, [np.round(verts[1, 60:68, :2]).astype(np.int32)], 1)
    seen = kind(frames[1], face.flat)
    assert (cv2.dilate(inner, np.ones((3, 3), np.uint8))[seen] == 1).all()


def test_the_teeth_take_the_photos_tones():
    """The interior's colours follow the photo: a grey photo's teeth and cavity are grey, a photo
    half as bright has teeth half as bright (below the cap, 235); a photo with its mouth open keeps
    its own."""
    lm = _closed_lips(neutral_landmarks(240, 240))
    img = R.portrait_image(lm, 240, 240)
    colour = R.build_face_mesh((img * (2 / 3)).astype(np.uint8), lm)
    grey = R.build_face_mesh(np.repeat(img.mean(axis=2, keepdims=True).astype(np.uint8), 3, axis=2), lm)
    dim = R.build_face_mesh((img * (1 / 3)).astype(np.uint8), lm)
    c = colour.colours[colour.teeth].astype(float)
    assert np.ptp(c, axis=1).min() > 5  # tinted
    assert np.ptp(grey.colours[grey.flat].astype(int), axis=1).max() == 0
    np.testing.assert_allclose(dim.colours[dim.teeth] / c, 0.5, atol=0.03)
    open_face = R.build_face_mesh(img, neutral_landmarks(240, 240) + np.where(
        np.isin(np.arange(68), [65, 66, 67]), 1, 0)[:, None] * [0.0, 12.0])
    assert not open_face.flat.any() and len(open_face.vertices) == len(colour.vertices) - 114
    blind = lm.copy()
    blind[45] = blind[36]  # no inter-ocular distance to lay the teeth out in: none, and no NaN
    assert not R.build_face_mesh(img, blind).flat.any()


def test_interpolation_is_identity_on_landmarks_zero_on_frame(face):
    M = face.interpolation_matrix()
    np.testing.assert_allclose(M[:68], np.eye(68))
    assert np.all(M[face.fixed] == 0)
    # a uniform landmark shift moves the border rings part of the way, never beyond
    ring = ~face.fixed & (np.arange(len(M)) >= 68)
    moved = M[ring].sum(axis=1)
    assert np.all(moved > 0.05) and np.all(moved < 1.2)


def test_retarget_recovers_a_planted_similarity(rng):
    ref = neutral_landmarks()
    angle, s = 0.3, 1.7
    Rm = np.array([[np.cos(angle), np.sin(angle)], [-np.sin(angle), np.cos(angle)]])
    target = s * ref @ Rm + [40.0, -12.0]
    d = rng.normal(size=(5, 68, 2))
    got = R.retarget(ref + d, ref, target)
    np.testing.assert_allclose(got, s * d @ Rm, atol=1e-9)


def test_action_unit_least_squares_recovers_planted_activations(rng):
    lm = neutral_landmarks()
    B = R.action_unit_basis(lm)
    assert B.shape == (len(R.ACTION_UNITS), 68, 3)
    truth = rng.uniform(-0.5, 1.0, size=(40, len(R.ACTION_UNITS)))
    disp = np.einsum("tk,kpc->tpc", truth, B[..., :2]) + rng.normal(scale=0.01, size=(40, 68, 2))
    act, err = R.fit_activations(disp, B)
    np.testing.assert_allclose(act, truth, atol=0.02)
    assert np.all(err < 0.02)
    # bounded: activations outside the box are clipped to it, the rest still recovered
    act_b, _ = R.fit_activations(disp, B, bounds=(np.zeros(len(R.ACTION_UNITS)), np.ones(len(R.ACTION_UNITS))))
    assert act_b.min() >= 0 and act_b.max() <= 1
    inside = np.all(truth > 0.05, axis=1)
    np.testing.assert_allclose(act_b[inside], truth[inside], atol=0.02)


def test_au_projection_reports_motion_outside_the_basis():
    B = R.action_unit_basis(neutral_landmarks())
    shift = np.zeros((3, 68, 2))
    shift[:, :, 0] = 3.0  # a head translation: no action unit expresses it
    _, err = R.fit_activations(shift, B)
    assert np.all(err > 1.0) and np.all(err <= 3.0 / np.sqrt(2) + 1e-9)


def test_au_mode_tracks_the_planted_jaw_and_reports_its_error(face, jaw_anim):
    anim, jaw = jaw_anim
    res = R.mesh_animation(anim, face, mode="au")
    k = R.ACTION_UNITS.index("jaw_open")
    np.testing.assert_allclose(res["activations"][:, k], jaw, atol=1e-6)
    assert np.max(res["rms_error"]) < 1e-6
    np.testing.assert_allclose(res["vertices"], R.mesh_animation(anim, face, mode="vertex")["vertices"], atol=1e-6)


def test_rendered_frames_change_at_the_mouth_only_and_follow_the_jaw(face, jaw_anim):
    anim, jaw = jaw_anim
    frames = np.stack(list(R.render_frames(anim, face=face))).astype(float)
    assert frames.shape == (24, 240, 240, 3)
    # the neutral frame reproduces the photo
    assert np.mean(np.abs(frames[0] - face.image)) < 2.0
    lm = face.landmarks
    x0, y0 = lm[48:68].min(axis=0).astype(int)
    x1, y1 = lm[48:68].max(axis=0).astype(int)
    mouth = np.mean(np.abs(frames[:, y0 - 5:y1 + 40, x0:x1] - frames[0, y0 - 5:y1 + 40, x0:x1]), axis=(1, 2, 3))
    ey0, ey1 = int(lm[17:27, 1].min()) - 5, int(lm[36:48, 1].max()) + 5
    eyes = np.mean(np.abs(frames[:, ey0:ey1] - frames[0, ey0:ey1]), axis=(1, 2, 3))
    assert np.corrcoef(mouth, jaw)[0, 1] > 0.95
    assert mouth.max() > 20.0
    assert eyes.max() < 1.0
    closed = jaw < 1e-9
    assert np.all(mouth[closed] < 1.0)


def test_side_by_side_and_2d_fallback(face, jaw_anim):
    anim, _ = jaw_anim
    short = Animation(anim.points[:3], anim.fps)
    single = list(R.render_frames(short, face=face))
    pair = list(R.render_frames(short, face=face, truth=short))
    assert pair[0].shape == (240, 480, 3)
    # same animation on both sides: halves agree apart from the labels
    assert np.mean(np.abs(pair[2][40:, :240].astype(int) - single[2][40:].astype(int))) < 1.0
    np.testing.assert_array_equal(pair[2][40:, :240], pair[2][40:, 240:])
    # a prediction resting on its neutral beside a truth of frames only that begins open: the
    # truth rests on its frame nearest that neutral (the last: closed), not on its first
    opening = procedural_animation(4, 24.0, width=240, height=240, jaw=[0.7, 0.4, 0.1, 0.0], smile=0.0)
    rest = opening.points[-1]
    pred = Animation(opening.points, opening.fps, neutral=rest)
    beside = list(R.render_frames(pred, face=face, truth=opening))
    np.testing.assert_array_equal(beside[0][40:, :240], beside[0][40:, 240:])
    first = list(R.render_frames(pred, face=face, truth=opening, neutral=opening.points[0]))
    assert np.abs(first[0][40:, 240:].astype(int) - beside[0][40:, 240:]).max() > 40
    flat = list(R.render_frames(short, renderer="2d"))
    assert len(flat) == 3 and flat[0].ndim == 3
    assert not np.array_equal(flat[0], flat[2]) or np.allclose(short.points[0], short.points[2])


def test_a_video_beside_the_prediction(face, jaw_anim, tmp_path, write_avi):
    """``beside``: the recording's frame t on the left (scaled to one side's size), the
    prediction's frame t on the right; a shorter video or a truth too is refused."""
    anim, _ = jaw_anim
    short = Animation(anim.points[:4], anim.fps)
    levels = np.array([40, 90, 140, 190], np.uint8)
    video = write_avi(tmp_path / "rec.avi", np.repeat(levels, 120 * 120).reshape(4, 120, 120), fps=anim.fps)
    single = list(R.render_frames(short, face=face))
    out = list(R.render_frames(short, face=face, beside=video))
    assert len(out) == 4 and out[0].shape == (240, 480, 3)
    for t in range(4):  # the video's grey level, upscaled to 240 x 240, below the label
        assert abs(float(np.median(out[t][40:, :240])) - levels[t]) <= 3
        np.testing.assert_array_equal(out[t][40:, 240:], single[t][40:])
    with pytest.raises(ValueError, match="has 4 frames, the animation 5"):
        list(R.render_frames(Animation(anim.points[:5], anim.fps), face=face, beside=video))
    with pytest.raises(ValueError, match="not both"):
        list(R.render_frames(short, face=face, truth=short, beside=video))
    # the verb: render --beside VIDEO, the video on the left
    from voicepuppet.cli.main import main

    save_animation(short, tmp_path / "a.npz")
    assert main(["render", str(tmp_path / "a.npz"), "-o", str(tmp_path / "b.mp4"), "--renderer", "2d",
                 "--beside", str(video), "--quiet"]) == 0
    frames = list(R.render_frames(load_animation(tmp_path / "a.npz"), renderer="2d", beside=video))
    info = tracking_video.probe_video(tmp_path / "b.mp4")
    assert info.frame_count == 4 and (info.width, info.height) == frames[0].shape[1::-1]


def _write_tone(path, seconds, rate=16000):
    import soundfile as sf

    t = np.arange(int(rate * seconds)) / rate
    sf.write(path, 0.3 * np.sin(2 * np.pi * 330 * t), rate)


@pytest.mark.parametrize("audio_seconds", [2.0, 0.5])
def test_mp4_has_the_frame_count_duration_and_audio(tmp_path, face, audio_seconds):
    av = pytest.importorskip("av")
    pytest.importorskip("imageio_ffmpeg")
    anim = procedural_animation(30, 29.97, width=240, height=240)
    wav = tmp_path / "a.wav"
    _write_tone(wav, audio_seconds)
    out = R.render(anim, tmp_path / "out.mp4", audio=wav, face=face)
    assert sorted(os.listdir(tmp_path)) == ["a.wav", "out.mp4"]
    with av.open(str(out)) as c:
        video = c.streams.video[0]
        audio = c.streams.audio[0]
        assert (video.width, video.height) == (240, 240)
        assert abs(float(video.average_rate) - 29.97) < 1e-3
        n = sum(1 for _ in c.decode(video=0))
        assert n == 30
        a_dur = float(audio.duration * audio.time_base)
        # in sync: both streams start at zero (within AAC's priming delay)
        assert abs(float(video.start_time * video.time_base)) < 1e-6
        assert abs(float(audio.start_time * audio.time_base)) <= 1024 / 16000 + 1e-6
    # audio longer than the video is cut to it; shorter audio stays as it is
    assert abs(a_dur - min(audio_seconds, 30 / 29.97)) < 1.0 / 29.97 + 0.03


def test_gif_and_png_frames(tmp_path, face):
    from PIL import Image

    anim = procedural_animation(6, 10.0, width=240, height=240)
    gif = R.render(anim, tmp_path / "a.gif", face=face)
    with Image.open(gif) as im:
        assert im.n_frames == 6
        assert im.info["duration"] == 100
    folder = R.render(anim, tmp_path / "frames", face=face)
    assert sorted(p.name for p in folder.iterdir()) == [f"frame_{t:06d}.png" for t in range(6)]
    with pytest.raises(ValueError, match="already exists"):
        R.render(anim, tmp_path / "frames", face=face)


def test_bad_input_gives_clear_errors_and_no_files(tmp_path, face):
    anim = procedural_animation(4, 10.0, width=240, height=240)
    with pytest.raises(ValueError, match=r"shape \(T, P, 2\)"):
        Animation(np.zeros((4, 68)), 10.0)
    bad = anim.points.copy()
    bad[2, 5, 0] = np.nan
    with pytest.raises(ValueError, match="frame 2, point 5"):
        Animation(bad, 10.0)
    with pytest.raises(ValueError, match="fps"):
        Animation(anim.points, 0.0)
    with pytest.raises(ValueError, match="20 points per frame but the face mesh has 68"):
        R.mesh_animation(Animation(anim.points[:, :20], 10.0), face)
    with pytest.raises(ValueError, match="unknown format '.avi'"):
        R.render(anim, tmp_path / "a.avi", face=face)
    with pytest.raises(ValueError, match="does not exist"):
        R.render(anim, tmp_path / "missing" / "a.mp4", face=face)
    with pytest.raises(ValueError, match="must lie inside"):
        R.build_face_mesh(face.image, face.landmarks + 500.0)
    with pytest.raises(ValueError, match="mode"):
        R.mesh_animation(anim, face, mode="bones")
    with pytest.raises(ValueError, match="audio can only be muxed into .mp4"):
        R.render(anim, tmp_path / "a.gif", face=face, audio=__file__)
    readonly = tmp_path / "ro"
    readonly.mkdir()
    readonly.chmod(0o500)
    try:
        if not os.access(readonly, os.W_OK):  # root can write anywhere
            with pytest.raises(ValueError, match="not writable"):
                R.render(anim, readonly / "a.mp4", face=face)
    finally:
        readonly.chmod(0o700)

    # a failure mid-write leaves neither the output nor a temporary file
    def frames():
        yield np.zeros((240, 240, 3), np.uint8)
        raise RuntimeError("renderer died")

    for name in ("b.mp4", "b.gif", "b_frames"):
        with pytest.raises(RuntimeError, match="renderer died"):
            R.write_video(frames(), tmp_path / name, 10.0)
    assert sorted(os.listdir(tmp_path)) == ["ro"]


def test_an_interrupted_mp4_reaps_its_encoder_before_the_interruption_leaves(tmp_path, monkeypatch):
    pytest.importorskip("imageio_ffmpeg")
    started = []
    popen = V.subprocess.Popen

    def spy(*args, **kwargs):
        started.append(popen(*args, **kwargs))
        return started[-1]

    monkeypatch.setattr(V.subprocess, "Popen", spy)

    def frames():
        for t in range(40):
            yield np.full((64, 64, 3), t, np.uint8)
        raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        V.write_video(frames(), tmp_path / "a.mp4", 30.0)
    # killed and waited for: an encoder still running could create the removed temporary again
    assert len(started) == 1 and started[0].returncode is not None
    assert os.listdir(tmp_path) == []


def test_mp4_encoder_errors_and_odd_sizes(tmp_path):
    av = pytest.importorskip("av")
    pytest.importorskip("imageio_ffmpeg")
    with pytest.raises(ValueError, match=r"FFmpeg could not write '.*wide\.mp4': invalid width x height \(40000x2\)"):
        V.write_video([np.zeros((2, 40000, 3), np.uint8)] * 3, tmp_path / "wide.mp4", 10.0)
    with pytest.raises(ValueError, match="every frame must be 4x4x3 uint8 like the first; one is 4x4 uint8"):
        V.write_video([np.zeros((4, 4, 3), np.uint8), np.zeros((4, 4), np.uint8)], tmp_path / "b.mp4", 10.0)
    with pytest.raises(ValueError, match=r"frames must be \(height, width, 3\) RGB"):
        V.write_video([np.zeros((4, 4), np.uint8)], tmp_path / "c.mp4", 10.0)
    assert os.listdir(tmp_path) == []
    # odd sides: padded by one black column and row (yuv420p needs even ones), the picture kept
    img = np.zeros((17, 33, 3), np.uint8)
    img[:, :, 1] = 200
    V.write_video([img] * 3, tmp_path / "odd.mp4", 10.0)
    with av.open(str(tmp_path / "odd.mp4")) as c:
        got = next(c.decode(video=0)).to_ndarray(format="rgb24")
    assert got.shape == (18, 34, 3)
    assert abs(int(got[8, 16, 1]) - 200) <= 6 and got[-1, -1].max() <= 20


def test_animation_files_round_trip(tmp_path):
    anim = procedural_animation(7, 29.97, seed=3)
    save_animation(anim, tmp_path / "a.npz")
    save_animation(anim, tmp_path / "a.csv")
    back = load_animation(tmp_path / "a.npz")
    np.testing.assert_array_equal(back.points, anim.points)
    assert back.fps == anim.fps and back.names == list(face_layout.NAMES)
    csv = load_animation(tmp_path / "a.csv")
    np.testing.assert_allclose(csv.points, anim.points, rtol=1e-8)
    assert abs(csv.fps - 29.97) < 1e-4
    header = (tmp_path / "a.csv").read_text().splitlines()[0]
    assert header.startswith("frame,time,x0,y0,x1,y1")
    with pytest.raises(ValueError, match="unknown format"):
        load_animation(Path(__file__))
    with pytest.raises(ValueError, match="no 'points'"):
        np.savez(tmp_path / "x.npz", fps=3.0)
        load_animation(tmp_path / "x.npz")


def test_cli_render(tmp_path, capsys):
    from voicepuppet.cli.main import main

    anim = procedural_animation(5, 10.0, width=200, height=200)
    save_animation(anim, tmp_path / "a.npz")
    assert main(["render", str(tmp_path / "a.npz"), "-o", str(tmp_path / "a.gif"), "--renderer", "2d"]) == 0
    assert (tmp_path / "a.gif").is_file()
    assert "render:" in capsys.readouterr().err  # the progress bar
    assert main(["render", str(tmp_path / "a.npz"), "-o", str(tmp_path / "b.gif"), "--renderer", "2d",
                 "--quiet"]) == 0
    assert (tmp_path / "b.gif").is_file() and capsys.readouterr().err == ""
    assert main(["render", str(tmp_path / "a.npz"), "-o", str(tmp_path / "a.webm")]) == 2
    assert not (tmp_path / "a.webm").exists()


def test_a_large_face_image_renders_scaled_down_to_fit_hd(tmp_path, capsys):
    """Without --size a face image over 1920x1080 (1080x1920 upright) renders scaled down to fit
    it, aspect kept, and says so; smaller images and a given --size render as asked."""
    from PIL import Image

    from voicepuppet.cli.main import main

    assert R.default_size(4000, 3000) == (1440, 1080) and R.default_size(3000, 4000) == (1080, 1440)
    assert R.default_size(3000, 3000) == (1080, 1080) and R.default_size(2000, 500) == (1920, 480)
    assert R.default_size(1920, 1080) == (1920, 1080) and R.default_size(641, 481) == (642, 482)
    W, H = 1200, 1800
    lm = neutral_landmarks(W, H)
    Image.fromarray(R.portrait_image(lm, W, H)).save(tmp_path / "tall.png")
    (tmp_path / "tall.json").write_text(json.dumps({"points": lm.tolist()}))
    anim = procedural_animation(2, 10.0, width=W, height=H)
    save_animation(anim, tmp_path / "a.npz")
    face = ["--face", str(tmp_path / "tall.png"), "--face-points", str(tmp_path / "tall.json"), "--quiet"]
    assert main(["render", str(tmp_path / "a.npz"), "-o", str(tmp_path / "big"), *face]) == 0
    assert "rendering the 1200x1800 face image at 1080x1620 (--size WxH" in capsys.readouterr().out
    with Image.open(tmp_path / "big" / "frame_000000.png") as im:
        assert im.size == (1080, 1620)
    assert main(["render", str(tmp_path / "a.npz"), "-o", str(tmp_path / "small"), "--size", "300x450", *face]) == 0
    assert "rendering the" not in capsys.readouterr().out
    with Image.open(tmp_path / "small" / "frame_000001.png") as im:
        assert im.size == (300, 450)


def test_animator_controls_exaggerate_and_expression_offset(tmp_path):
    from voicepuppet.render import export as E
    from voicepuppet.animation import add_offset, exaggerate
    from voicepuppet.cli.main import main

    anim = procedural_animation(20, 10.0, seed=5)
    mu = anim.points.mean(axis=0)
    np.testing.assert_allclose(exaggerate(anim, 1.0).points, anim.points)
    np.testing.assert_allclose(exaggerate(anim, 2.0).points - mu, 2.0 * (anim.points - mu))
    np.testing.assert_allclose(exaggerate(anim, 0.0).points, np.broadcast_to(mu, anim.points.shape))
    with pytest.raises(ValueError, match="exaggeration factor"):
        exaggerate(anim, -1.0)
    offset = R.expression_offset(anim.points[0], "smile_left=1,smile_right=0.5")
    B = R.action_unit_basis(anim.points[0])[..., :2]
    np.testing.assert_allclose(offset, B[1] * 0.5 + B[2])
    grin = add_offset(anim, offset, start=0.5, end=1.0)
    inside = (anim.times >= 0.5 - 1e-9) & (anim.times <= 1.0 + 1e-9)
    np.testing.assert_allclose(grin.points[inside] - anim.points[inside], np.broadcast_to(offset, (6, 68, 2)))
    np.testing.assert_array_equal(grin.points[~inside], anim.points[~inside])
    faded = add_offset(anim, offset, start=0.5, end=1.5, fade=0.5)
    # the ramp reaches full strength only in the middle of the range (t = 1.0 s)
    w = (faded.points - anim.points)[:, 54, 0] / offset[54, 0]
    np.testing.assert_allclose(w[[4, 5, 7, 10, 13, 15, 16]], [0, 0, 0.4, 1.0, 0.4, 0, 0], atol=1e-9)
    with pytest.raises(ValueError, match="unknown action unit 'grin'"):
        R.expression_offset(anim.points[0], "grin=1")
    # the command line: a smile over 0.5..1.0 s shows up in the ARKit weights only there
    still = Animation(np.repeat(anim.points[:1], 20, axis=0), 10.0)
    save_animation(still, tmp_path / "s.npz")
    out = tmp_path / "w.csv"
    assert main(["export", str(tmp_path / "s.npz"), "--format", "arkit", "-o", str(out),
                 "--expression", "smile_left=1,smile_right=1", "--expression-time", "0.5:1.0"]) == 0
    table = np.loadtxt(out, delimiter=",", skiprows=1)
    smile = table[:, 2 + E.ARKIT_NAMES.index("mouthSmileLeft")]
    np.testing.assert_allclose(smile, inside.astype(float), atol=1e-6)
    # exaggerated, a frame at rest stays at rest (the neutral is scaled too) and the motion from
    # it doubles: jawOpen 0, 1, 0 for rest, half open, rest (the rest kept, 0.83 at the opening)
    talk = procedural_animation(3, 10.0, jaw=[0.0, 0.5, 0.0], smile=0.0)
    talk = Animation(talk.points, talk.fps, neutral=talk.points[0])
    loud = exaggerate(talk, 2.0)
    np.testing.assert_allclose(loud.neutral, loud.points[0], atol=1e-9)
    save_animation(talk, tmp_path / "t.npz")
    for path in (tmp_path / "t.npz", tmp_path / "t.csv"):  # with a neutral, and frames only
        save_animation(talk, path)
        assert main(["export", str(path), "--format", "arkit", "-o", str(out), "--exaggerate", "2"]) == 0
        jaw = np.loadtxt(out, delimiter=",", skiprows=1)[:, 2 + E.ARKIT_NAMES.index("jawOpen")]
        np.testing.assert_allclose(jaw, [0.0, 1.0, 0.0], atol=1e-6)


def test_a_photo_without_a_face_names_the_option_that_gives_its_points(tmp_path, monkeypatch):
    from PIL import Image

    import dlib  # noqa: F401  (installed with voicepuppet)
    Image.fromarray(np.full((120, 160, 3), 128, np.uint8)).save(tmp_path / "wall.png")
    with pytest.raises(ValueError, match=r"no face found in the photo .*wall\.png.*--face-points points\.json"):
        R.load_face(tmp_path / "wall.png")
    import sys

    monkeypatch.setitem(sys.modules, "dlib", None)  # no detector: the same option is named
    with pytest.raises(ValueError, match=r"pip install dlib-bin.*--face-points points\.json"):
        R.load_face(tmp_path / "wall.png")


def test_real_photo_with_dlib_landmarks():
    """A real face (scikit-image's astronaut) with dlib's 68 points: the neutral frame is the
    photo, a planted jaw opening moves the mouth and chin, not the eyes."""
    import dlib  # installed with voicepuppet
    skdata = pytest.importorskip("skimage.data")
    from voicepuppet.tracking.detect import landmark_model

    model = landmark_model()  # installed with voicepuppet
    img = skdata.astronaut()
    rects, scores, _ = dlib.get_frontal_face_detector().run(img, 1)
    shape = dlib.shape_predictor(model)(img, rects[int(np.argmax(scores))])
    pts = np.array([[shape.part(i).x, shape.part(i).y] for i in range(68)], dtype=np.float64)
    face = R.build_face_mesh(img, pts)
    assert 150 <= len(face.faces) <= 250
    assert not face.mouth.any()  # her mouth is open in the photo: its teeth texture the cavity
    jaw = np.r_[0.0, 0.5, 1.0, 0.5, 0.0]
    anim = procedural_animation(5, 10.0, jaw=jaw, smile=0.0)  # another face's geometry: retargeted
    frames = np.stack(list(R.render_frames(anim, face=face))).astype(float)
    assert np.mean(np.abs(frames[0] - img)) < 2.0
    lo, hi = pts[48:68].min(axis=0).astype(int), pts[48:68].max(axis=0).astype(int)
    mouth = np.mean(np.abs(frames[:, lo[1]:hi[1] + 20, lo[0]:hi[0]] - frames[0, lo[1]:hi[1] + 20, lo[0]:hi[0]]),
                    axis=(1, 2, 3))
    ey0, ey1 = int(pts[17:27, 1].min()), int(pts[36:48, 1].max()) + 3
    eyes = np.mean(np.abs(frames[:, ey0:ey1] - frames[0, ey0:ey1]), axis=(1, 2, 3))
    # more opening, more change; the same opening on the way back, the same picture
    assert mouth[1] > 3.0 and mouth[2] > mouth[1] + 3.0 and mouth[2] > 10.0
    assert abs(mouth[3] - mouth[1]) < 0.5
    assert eyes.max() < 1.0
    assert mouth[4] < 1.0


def test_a_video_gives_the_face_of_its_first_frame_with_one(tmp_path):
    """--face VIDEO (the puppet's own, say): the first frame dlib finds a face on, in colour,
    with its points; with --face-points, the video's first frame and those points. A file that
    is neither picture nor video is refused saying what to give."""
    import cv2

    import dlib  # installed with voicepuppet
    skdata = pytest.importorskip("skimage.data")
    from voicepuppet.tracking.detect import auto_init
    del dlib
    face = cv2.cvtColor(skdata.astronaut()[:256, 128:384], cv2.COLOR_RGB2BGR)
    path = tmp_path / "late.avi"
    w = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), 10.0, (256, 256), True)
    for k in range(12):  # 0.7 s of grey card, then the face: the probe at 0.5 s misses it
        w.write(np.full_like(face, 128) if k < 7 else face)
    w.release()
    cap = cv2.VideoCapture(str(path))
    decoded = [cap.read()[1] for _ in range(12)]
    mesh = R.load_face(path)
    np.testing.assert_array_equal(mesh.image, cv2.cvtColor(decoded[7], cv2.COLOR_BGR2RGB))
    np.testing.assert_array_equal(mesh.vertices[:68, :2], auto_init(cv2.cvtColor(decoded[7], cv2.COLOR_BGR2GRAY)))
    points = tmp_path / "p.json"
    points.write_text(json.dumps({"points": neutral_landmarks(256, 256).tolist()}))
    given = R.load_face(path, points)
    np.testing.assert_array_equal(given.image, cv2.cvtColor(decoded[0], cv2.COLOR_BGR2RGB))
    np.testing.assert_allclose(given.vertices[:68, :2], neutral_landmarks(256, 256))
    (tmp_path / "notes.txt").write_text("not a face")
    with pytest.raises(ValueError, match=r"neither a readable picture .* nor a video.*\.png / \.jpg photo"):
        R.load_face(tmp_path / "notes.txt")
    blank = tmp_path / "blank.avi"
    w = cv2.VideoWriter(str(blank), cv2.VideoWriter_fourcc(*"MJPG"), 10.0, (64, 48), True)
    for _ in range(3):
        w.write(np.full((48, 64, 3), 128, np.uint8))
    w.release()
    with pytest.raises(ValueError, match=r"face video: no face in the first .* --face-points"):
        R.load_face(blank)


def test_a_video_gives_its_face_at_rest_when_the_animation_has_one(tmp_path):
    """--face VIDEO for an animation with a rest face (a puppet's silence): the video's frame
    nearest it, not the first (which may be mid-word), among dlib's probes or the frames of
    --face-points landmarks."""
    import cv2

    import dlib  # installed with voicepuppet
    skdata = pytest.importorskip("skimage.data")
    from voicepuppet.tracking.detect import auto_init
    del dlib
    photo = np.ascontiguousarray(skdata.astronaut()[:256, 128:384])
    rest = auto_init(cv2.cvtColor(photo, cv2.COLOR_RGB2GRAY))
    opened = rest + 0.8 * R.action_unit_basis(rest)[R.ACTION_UNITS.index("jaw_open"), :, :2]
    points = np.stack([opened] * 8 + [rest] * 4)  # 0.8 s mid-word, then at rest (10 fps)
    mesh = R.build_face_mesh(photo, rest)
    path = tmp_path / "talk.avi"
    w = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), 10.0, (256, 256), True)
    for img in R.render_frames(Animation(points, 10.0), face=mesh, neutral=rest):
        w.write(np.ascontiguousarray(img[:, :, ::-1]))
    w.release()
    cap = cv2.VideoCapture(str(path))
    decoded = [cv2.cvtColor(cap.read()[1], cv2.COLOR_BGR2RGB) for _ in range(12)]
    gap = lambda q: np.linalg.norm(q[66] - q[62])  # noqa: E731
    first = R.load_face(path)
    np.testing.assert_array_equal(first.image, decoded[0])
    assert gap(first.landmarks) > gap(rest) + 8
    at_rest = R.load_face(path, rest=rest)  # probes at frames 5 (open) and 10 (at rest)
    np.testing.assert_array_equal(at_rest.image, decoded[10])
    assert abs(gap(at_rest.landmarks) - gap(rest)) < 3
    save_animation(Animation(points, 10.0), tmp_path / "tracked.npz")
    given = R.load_face(path, tmp_path / "tracked.npz", rest=rest)
    np.testing.assert_array_equal(given.image, decoded[8])
    np.testing.assert_allclose(given.landmarks, rest)
    np.testing.assert_array_equal(R.load_face(path, tmp_path / "tracked.npz").image, decoded[0])
    # points of another layout than the rest face's: nothing to compare, the first frame
    save_animation(Animation(points[:, ::6], 10.0), tmp_path / "other.npz")
    assert R.load_face(path, tmp_path / "other.npz", rest=rest).n_landmarks == 12


def test_a_photo_with_the_mouth_open_is_warned_about(tmp_path):
    """A photo moved from a closed rest face shows its own opening on every frame: said once,
    with what to give instead; a photo at rest is taken silently."""
    import warnings

    from PIL import Image

    rest = neutral_landmarks(240, 240)
    for name, jaw in (("open", 0.5), ("closed", 0.0)):
        pts = procedural_animation(1, 30.0, width=240, height=240, jaw=jaw, smile=0.0).points[0]
        Image.fromarray(R.portrait_image(pts, 240, 240)).save(tmp_path / f"{name}.png")
        (tmp_path / f"{name}.json").write_text(json.dumps({"points": pts.tolist()}))
    assert R.lip_gap_iod(rest) < 0.5 * R.OPEN_MOUTH_IOD
    with pytest.warns(UserWarning, match=r"lips 0\.\d+ inter-ocular distances apart .* mouth closed at rest"):
        R.resolve_face(str(tmp_path / "open.png"), tmp_path / "open.json", rest=rest)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        R.resolve_face(str(tmp_path / "closed.png"), tmp_path / "closed.json", rest=rest)
        R.resolve_face(str(tmp_path / "open.png"), tmp_path / "open.json")  # no rest: nothing to say


def test_face_palette_by_name(tmp_path):
    import json

    from PIL import Image

    from voicepuppet.cli.main import main

    pal = tmp_path / "faces"
    pal.mkdir()
    for name, size in (("wide", (300, 240)), ("tall", (240, 300))):
        lm = neutral_landmarks(*size)
        Image.fromarray(R.portrait_image(lm, *size)).save(pal / f"{name}.png")
        (pal / f"{name}.json").write_text(json.dumps({"points": lm.tolist()}))
    assert list(R.face_palette(pal)) == ["tall", "wide"]
    face = R.resolve_face("wide", palette=pal)
    assert face.size == (300, 240)
    np.testing.assert_allclose(face.landmarks, neutral_landmarks(300, 240))
    with pytest.raises(ValueError, match="choose one of tall, wide"):
        R.resolve_face("round", palette=pal)
    anim = procedural_animation(3, 10.0)
    save_animation(anim, tmp_path / "a.npz")
    assert main(["render", str(tmp_path / "a.npz"), "-o", str(tmp_path / "t.gif"), "--palette", str(pal),
                 "--face", "tall"]) == 0
    with Image.open(tmp_path / "t.gif") as im:
        assert im.size == (240, 300) and im.n_frames == 3


def test_a_face_of_other_geometry_by_point_correspondence():
    """Any point set works (a cartoon with 12 points): the mesh, vertex driving and rendering
    need no 68-point semantics; the action-unit mode says it needs them."""
    from PIL import Image, ImageDraw

    ang = np.linspace(0, 2 * np.pi, 12, endpoint=False)
    pts = np.column_stack([100 + 50 * np.cos(ang), 100 + 60 * np.sin(ang)])
    im = Image.new("RGB", (200, 200), (30, 90, 160))
    ImageDraw.Draw(im).polygon([tuple(p) for p in pts], fill=(250, 200, 40))
    face = R.build_face_mesh(np.asarray(im), pts)
    assert not face.mouth.any() and face.n_landmarks == 12
    motion = np.zeros((4, 12, 2))
    motion[:, 3, 1] = np.r_[0.0, 5.0, 10.0, 0.0]  # point 3 (bottom) moves down and back
    anim = Animation(pts + motion, 10.0)
    frames = np.stack(list(R.render_frames(anim, face=face))).astype(float)
    diff = np.abs(frames - frames[0]).mean(axis=(1, 2, 3))
    assert diff[0] == 0 and diff[3] < 0.5 and diff[2] > diff[1] > 0.05
    with pytest.raises(ValueError, match="68-point layout"):
        R.mesh_animation(anim, face, mode="au")


def test_chunked_rendering_matches_whole_animation_driving(face, monkeypatch):
    anim = procedural_animation(8, 10.0, width=240, height=240, seed=6)
    verts = R.mesh_animation(anim, face)["vertices"]
    with R.FaceRenderer(face) as r:
        direct = [r.frame(v) for v in verts]
    monkeypatch.setattr(V, "_FRAME_CHUNK", 3)
    chunked = list(R.render_frames(anim, face=face))
    for a, b in zip(direct, chunked):
        np.testing.assert_array_equal(a, b)
