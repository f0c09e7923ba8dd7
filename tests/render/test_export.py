"""Exports on planted animations: glTF round trip (pygltflib, trimesh), VTK series back through
pyvista, ARKit weights of a known jaw opening, Rhubarb cues of known mouth shapes, bad input."""

import json
import os

import numpy as np
import pytest

from voicepuppet.render import export as E
from voicepuppet import render as R
from voicepuppet.animation import Animation, load_animation, neutral_landmarks, procedural_animation, save_animation

pytest.importorskip("pyvista")


def _accessor(gltf, blob, index):
    import pygltflib as g

    acc = gltf.accessors[index]
    view = gltf.bufferViews[acc.bufferView]
    dtype = {g.FLOAT: np.float32, g.UNSIGNED_INT: np.uint32}[acc.componentType]
    width = {g.SCALAR: 1, g.VEC2: 2, g.VEC3: 3}[acc.type]
    assert view.byteOffset + view.byteLength <= len(blob)
    arr = np.frombuffer(blob, dtype=dtype, count=acc.count * width, offset=view.byteOffset)
    assert arr.nbytes == view.byteLength
    return arr.reshape(acc.count, width) if width > 1 else arr


@pytest.mark.parametrize("mode", ["au", "vertex"])
def test_glb_round_trips_and_morph_weights_reproduce_the_mesh(tmp_path, mode):
    g = pytest.importorskip("pygltflib")
    anim = procedural_animation(20, 25.0, seed=4 if mode == "vertex" else None)
    face = E.default_face(anim)
    out = tmp_path / "a.glb"
    summary = E.write_glb(anim, out, face=face, mode=mode)
    assert os.listdir(tmp_path) == ["a.glb"]
    gltf = g.GLTF2.load(str(out))
    blob = gltf.binary_blob()
    assert gltf.buffers[0].byteLength == len(blob)
    prim = gltf.meshes[0].primitives[0]
    V = len(face.vertices)
    assert gltf.accessors[prim.attributes.POSITION].count == V
    assert gltf.accessors[prim.attributes.TEXCOORD_0].count == V
    assert gltf.accessors[prim.indices].count == 3 * int((~face.flat).sum())
    # the cavity and the teeth: the second primitive, in their colours, behind the skin
    inside = gltf.meshes[0].primitives[1]
    idx = _accessor(gltf, blob, inside.indices).reshape(-1, 3)
    np.testing.assert_array_equal(idx, face.faces[face.flat])
    colours = _accessor(gltf, blob, inside.attributes.COLOR_0)
    np.testing.assert_allclose(colours[idx[:, 0]] * 255, face.colours[face.flat], atol=1e-3)
    below = R.skin_depth(face.vertices[:, :2], face.landmarks) - face.vertices[:, 2]
    own = np.setdiff1d(idx, face.faces[~face.flat])  # the interior's own vertices, not the inner lips
    assert len(own) == 114 and below[own].min() > 0  # (the positions are the mesh's: `got` below)
    sampler = gltf.animations[0].samplers[0]
    times = _accessor(gltf, blob, sampler.input)
    assert len(times) == anim.n_frames and np.all(np.diff(times) > 0)
    # keys at t / fps: the last key at (T - 1) / fps, the frames cover T / fps
    np.testing.assert_allclose(times[-1] + 1 / anim.fps, anim.duration, rtol=1e-6)
    assert gltf.accessors[sampler.input].max[0] == pytest.approx(times[-1])
    K = len(prim.targets)
    names = gltf.meshes[0].extras["targetNames"]
    assert K == summary["targets"] == len(names)
    if mode == "au":
        assert names == list(R.ACTION_UNITS)
    weights = _accessor(gltf, blob, sampler.output).reshape(anim.n_frames, K)
    base = _accessor(gltf, blob, prim.attributes.POSITION).astype(float)
    targets = np.stack([_accessor(gltf, blob, t["POSITION"] if isinstance(t, dict) else t.POSITION)
                        for t in prim.targets]).astype(float)
    got = base[None] + np.einsum("tk,kvc->tvc", weights.astype(float), targets)
    # expected: the driven mesh, mapped to metres with the inter-ocular distance at 65 mm
    verts = R.mesh_animation(anim, face, mode=mode)["vertices"]
    iod = np.linalg.norm(face.landmarks[36] - face.landmarks[45])
    centre = np.r_[face.landmarks.mean(axis=0), 0.0]
    want = (verts - centre) * (0.065 / iod)
    want[..., 1] *= -1
    np.testing.assert_allclose(got, want, atol=2e-6)  # float32 storage
    assert summary["max_error_m"] < 1e-6
    trimesh = pytest.importorskip("trimesh")
    scene = trimesh.load(str(out))
    assert sum(len(m.faces) for m in scene.geometry.values()) == len(face.faces)


