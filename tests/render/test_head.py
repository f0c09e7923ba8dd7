"""A textured 3-D head scan driven by landmark animations (voicepuppet.render.head).

Heads are planted: a textured dome with the 68 landmarks of a parametric face on its surface,
written as .obj + material + texture, in any pose; and the real scan ``james`` of menpo3d's
source archive.
"""

import json
from pathlib import Path

import numpy as np
import pytest

from voicepuppet import layout as face_layout
from voicepuppet.render import head as Hd
from voicepuppet import render as R
from voicepuppet.cli import render as cli_render
from voicepuppet.render.mesh import MOUTH_COLOUR
from voicepuppet.animation import Animation, neutral_landmarks, procedural_animation, save_animation

pytest.importorskip("pyvista")

DOME_R = 3.0


def _rotation(axis, degrees):
    a = np.asarray(axis, np.float64) / np.linalg.norm(axis)
    K = np.array([[0, -a[2], a[1]], [a[2], 0, -a[0]], [-a[1], a[0], 0]])
    t = np.radians(degrees)
    return np.eye(3) + np.sin(t) * K + (1 - np.cos(t)) * K @ K


def _dome_points():
    """The parametric face's 68 points on the dome z = sqrt(R² - x² - y²), model units (y up)."""
    lm = neutral_landmarks(440, 440)
    xy = np.column_stack([(lm[:, 0] - 220) / 100.0, -(lm[:, 1] - 220) / 100.0])
    return np.column_stack([xy, np.sqrt(DOME_R ** 2 - (xy ** 2).sum(axis=1))])