def test_vtk_series_loads_back_in_pyvista(tmp_path):
    pv = pytest.importorskip("pyvista")
    anim = procedural_animation(5, 10.0)
    face = E.default_face(anim)
    E.write_pvd(anim, tmp_path / "s.pvd", face=face)
    assert sorted(os.listdir(tmp_path)) == ["s.pvd", "s_frames"]
    assert (tmp_path / "s_frames" / "texture.png").is_file()
    verts = R.mesh_animation(anim, face)["vertices"]
    reader = pv.get_reader(str(tmp_path / "s.pvd"))
    np.testing.assert_allclose(reader.time_values, np.arange(5) / 10.0)
    for t in (0, 3):
        reader.set_active_time_value(t / 10.0)
        mesh = reader.read()[0]
        np.testing.assert_allclose(mesh.points, verts[t], atol=1e-4)
        assert mesh.n_cells == len(face.faces)
        np.testing.assert_array_equal(mesh.cell_data["teeth"], face.teeth)
        np.testing.assert_array_equal(mesh.cell_data["colour"][face.flat], face.colours[face.flat])
    with pytest.raises(ValueError, match="already exists"):
        E.write_pvd(anim, tmp_path / "s.pvd", face=face)


def test_arkit_weights_of_a_planted_jaw_opening(tmp_path):
    jaw = np.linspace(0.0, 1.0, 11)
    anim = procedural_animation(11, 30.0, jaw=jaw, smile=0.0)
    W, err = E.arkit_weights(anim)
    assert W.shape == (11, 52) and len(set(E.ARKIT_NAMES)) == 52
    col = E.ARKIT_NAMES.index("jawOpen")
    np.testing.assert_allclose(W[:, col], jaw, atol=1e-6)
    others = np.delete(W, col, axis=1)
    assert np.abs(others).max() < 1e-6
    assert err.max() < 1e-6
    # a planted smile shows up on both smile shapes, not on the jaw
    smile = procedural_animation(11, 30.0, jaw=0.0, smile=np.linspace(0.0, 1.0, 11))
    Ws, _ = E.arkit_weights(smile)
    for name in ("mouthSmileLeft", "mouthSmileRight"):
        assert np.corrcoef(Ws[:, E.ARKIT_NAMES.index(name)], np.linspace(0, 1, 11))[0, 1] > 0.99
        assert Ws[-1, E.ARKIT_NAMES.index(name)] > 0.8
    assert Ws[:, col].max() < 0.05
    # subject's left vs right, and a negative brow raise as browDown
    base = neutral_landmarks()
    B = R.action_unit_basis(base)[..., :2]
    k = R.ACTION_UNITS.index
    planted = base + 0.7 * B[k("blink_left")] - 0.5 * B[k("brow_raise")] + 0.3 * B[k("smile_right")]
    Wp, errp = E.arkit_weights(Animation(np.stack([base, planted]), 10.0))
    got = {n: w for n, w in zip(E.ARKIT_NAMES, Wp[1]) if w > 1e-6}
    assert got.keys() == {"eyeBlinkLeft", "browDownLeft", "browDownRight", "mouthSmileRight"}
    names = ["eyeBlinkLeft", "browDownLeft", "browDownRight", "mouthSmileRight"]
    np.testing.assert_allclose([got[n] for n in names], [0.7, 0.5, 0.5, 0.3], atol=1e-6)
    assert errp.max() < 1e-9
    # the subject's left eye is on the image's right (larger x)
    assert base[42:48, 0].mean() > base[36:42, 0].mean()
    E.export(anim, tmp_path / "w.csv", "arkit")
    E.export(anim, tmp_path / "w.json", "arkit-json")
    table = np.loadtxt(tmp_path / "w.csv", delimiter=",", skiprows=1)
    assert table.shape == (11, 54)
    doc = json.loads((tmp_path / "w.json").read_text())
    assert doc["names"] == list(E.ARKIT_NAMES)
    assert doc["frames"][-1]["weights"]["jawOpen"] == pytest.approx(1.0, abs=1e-4)


def test_an_animation_moves_from_its_neutral_not_its_first_frame(tmp_path):
    """Audio that begins mid-word gives an animation whose first frame is open: retargeted from
    that frame, a photo at rest would keep its mouth shut there and open by the difference only.
    The animation's ``neutral`` (a puppet's face in silence) is the rest it moves from, and it
    travels in the .npz (not the .csv: frames only, rest = first frame)."""
    from voicepuppet.cli.main import main

    jaw = np.linspace(0.6, 1.0, 9)
    anim = procedural_animation(9, 30.0, jaw=jaw, smile=0.0)
    rest = neutral_landmarks()
    np.testing.assert_allclose(procedural_animation(1, 30.0, jaw=0.0, smile=0.0).points[0], rest, atol=1e-12)
    moved = Animation(anim.points, anim.fps, anim.names, neutral=rest)
    col = E.ARKIT_NAMES.index("jawOpen")
    np.testing.assert_allclose(E.arkit_weights(moved)[0][:, col], jaw, atol=1e-6)
    np.testing.assert_allclose(E.arkit_weights(anim)[0][:, col], jaw - 0.6, atol=1e-6)
    # the photo's mesh on the rest face: its landmark vertices are the animation's points
    face = R.build_face_mesh(R.portrait_image(rest, 320, 320), rest)
    v = R.mesh_animation(moved, face)["vertices"][:, :68, :2]
    np.testing.assert_allclose(v, moved.points, atol=1e-9)
    assert np.abs(R.mesh_animation(anim, face)["vertices"][:, :68, :2] - anim.points).max() > 10
    save_animation(moved, tmp_path / "a.npz")
    np.testing.assert_array_equal(load_animation(tmp_path / "a.npz").neutral, rest)
    assert main(["export", str(tmp_path / "a.npz"), "--format", "arkit", "-o", str(tmp_path / "w.csv")]) == 0
    table = np.loadtxt(tmp_path / "w.csv", delimiter=",", skiprows=1)
    np.testing.assert_allclose(table[:, 2 + col], jaw, atol=1e-4)
    save_animation(moved, tmp_path / "a.csv")
    assert load_animation(tmp_path / "a.csv").neutral is None
    with pytest.raises(ValueError, match=r"neutral must have shape \(68, 2\)"):
        Animation(anim.points, anim.fps, neutral=rest[:10])
    with pytest.raises(ValueError, match="neutral must be finite"):
        Animation(anim.points, anim.fps, neutral=np.full((68, 2), np.nan))


def _mouth(opening_iod, width_ratio, n=10):
    """Frames with the inner lips apart by ``opening_iod`` inter-ocular distances and the mouth
    width scaled by ``width_ratio`` about its centre."""
    base = neutral_landmarks()
    iod = np.linalg.norm(base[36] - base[45])
    frames = []
    for o, r in zip(np.broadcast_to(opening_iod, (n,)), np.broadcast_to(width_ratio, (n,))):
        p = base.copy()
        mc = p[48:68].mean(axis=0)
        p[48:68, 0] = mc[0] + r * (p[48:68, 0] - mc[0])
        p[[65, 66, 67, 55, 56, 57, 58, 59], 1] += o * iod
        frames.append(p)
    return np.stack(frames), base