def _write_head(folder: Path, rotation=np.eye(3), shift=(0.0, 0.0, 0.0), texture=True, uv=True) -> tuple[Path, Path]:
    """A dome mesh (51 x 51 grid over [-2, 2]², 5,000 triangles) with a checked colour texture and
    the face's points, both moved by ``rotation`` then ``shift``; returns (obj, points json)."""
    from PIL import Image

    folder.mkdir(parents=True, exist_ok=True)
    g = np.linspace(-2.0, 2.0, 51)
    X, Y = np.meshgrid(g, g)
    P = np.column_stack([X.ravel(), Y.ravel(), np.sqrt(DOME_R ** 2 - X.ravel() ** 2 - Y.ravel() ** 2)])
    UV = np.column_stack([(X.ravel() + 2) / 4, (Y.ravel() + 2) / 4])
    idx = np.arange(51 * 51).reshape(51, 51)
    a, b, c, d = idx[:-1, :-1].ravel(), idx[:-1, 1:].ravel(), idx[1:, 1:].ravel(), idx[1:, :-1].ravel()
    F = np.vstack([np.column_stack([a, b, c]), np.column_stack([a, c, d])])  # counter-clockwise from +z
    move = lambda p: p @ np.asarray(rotation).T + np.asarray(shift)  # noqa: E731
    lines = ["mtllib dome.mtl"] + [f"v {x:.9f} {y:.9f} {z:.9f}" for x, y, z in move(P)]
    if uv:
        lines += [f"vt {u:.9f} {v:.9f}" for u, v in UV]
        lines += [f"f {i + 1}/{i + 1} {j + 1}/{j + 1} {k + 1}/{k + 1}" for i, j, k in F]
    else:
        lines += [f"f {i + 1} {j + 1} {k + 1}" for i, j, k in F]
    (folder / "dome.obj").write_text("\n".join(lines) + "\n")
    if texture:
        (folder / "dome.mtl").write_text("newmtl skin\nmap_Kd dome_skin.png\n")
        yy, xx = np.mgrid[0:256, 0:256]
        img = np.stack([90 + xx // 2, 60 + yy // 2, 120 + 40 * (((xx // 16) + (yy // 16)) % 2)], axis=2)
        Image.fromarray(img.astype(np.uint8)).save(folder / "dome_skin.png")
    (folder / "dome.json").write_text(json.dumps({"points": move(_dome_points()).tolist()}))
    return folder / "dome.obj", folder / "dome.json"


@pytest.fixture(scope="module")
def dome(tmp_path_factory):
    return Hd.load_head(*_write_head(tmp_path_factory.mktemp("dome")))


def _opened(mesh, amount):
    """The mesh's landmarks with the jaw, the chin and the lower lip down by ``amount`` IOD."""
    lm = mesh.landmarks.copy()
    iod = float(face_layout.inter_ocular_distance(lm))
    lower = [5, 6, 7, 8, 9, 10, 11, 55, 56, 57, 58, 59, 65, 66, 67]
    lm[lower, 1] += amount * iod
    return lm


def _frontal_area(xy, faces):
    a, b, c = (xy[faces[:, k]] for k in range(3))
    return 0.5 * np.abs((b[:, 0] - a[:, 0]) * (c[:, 1] - a[:, 1]) - (b[:, 1] - a[:, 1]) * (c[:, 0] - a[:, 0]))


def _area_3d(v, faces):
    return 0.5 * np.linalg.norm(np.cross(v[faces[:, 1]] - v[faces[:, 0]], v[faces[:, 2]] - v[faces[:, 0]]), axis=1)


def test_a_head_is_seen_from_the_front_whatever_its_pose(tmp_path, dome):
    """The same head turned 35 degrees about a slanted axis and moved gives the same frontal mesh
    (to 1e-6 px); the landmarks' frontal shape is the face's, centred, 720 px high."""
    turned = Hd.load_head(*_write_head(tmp_path, _rotation((0.3, 1.0, 0.2), 35.0), (5.0, -2.0, 7.0)))
    from scipy.spatial import cKDTree

    # the same vertices (in another order: they are numbered by their model coordinates) and faces
    assert turned.vertices.shape == dome.vertices.shape and turned.faces.shape == dome.faces.shape
    np.testing.assert_allclose(turned.landmarks, dome.landmarks, atol=1e-6)
    assert cKDTree(dome.vertices).query(turned.vertices)[0].max() < 1e-6

    # each face found again by its centroid, with its area and its kind (skin, cavity, teeth)
    centroid = lambda m: m.vertices[m.faces].mean(axis=1)  # noqa: E731
    dist, match = cKDTree(centroid(dome)).query(centroid(turned))
    assert dist.max() < 1e-5  # (the cavity's faces, of zero area at rest, share their centroids)
    np.testing.assert_allclose(_area_3d(turned.vertices, turned.faces), _area_3d(dome.vertices, dome.faces)[match],
                               rtol=1e-6, atol=1e-9)
    np.testing.assert_array_equal(turned.mouth, dome.mouth[match])
    np.testing.assert_array_equal(turned.teeth, dome.teeth[match])
    assert dome.size[1] == 720 and dome.n_landmarks == 68
    lm = dome.landmarks
    assert abs(0.5 * (lm[:, 0].min() + lm[:, 0].max()) - dome.size[0] / 2) < 1e-6
    from voicepuppet.face import shape_distance

    flat = neutral_landmarks(440, 440)
    assert shape_distance(lm[None], flat)[0] < 0.05 * face_layout.inter_ocular_distance(flat)
    # the frame: x along the outer eye corners, y up from the chin, z towards the viewer
    Rm = Hd.frontal_frame(_dome_points())
    np.testing.assert_allclose(Rm @ Rm.T, np.eye(3), atol=1e-12)
    assert Rm[0] @ [1, 0, 0] > 0.99 and Rm[1] @ [0, 1, 0] > 0.99 and np.linalg.det(Rm) > 0


def test_the_lips_are_cut_apart_invisibly_at_rest(dome, tmp_path):
    """The cut keeps the surface (its area to 1e-9, each crossing's two copies at one place, the
    cavity of zero frontal area), so the head at rest renders exactly as without its interior."""
    skin = dome.faces[~dome.flat]
    original = Hd._read_mesh(_write_head(tmp_path)[0])
    lf = _dome_points() @ Hd.frontal_frame(_dome_points()).T
    ext = lf[:, :2].max(axis=0) - lf[:, :2].min(axis=0)  # canvas pixels per model unit, as load_head
    scale = dome.size[1] / (ext[1] + 0.9 * ext.max())
    np.testing.assert_allclose(_area_3d(dome.vertices, skin).sum(), _area_3d(*original[:2]).sum() * scale ** 2,
                               rtol=1e-9)
    cavity = dome.faces[np.flatnonzero(dome.mouth & ~dome.teeth)[:-8]]  # the tongue's 8 come last
    assert len(cavity) > 20
    np.testing.assert_allclose(_frontal_area(dome.vertices[:, :2], cavity), 0.0, atol=1e-6)
    with R.FaceRenderer(dome, size=(300, 288)) as r:
        full = r.frame(dome.vertices)
    bare = R.FaceMesh(dome.vertices, skin, np.zeros(len(skin), bool), dome.uv, dome.image, 68,
                      dome.fixed, canvas=dome.canvas, _interp=dome.interpolation_matrix())
    with R.FaceRenderer(bare, size=(300, 288)) as r:
        np.testing.assert_array_equal(r.frame(bare.vertices), full)


def test_an_opened_jaw_parts_the_lips_and_shows_the_mouth(dome):
    """The lower lip follows its landmarks and the upper lip its own (the cut between them
    opens); the back of the dome does not move; a shift of the whole face shifts every vertex
    near it exactly; rendered, the mouth's interior shows between the lips, more the wider."""
    M = dome.interpolation_matrix()
    lm = dome.landmarks
    iod = float(face_layout.inter_ocular_distance(lm))
    dv = M @ (_opened(dome, 0.2) - lm)
    skin = np.zeros(len(dome.vertices), bool)
    skin[dome.faces[~dome.flat]] = True
    near_mouth = skin & (np.linalg.norm(dome.vertices[:, :2] - lm[[62, 66]].mean(axis=0), axis=1) < 0.15 * iod)
    up = near_mouth & (dome.vertices[:, 1] < lm[62, 1] - 0.03 * iod)
    down = near_mouth & (dome.vertices[:, 1] > lm[66, 1] + 0.03 * iod)
    assert up.sum() >= 2 and down.sum() >= 2
    assert np.all(dv[up, 1] < 0.15 * 0.2 * iod) and np.all(dv[down, 1] > 0.6 * 0.2 * iod)
    assert dome.fixed.any() and np.all(dv[dome.fixed] == 0.0)
    shift = M @ np.tile([3.0, -2.0], (68, 1))
    from scipy.spatial import cKDTree

    close = cKDTree(lm).query(dome.vertices[:, :2])[0] < 0.1 * iod
    np.testing.assert_allclose(shift[close], np.tile([3.0, -2.0], (close.sum(), 1)), atol=1e-9)

    shown = []
    anim = Animation(np.stack([lm, _opened(dome, 0.1), _opened(dome, 0.2)]), 10.0)
    verts = R.mesh_animation(anim, dome, neutral=lm)["vertices"]
    with R.FaceRenderer(dome) as r:
        for v in verts:
            img = r.frame(v).astype(int)
            shown.append(int(np.sum(np.abs(img - np.asarray(MOUTH_COLOUR)).sum(axis=2) < 40)))
    assert shown[0] == 0 < shown[1] < shown[2]


def test_menpo_ljson_groups_are_put_in_ibug_order(tmp_path):
    """menpo's labelled groups (eyes and brows before the nose, each named from the subject's
    side) come back in iBUG order; the points mirrored are refused by the frontal frame."""
    pts = _dome_points()
    order = np.r_[0:17, 36:42, 42:48, 17:22, 27:36, 22:27, 48:68]  # menpo's: chin, eyes, brow, nose, brow, mouth
    groups, start = [], 0
    for name, n in (("chin", 17), ("leye", 6), ("reye", 6), ("leyebrow", 5), ("nose", 9), ("reyebrow", 5),
                    ("mouth", 20)):
        groups.append({"label": name, "mask": list(range(start, start + n))})
        start += n
    doc = {"groups": {"LJSON": {"labels": groups, "landmarks": {"points": pts[order].tolist()}}}, "version": 3}
    (tmp_path / "h.ljson").write_text(json.dumps(doc))
    np.testing.assert_array_equal(Hd.read_points_3d(tmp_path / "h.ljson"), pts)
    mirrored = pts * [-1.0, 1.0, 1.0]
    with pytest.raises(ValueError, match="mirrored"):
        Hd.frontal_frame(mirrored)
    doc["groups"]["LJSON"]["labels"] = groups[:-1]
    (tmp_path / "bad.ljson").write_text(json.dumps(doc))
    with pytest.raises(ValueError, match="68-point groups"):
        Hd.read_points_3d(tmp_path / "bad.ljson")


def test_bad_heads_get_clear_errors(tmp_path):
    obj, pts = _write_head(tmp_path / "ok")
    with pytest.raises(ValueError, match="no face found on .*--face-points"):
        Hd.load_head(obj, None)  # a checked texture: no face for the detector
    with pytest.raises(ValueError, match="does not exist"):
        Hd.load_head(tmp_path / "none.obj", pts)
    (tmp_path / "few.json").write_text(json.dumps({"points": _dome_points()[:67].tolist()}))
    with pytest.raises(ValueError, match="67 points"):
        Hd.load_head(obj, tmp_path / "few.json")
    bad = _dome_points()
    bad[3, 1] = np.nan
    (tmp_path / "nan.json").write_text(json.dumps({"points": bad.tolist()}))
    with pytest.raises(ValueError, match="NaN"):
        Hd.load_head(obj, tmp_path / "nan.json")
    (tmp_path / "flat.json").write_text(json.dumps({"points": neutral_landmarks().tolist()}))
    with pytest.raises(ValueError, match=r"\[x, y, z\]"):
        Hd.load_head(obj, tmp_path / "flat.json")
    (tmp_path / "far.json").write_text(json.dumps({"points": (_dome_points() * 10.0).tolist()}))
    with pytest.raises(ValueError, match="not on the mesh"):
        Hd.load_head(obj, tmp_path / "far.json")
    with pytest.raises(ValueError, match="no texture"):
        Hd.load_head(*_write_head(tmp_path / "bare", texture=False))
    with pytest.raises(ValueError, match="texture coordinates"):
        Hd.load_head(*_write_head(tmp_path / "nouv", uv=False))
    two = tmp_path / "two"
    obj2, pts2 = _write_head(two)
    (two / "dome.mtl").write_text("newmtl skin\nmap_Kd dome_skin.png\nnewmtl eyes\nmap_Kd eyes.png\n")
    with pytest.warns(UserWarning, match="2 textures.*dome_skin.png textures every face"):
        Hd.load_head(obj2, pts2)
    (tmp_path / "junk.obj").write_text("this is not a mesh\n")
    with pytest.raises(ValueError, match="junk.obj"):
        Hd.load_head(tmp_path / "junk.obj", pts)


def test_cli_renders_and_exports_a_head(tmp_path, capsys):
    from voicepuppet.cli.main import main

    obj, pts = _write_head(tmp_path / "head")
    anim = procedural_animation(4, 10.0, width=240, height=240, jaw=np.array([0.0, 0.5, 1.0, 0.5]))
    save_animation(anim, tmp_path / "a.npz")
    face = ["--face", str(obj), "--face-points", str(pts)]
    assert main(["render", str(tmp_path / "a.npz"), "-o", str(tmp_path / "frames"), *face, "--quiet"]) == 0
    from PIL import Image

    frames = sorted((tmp_path / "frames").glob("*.png"))
    with Image.open(frames[0]) as im:
        assert len(frames) == 4 and im.size == Hd.load_head(obj, pts).size
    assert "finding" not in capsys.readouterr().err  # the points were given
    assert main(["export", str(tmp_path / "a.npz"), "--format", "gltf", "-o", str(tmp_path / "a.glb"), *face]) == 0
    assert (tmp_path / "a.glb").stat().st_size > 0
    assert main(["render", str(tmp_path / "a.npz"), "-o", str(tmp_path / "b.mp4"), "--face", str(obj)]) == 2
    assert not (tmp_path / "b.mp4").exists()
    err = capsys.readouterr().err
    assert "finding the 68 landmarks of dome.obj" in err and "no face found on" in err
    from voicepuppet.live.outputs import FaceDriver

    with pytest.raises(ValueError, match="render and export take the head"):
        FaceDriver(str(obj), str(pts), 68)


def _marked(head):
    """The head with its mouth's interior (cavity, tongue, teeth) in pure green."""
    return R.FaceMesh(head.vertices, head.faces, head.mouth, head.uv, head.image, 68, head.fixed,
                      teeth=head.teeth, colours=np.where(head.flat[:, None], [0, 255, 0], 0).astype(np.uint8),
                      canvas=head.canvas, _interp=head.interpolation_matrix())


def test_the_real_head_scan_shows_its_mouth_through_the_opening_only():
    """menpo3d's scan ``james``: its menpo points come in iBUG order (the outer eye corners at the
    ends of the eyes, the nose tip below the bridge); opening the parametric face's jaw on it
    opens a hole in its skin (the skin alone rendered: the background shows through inside the
    outer lips) that the mouth's interior fills exactly: none of it shows elsewhere (to 1 px),
    and no background shows through the mouth."""
    import cv2

    obj, pts = Hd.sample_head()
    head = Hd.load_head(obj, pts)
    lm = head.landmarks
    assert lm[36, 0] < lm[37:42, 0].min() and lm[45, 0] > np.r_[lm[42:45, 0], lm[46:48, 0]].max()
    assert lm[30, 1] > lm[27, 1] and lm[8, 1] == lm[:, 1].max()
    anim = procedural_animation(3, 10.0, width=240, height=240, jaw=np.array([0.0, 0.6, 1.0]))
    verts = R.mesh_animation(anim, head)["vertices"]
    M = head.interpolation_matrix()
    skin = head.faces[~head.flat]
    bare = R.FaceMesh(head.vertices, skin, np.zeros(len(skin), bool), head.uv, head.image, 68, head.fixed,
                      canvas=head.canvas, _interp=M)
    shown = []
    with R.FaceRenderer(_marked(head)) as r, R.FaceRenderer(bare) as rb:
        for v in verts:
            img, skin_only = r.frame(v).astype(int), rb.frame(v).astype(int)
            interior = np.all(np.abs(img - [0, 255, 0]) < 30, axis=2)
            lips = np.zeros(img.shape[:2], np.uint8)
            cv2.fillConvexPoly(lips, cv2.convexHull(np.round(v[48:60, :2]).astype(np.int32)), 1)
            hole = (skin_only.sum(axis=2) == 0) & lips.astype(bool)
            grown = cv2.dilate(hole.astype(np.uint8), np.ones((3, 3), np.uint8)).astype(bool)
            assert not np.any(interior & ~grown)
            assert not np.any((img.sum(axis=2) == 0) & lips.astype(bool))
            shown.append(int(interior.sum()))
    assert shown[0] == 0 < 1000 < shown[1] < shown[2]


def test_a_heads_points_are_found_on_its_front_view():
    """Without points, dlib's 68 on james's front view, lifted to the surface, lie near menpo's
    hand-placed ones in the frontal plane (eyes and brows within 0.04 IOD, outer lips 0.08, the
    inner lips, closed as the scan's mouth is, 0.03, nose bridge 0.1, as means), and the head
    they give opens its mouth with the interior showing."""
    obj, pts = Hd.sample_head()
    v, f, uv = Hd._read_mesh(obj)
    found = Hd.detect_points_3d(v, f, uv, Hd._texture(obj))
    truth = Hd.read_points_3d(pts)
    iod = float(np.linalg.norm(truth[36] - truth[45]))
    err = np.linalg.norm(((found - truth) @ Hd.frontal_frame(truth).T)[:, :2], axis=1) / iod
    G = face_layout.GROUPS
    for groups, limit in (((G["right_eye"], G["left_eye"], G["right_brow"], G["left_brow"]), 0.04),
                          ((G["outer_lip"],), 0.08), ((G["inner_lip"],), 0.03), ((G["nose_bridge"],), 0.1)):
        assert err[np.concatenate([list(g) for g in groups])].mean() < limit
    # the same head facing -z (as Blender leaves one) or +x: found from that side, the same points
    for turn in ((0.0, 1.0, 0.0, 180.0), (0.0, 1.0, 0.0, 90.0)):
        Rt = _rotation(turn[:3], turn[3])
        np.testing.assert_allclose(Hd.detect_points_3d(v @ Rt.T, f, uv, Hd._texture(obj)), found @ Rt.T,
                                   atol=0.01 * iod)
    head = Hd.load_head(obj, None)
    assert R.lip_gap_iod(head.landmarks) < 0.01  # the scan's mouth is closed: dlib parted its lips
    anim = procedural_animation(2, 10.0, width=240, height=240, jaw=np.array([0.0, 1.0]))
    verts = R.mesh_animation(anim, head)["vertices"]
    with R.FaceRenderer(_marked(head)) as r:
        shown = [int(np.all(np.abs(r.frame(x).astype(int) - [0, 255, 0]) < 30, axis=2).sum()) for x in verts]
    assert shown[0] == 0 < 1000 < shown[1]


def test_a_turned_view_turns_the_face_the_way_it_says(dome):
    """``turn``: (0, 0) is the front view exactly. Two flat marks 60 px in front of and behind the
    view's centre land where the turn puts them: a face turned to its left (positive yaw) moves
    what is in front of it to the viewer's right by 60 sin(yaw) px and what is behind to the left;
    a lifted chin (positive pitch) moves what is in front up. Out-of-range turns are refused."""
    with R.FaceRenderer(dome, size=(300, 288)) as r, R.FaceRenderer(dome, size=(300, 288), turn=(0.0, 0.0)) as r0:
        np.testing.assert_array_equal(r0.frame(dome.vertices), r.frame(dome.vertices))
    tri = np.array([[-6.0, 5.0, 0.0], [6.0, 5.0, 0.0], [0.0, -6.0, 0.0]])  # y down, as the canvas
    verts = np.vstack([tri + [150, 150, 60], tri + [150, 150, -60], [[0, 0, -200], [10, 0, -200], [0, 10, -200]]])
    faces = np.array([[0, 1, 2], [3, 4, 5], [6, 7, 8]])
    marks = R.FaceMesh(verts, faces, np.array([True, True, False]), np.zeros((9, 2)), np.zeros((4, 4, 3), np.uint8),
                       0, np.zeros(9, bool), colours=np.array([[0, 255, 0], [255, 0, 255], [0, 0, 0]], np.uint8),
                       canvas=(300, 300))

    def seen(turn):
        with R.FaceRenderer(marks, size=(300, 300), turn=turn) as r:
            img = r.frame(verts).astype(int)
        where = [np.argwhere(np.all(np.abs(img - c) < 30, axis=2)) for c in ([0, 255, 0], [255, 0, 255])]
        return [w.mean(axis=0)[::-1] if len(w) else None for w in where]

    front0, back0 = seen((0.0, 0.0))
    assert back0 is None  # from the front the mark in front hides the one behind
    back0 = front0
    s = 60 * np.sin(np.radians(25.0))
    front, back = seen((25.0, 0.0))
    np.testing.assert_allclose(front - front0, [s, 0.0], atol=2.0)
    np.testing.assert_allclose(back - back0, [-s, 0.0], atol=2.0)
    front, back = seen((0.0, 25.0))
    np.testing.assert_allclose(front - front0, [0.0, -s], atol=2.0)
    with pytest.raises(ValueError, match="turn"):
        R.FaceRenderer(dome, size=(300, 288), turn=(120.0, 0.0))
    with pytest.raises(ValueError, match="--turn"):
        cli_render._turn("left")
    assert cli_render._turn("30") == (30.0, 0.0) and cli_render._turn("-20,10") == (-20.0, 10.0)