@pytest.mark.parametrize("opening,ratio,shape", [(0.0, 1.0, "X"), (0.08, 1.0, "B"), (0.2, 1.0, "C"),
                                                 (0.4, 1.0, "D"), (0.08, 0.7, "F"), (0.2, 0.7, "E")])
def test_rhubarb_shapes_of_planted_mouths(opening, ratio, shape):
    pts, base = _mouth(opening, ratio)
    cues = E.mouth_cues(Animation(pts, 25.0), neutral=base)
    assert cues == [{"start": 0.0, "end": 0.4, "value": shape}]


def test_rhubarb_G_is_the_lower_lip_drawn_in_under_the_upper_teeth():
    """G (F, V): a slightly open mouth whose lower lip shows 0.045 IOD less of itself (its inner
    edge drawn up and in); the same opening without that is B. On the synthetic performer's
    articulation (its labiodental gesture tucks the lower lip), /f/ and /v/ give G and the vowels
    and the other consonants do not; ARKit's mouthRollLower is that share of the lip drawn in."""
    from voicepuppet import synth

    pts, base = _mouth(0.06, 1.0)
    iod = np.linalg.norm(base[36] - base[45])
    tucked = pts.copy()
    tucked[:, [56, 57, 58], 1] -= 0.045 * iod  # the lip's outer edge comes up to its inner one
    assert [c["value"] for c in E.mouth_cues(Animation(pts, 25.0), neutral=base)] == ["B"]
    assert [c["value"] for c in E.mouth_cues(Animation(tucked, 25.0), neutral=base)] == ["G"]
    roll = E.ARKIT_NAMES.index("mouthRollLower")
    height = np.linalg.norm(base[57] - base[66])
    np.testing.assert_allclose(E.arkit_weights(Animation(tucked, 25.0), neutral=base)[0][:, roll],
                               0.045 * iod / height, atol=1e-9)
    assert E.arkit_weights(Animation(pts, 25.0), neutral=base)[0][:, roll].max() < 1e-9
    photo = synth.face_photo((320, 320))
    phones = [("_", 0.0, 0.2), ("a", 0.2, 0.45), ("f", 0.45, 0.6), ("o", 0.6, 0.85), ("v", 0.85, 1.0),
              ("i", 1.0, 1.25), ("t", 1.25, 1.35), ("a", 1.35, 1.6), ("_", 1.6, 1.9)]
    rate, fps = 16000, 29.97
    hum = 0.1 * np.sin(2 * np.pi * 140 * np.arange(int(1.9 * rate)) / rate)
    art = synth.articulate(phones, hum, rate, photo.points, fps=fps, seed=3, blinks=False)
    cues = E.mouth_cues(Animation(art.points, fps), neutral=photo.points)
    at = lambda t: next(c["value"] for c in cues if c["start"] <= t < c["end"])  # noqa: E731
    W = E.arkit_weights(Animation(art.points, fps), neutral=photo.points)[0][:, roll]
    for name, a, b in phones[1:-1]:
        assert (at(0.5 * (a + b)) == "G") == (name in "fv"), (name, cues)
        w = W[int(0.5 * (a + b) * fps)]
        assert w > 0.5 if name in "fv" else w < 0.15, (name, w)


def test_rhubarb_short_closure_is_A_and_files(tmp_path):
    opening = np.r_[np.zeros(3), np.full(5, 0.4), np.zeros(2), np.full(5, 0.4), np.zeros(20)]
    pts, base = _mouth(opening, 1.0, n=len(opening))
    anim = Animation(pts, 25.0)
    cues = E.mouth_cues(anim, neutral=base)
    assert [c["value"] for c in cues] == ["X", "D", "A", "D", "X"]
    assert [c["start"] for c in cues] == [0.0, 0.12, 0.32, 0.4, 0.6]
    assert cues[-1]["end"] == pytest.approx(anim.duration, abs=1e-3)
    E.write_rhubarb(anim, tmp_path / "c.json", neutral=base, sound_file="a.wav")
    doc = json.loads((tmp_path / "c.json").read_text())
    assert doc["metadata"] == {"soundFile": "a.wav", "duration": 1.4} and doc["mouthCues"] == cues
    E.write_rhubarb(anim, tmp_path / "c.tsv", neutral=base)
    lines = (tmp_path / "c.tsv").read_text().splitlines()
    assert lines[:3] == ["0.00\tX", "0.12\tD", "0.32\tA"] and lines[-1] == "1.40\tX"


def test_bad_exports_give_clear_errors_and_no_files(tmp_path):
    anim = procedural_animation(4, 10.0)
    with pytest.raises(ValueError, match="unknown export format 'fbx'"):
        E.export(anim, tmp_path / "a.fbx", "fbx")
    with pytest.raises(ValueError, match="cannot tell the export format"):
        E.export(anim, tmp_path / "a.xyz")
    with pytest.raises(ValueError, match=r"writes \.glb files.*name it '.*a\.glb'"):
        E.export(anim, tmp_path / "a.gltf", "gltf")
    with pytest.raises(ValueError, match="does not exist"):
        E.export(anim, tmp_path / "no" / "a.glb")
    with pytest.raises(ValueError, match="68-point layout"):
        E.arkit_weights(Animation(anim.points[:, :30], 10.0))
    with pytest.raises(ValueError, match="does not move"):
        E.write_glb(Animation(np.repeat(anim.points[:1], 3, axis=0), 10.0), tmp_path / "s.glb", mode="vertex")
    assert os.listdir(tmp_path) == []


def test_cli_export(tmp_path):
    from voicepuppet.cli.main import main

    anim = procedural_animation(6, 10.0)
    save_animation(anim, tmp_path / "a.npz")
    assert main(["export", str(tmp_path / "a.npz"), "--format", "rhubarb"]) == 0
    assert (tmp_path / "a_cues.json").is_file()
    assert main(["export", str(tmp_path / "a.npz"), "-o", str(tmp_path / "b.glb")]) == 0
    assert main(["export", str(tmp_path / "a.npz"), "--format", "gltf", "-o", str(tmp_path / "b.csv")]) == 2


def test_failed_writes_leave_nothing(tmp_path, monkeypatch):
    pygltflib = pytest.importorskip("pygltflib")
    anim = procedural_animation(4, 10.0)

    def boom(*args, **kwargs):
        raise OSError("disk full")

    monkeypatch.setattr(pygltflib.GLTF2, "save_binary", boom)
    with pytest.raises(OSError, match="disk full"):
        E.write_glb(anim, tmp_path / "a.glb")
    monkeypatch.setattr(np, "savetxt", boom)
    with pytest.raises(OSError, match="disk full"):
        E.export(anim, tmp_path / "w.csv", "arkit")
    import pyvista as pv

    monkeypatch.setattr(pv.PolyData, "save", boom)
    with pytest.raises(OSError, match="disk full"):
        E.write_pvd(anim, tmp_path / "s.pvd")
    assert os.listdir(tmp_path) == []


def test_outputs_get_the_permissions_of_plainly_created_files(tmp_path, monkeypatch):
    """Atomic writes go through mkstemp/mkdtemp (owner-only); the published files and folders
    must carry the mode open()/mkdir() would give under the process's umask (here 022)."""
    import stat

    from voicepuppet import _files

    monkeypatch.setattr(_files, "_UMASK", 0o022)
    anim = procedural_animation(4, 10.0)
    save_animation(anim, tmp_path / "a.npz")
    save_animation(anim, tmp_path / "a.csv")
    E.export(anim, tmp_path / "w.csv", "arkit")
    E.write_pvd(anim, tmp_path / "s.pvd")

    def mode(name):
        return stat.S_IMODE(os.stat(tmp_path / name).st_mode)

    for name in ("a.npz", "a.csv", "w.csv", "s.pvd"):
        assert mode(name) == 0o644, name
    assert mode("s_frames") == 0o755
