"""Interchange formats for landmark animations: landmarks (csv, npz), a VTK time series (.pvd)
for ParaView, an animated glTF 2.0 binary (.glb) for Blender and three.js, ARKit-named
blendshape weights (csv, json) and Rhubarb Lip Sync mouth cues (json, tsv).

Every writer goes through a temporary file and a rename (:func:`voicepuppet._files.atomic_path`),
so a failed export leaves nothing behind.
"""

from __future__ import annotations

import json
import shutil
import tempfile
from io import BytesIO
from pathlib import Path
from typing import Optional

import numpy as np

from voicepuppet import layout as face_layout
from voicepuppet._files import atomic_path, check_output_path, publish
from voicepuppet.animation import Animation, save_animation
from voicepuppet.render._backend import import_pyvista
from voicepuppet.render.mesh import FaceMesh
from voicepuppet.render.photo import build_face_mesh, portrait_image
from voicepuppet.render.retargeting import ACTION_UNITS, action_unit_basis, fit_activations, mesh_animation

__all__ = ["FORMATS", "ARKIT_NAMES", "arkit_weights", "mouth_cues", "write_arkit", "write_rhubarb",
           "write_pvd", "write_glb", "export", "default_face"]

#: format name -> file suffix
FORMATS = {"csv": ".csv", "npz": ".npz", "pvd": ".pvd", "gltf": ".glb", "arkit": ".csv",
           "arkit-json": ".json", "rhubarb": ".json", "rhubarb-tsv": ".tsv"}

#: Apple ARKit's 52 blendshape locations (ARFaceAnchor.BlendShapeLocation), in Apple's order
ARKIT_NAMES = (
    "eyeBlinkLeft", "eyeLookDownLeft", "eyeLookInLeft", "eyeLookOutLeft", "eyeLookUpLeft", "eyeSquintLeft",
    "eyeWideLeft", "eyeBlinkRight", "eyeLookDownRight", "eyeLookInRight", "eyeLookOutRight", "eyeLookUpRight",
    "eyeSquintRight", "eyeWideRight", "jawForward", "jawLeft", "jawRight", "jawOpen", "mouthClose",
    "mouthFunnel", "mouthPucker", "mouthLeft", "mouthRight", "mouthSmileLeft", "mouthSmileRight",
    "mouthFrownLeft", "mouthFrownRight", "mouthDimpleLeft", "mouthDimpleRight", "mouthStretchLeft",
    "mouthStretchRight", "mouthRollLower", "mouthRollUpper", "mouthShrugLower", "mouthShrugUpper",
    "mouthPressLeft", "mouthPressRight", "mouthLowerDownLeft", "mouthLowerDownRight", "mouthUpperUpLeft",
    "mouthUpperUpRight", "browDownLeft", "browDownRight", "browInnerUp", "browOuterUpLeft",
    "browOuterUpRight", "cheekPuff", "cheekSquintLeft", "cheekSquintRight", "noseSneerLeft",
    "noseSneerRight", "tongueOut",
)

# action unit -> ARKit shapes driven by its positive (and negative) activation
_AU_TO_ARKIT = {
    "jaw_open": (("jawOpen",), ()),
    "smile_right": (("mouthSmileRight",), ()),
    "smile_left": (("mouthSmileLeft",), ()),
    "pucker": (("mouthPucker",), ()),
    "lip_press": (("mouthPressLeft", "mouthPressRight"), ()),
    "upper_lip_raise": (("mouthUpperUpLeft", "mouthUpperUpRight"), ()),
    "brow_raise": (("browInnerUp", "browOuterUpLeft", "browOuterUpRight"), ("browDownLeft", "browDownRight")),
    "blink_right": (("eyeBlinkRight",), ()),
    "blink_left": (("eyeBlinkLeft",), ()),
}


def _rest(anim: Animation, neutral) -> np.ndarray:
    if neutral is None:
        return anim.rest
    ref = np.asarray(neutral, dtype=np.float64)
    if ref.shape != (anim.n_points, 2):
        raise ValueError(f"neutral must have shape ({anim.n_points}, 2), got {ref.shape}")
    return ref


def _require_68(anim: Animation, what: str) -> None:
    if anim.n_points != face_layout.N_POINTS:
        raise ValueError(f"{what} needs the 68-point layout (voicepuppet.layout), got {anim.n_points} points "
                         "per frame")


# --------------------------------------------------------------------------- ARKit weights

def arkit_weights(anim: Animation, neutral=None) -> tuple[np.ndarray, np.ndarray]:
    """Blendshape weights in ARKit's 52 names from the action-unit activations.

    Activations are fitted per frame by bounded least squares (``[0, 1]``; brows ``[-1, 1]``,
    negative lowering them) on the animation's own neutral face. ``mouthRollLower`` is the share
    of the lower lip's height (66 to 57) drawn in beyond what the fitted units explain (the
    labiodental tuck of /f v/, :func:`mouth_measures`); the other shapes the basis cannot
    express stay zero.

    Parameters
    ----------
    anim : Animation
        68 points per frame.
    neutral : ndarray, shape (68, 2), optional
        the rest face the motion is measured from (default: :attr:`Animation.rest`).

    Returns
    -------
    weights : ndarray, shape (T, 52)
        in [0, 1], columns in the order of :data:`ARKIT_NAMES`.
    rms_error : ndarray, shape (T,)
        the landmark motion the units do not explain, in inter-ocular distances.

    Raises
    ------
    ValueError
        the animation is not in the 68-point layout, or ``neutral`` has another shape.
    """
    _require_68(anim, "ARKit weights")
    ref = _rest(anim, neutral)
    B = action_unit_basis(ref)
    lo = np.zeros(len(ACTION_UNITS))
    lo[ACTION_UNITS.index("brow_raise")] = -1.0
    act, err = fit_activations(anim.points - ref, B, bounds=(lo, np.ones(len(ACTION_UNITS))))
    W = np.zeros((anim.n_frames, len(ARKIT_NAMES)))
    col = {n: i for i, n in enumerate(ARKIT_NAMES)}
    for k, au in enumerate(ACTION_UNITS):
        pos, neg = _AU_TO_ARKIT[au]
        for n in pos:
            W[:, col[n]] = np.clip(act[:, k], 0.0, 1.0)
        for n in neg:
            W[:, col[n]] = np.clip(-act[:, k], 0.0, 1.0)
    fitted = ref + np.einsum("tk,kpc->tpc", act, B[..., :2])
    roll = (_lower_lip_height(fitted) - _lower_lip_height(anim.points)) / _lower_lip_height(ref)
    W[:, col["mouthRollLower"]] = np.clip(roll, 0.0, 1.0)
    return W, err / float(face_layout.inter_ocular_distance(ref))


def write_arkit(anim: Animation, path, neutral=None) -> Path:
    """Writes ARKit weights (:func:`arkit_weights`) as ``.csv`` (``frame,time,<52 names>``) or
    ``.json`` (``{"fps", "names", "frames": [{"time", "weights": {name: w}}]}``), atomically.

    Parameters
    ----------
    anim : Animation
        68 points per frame.
    path : str or path-like
        ``.csv`` or ``.json``.
    neutral : ndarray, shape (68, 2), optional
        the rest face the motion is measured from (default: :attr:`Animation.rest`).

    Returns
    -------
    Path
        ``path``.

    Raises
    ------
    ValueError
        another suffix, or the errors of :func:`arkit_weights`.
    """
    W, _ = arkit_weights(anim, neutral)
    with atomic_path(path, (".csv", ".json"), "ARKit weights file") as tmp:
        if tmp.suffix == ".csv":
            table = np.column_stack([np.arange(anim.n_frames), anim.times, W])
            np.savetxt(tmp, table, fmt=["%d", "%.6f"] + ["%.5f"] * W.shape[1], delimiter=",",
                       header="frame,time," + ",".join(ARKIT_NAMES), comments="")
        else:
            doc = {"fps": anim.fps, "names": list(ARKIT_NAMES),
                   "frames": [{"time": round(float(t), 6),
                               "weights": {n: round(float(w), 5) for n, w in zip(ARKIT_NAMES, row)}}
                              for t, row in zip(anim.times, W)]}
            tmp.write_text(json.dumps(doc), encoding="utf-8")
    return Path(path)


# --------------------------------------------------------------------------- Rhubarb cues

def _lower_lip_height(points: np.ndarray) -> np.ndarray:
    """The lower lip's height in its middle, inner (66) to outer (57) edge, of (..., 68, 2) points."""
    return np.linalg.norm(points[..., 57, :] - points[..., 66, :], axis=-1)


def mouth_measures(anim: Animation, neutral=None) -> dict:
    """Per-frame mouth opening (inner lip gap), width (inner corners) and their ratio to the
    neutral width, and the change of the lower lip's height (its middle, 66 to 57) from the
    neutral's, in inter-ocular distances of the neutral face.

    Parameters
    ----------
    anim : Animation
        68 points per frame.
    neutral : ndarray, shape (68, 2), optional
        the rest face the motion is measured from (default: :attr:`Animation.rest`).

    Returns
    -------
    dict
        ``opening``, ``width``, ``width_ratio``, ``lower_lip``: (T,) arrays.

    Raises
    ------
    ValueError
        the animation is not in the 68-point layout, or ``neutral`` has another shape.
    """
    _require_68(anim, "mouth measures")
    ref = _rest(anim, neutral)
    iod = float(face_layout.inter_ocular_distance(ref))
    p = anim.points
    gap = np.mean(np.linalg.norm(p[:, [61, 62, 63]] - p[:, [67, 66, 65]], axis=2), axis=1) / iod
    width = np.linalg.norm(p[:, 64] - p[:, 60], axis=1) / iod
    width0 = np.linalg.norm(ref[64] - ref[60]) / iod
    lower = (_lower_lip_height(p) - _lower_lip_height(ref)) / iod
    return {"opening": gap, "width": width, "width_ratio": width / width0, "lower_lip": lower}


def mouth_cues(anim: Animation, neutral=None, *, closed: float = 0.04, slight: float = 0.12, open_: float = 0.28,
               rounded: float = 0.85, tucked: float = -0.03, rest_seconds: float = 0.4) -> list[dict]:
    """Rhubarb Lip Sync mouth shapes from lip geometry.

    Shapes (Rhubarb's): A closed (M, B, P); B slightly open, teeth together; C open; D wide
    open; E slightly rounded; F puckered; G upper teeth on the lower lip (F, V); X rest. Per
    frame, with opening ``o``, width ratio ``r`` and lower-lip height change ``h`` of
    :func:`mouth_measures`: ``o < closed`` → A (X when the closure lasts at least
    ``rest_seconds`` or touches the start or end); ``h < tucked`` (the lower lip drawn in under
    the upper teeth shows less of itself) and ``o < slight`` → G; ``r < rounded`` → F if
    ``o < slight`` else E; otherwise B, C or D by ``o`` against ``slight`` and ``open_``. H (the
    tongue) is not visible in lip landmarks and is never emitted (Rhubarb's extended shapes are
    optional).

    Parameters
    ----------
    anim : Animation
        68 points per frame.
    neutral : ndarray, shape (68, 2), optional
        the rest face the motion is measured from (default: :attr:`Animation.rest`).
    closed, slight, open_ : float
        opening thresholds, inter-ocular distances.
    rounded : float
        width ratio below which the lips are rounded.
    tucked : float
        lower-lip height change (inter-ocular distances) below which the lip is tucked.
    rest_seconds : float
        a closure at least this long is rest (X).

    Returns
    -------
    list of dict
        ``{"start", "end", "value"}`` in seconds, consecutive, covering the animation.

    Raises
    ------
    ValueError
        the animation is not in the 68-point layout, or ``neutral`` has another shape.
    """
    m = mouth_measures(anim, neutral)
    o, r, h = m["opening"], m["width_ratio"], m["lower_lip"]
    shape = np.where(r < rounded, np.where(o < slight, "F", "E"),
                     np.where(o < slight, "B", np.where(o < open_, "C", "D")))
    shape = np.where(o < closed, "A", np.where((h < tucked) & (o < slight), "G", shape))
    T = anim.n_frames
    runs = []
    start = 0
    for t in range(1, T + 1):
        if t == T or shape[t] != shape[start]:
            runs.append([start, t, str(shape[start])])
            start = t
    for run in runs:
        if run[2] == "A" and (run[0] == 0 or run[1] == T or (run[1] - run[0]) / anim.fps >= rest_seconds):
            run[2] = "X"
    merged = []
    for run in runs:
        if merged and merged[-1][2] == run[2]:
            merged[-1][1] = run[1]
        else:
            merged.append(run)
    return [{"start": round(a / anim.fps, 3), "end": round(b / anim.fps, 3), "value": v} for a, b, v in merged]


def write_rhubarb(anim: Animation, path, neutral=None, sound_file: str = "") -> Path:
    """Writes mouth cues (:func:`mouth_cues`) as Rhubarb's ``.json`` (``{"metadata": {"soundFile",
    "duration"}, "mouthCues": [...]}``) or ``.tsv`` (``start<TAB>shape`` lines, the last one the
    end), atomically.

    Parameters
    ----------
    anim : Animation
        68 points per frame.
    path : str or path-like
        ``.json`` or ``.tsv``.
    neutral : ndarray, shape (68, 2), optional
        the rest face the motion is measured from (default: :attr:`Animation.rest`).
    sound_file : str
        the sound's name recorded in the ``.json``'s metadata.

    Returns
    -------
    Path
        ``path``.

    Raises
    ------
    ValueError
        another suffix, or the errors of :func:`mouth_cues`.
    """
    cues = mouth_cues(anim, neutral)
    with atomic_path(path, (".json", ".tsv"), "mouth cues file") as tmp:
        if tmp.suffix == ".json":
            doc = {"metadata": {"soundFile": sound_file, "duration": round(anim.duration, 3)}, "mouthCues": cues}
            tmp.write_text(json.dumps(doc, indent=2) + "\n", encoding="utf-8")
        else:
            lines = [f"{c['start']:.2f}\t{c['value']}" for c in cues]
            lines.append(f"{cues[-1]['end']:.2f}\tX")
            tmp.write_text("\n".join(lines) + "\n", encoding="utf-8")
    return Path(path)


# --------------------------------------------------------------------------- meshes

def default_face(anim: Animation, neutral=None) -> FaceMesh:
    """The drawn-portrait face mesh on the animation's neutral frame (68-point layout).

    Parameters
    ----------
    anim : Animation
        68 points per frame.
    neutral : ndarray, shape (68, 2), optional
        the rest face the motion is measured from (default: :attr:`Animation.rest`).

    Returns
    -------
    FaceMesh
        a mesh on :func:`voicepuppet.render.photo.portrait_image`.

    Raises
    ------
    ValueError
        the animation is not in the 68-point layout.
    """
    _require_68(anim, "a face mesh without a photo")
    first = _rest(anim, neutral)
    lo, hi = first.min(axis=0), first.max(axis=0)
    margin = 0.45 * (hi - lo).max()
    shift = lo - margin
    W, H = int(hi[0] - lo[0] + 2 * margin) + 1, int(hi[1] - lo[1] + 2 * margin) + 1
    return build_face_mesh(portrait_image(first - shift, W, H), first - shift)


def write_pvd(anim: Animation, path, face: Optional[FaceMesh] = None, mode: str = "vertex", neutral=None) -> Path:
    """A VTK time series for ParaView: ``NAME.pvd`` listing ``NAME_frames/frame_000000.vtp``
    (the mesh per frame, with texture coordinates, ``mouth`` and ``teeth`` cell flags and the
    flat ``colour`` of those cells, RGB; times in seconds)
    and the photo as ``NAME_frames/texture.png``. Both the folder and the collection are
    written to temporary names and renamed into place.

    Parameters
    ----------
    anim : Animation
        the animation to export.
    path : str or path-like
        ``NAME.pvd``.
    face : FaceMesh, optional
        the face to drive (default: :func:`default_face`).
    mode : {"vertex", "au"}
        how landmark motion drives the mesh (:func:`voicepuppet.render.retargeting.mesh_animation`).
    neutral : ndarray, shape (P, 2), optional
        the rest face the motion is measured from (default: :attr:`Animation.rest`).

    Returns
    -------
    Path
        ``path``.

    Raises
    ------
    ValueError
        the output or its frames' folder exists, pyvista is missing, or the errors of
        :func:`voicepuppet.render.retargeting.mesh_animation`.
    """
    pv = import_pyvista()
    p = check_output_path(path, (".pvd",), "VTK series")
    face = default_face(anim, neutral) if face is None else face
    verts = mesh_animation(anim, face, mode=mode, neutral=neutral)["vertices"]
    folder = p.with_name(p.stem + "_frames")
    if folder.exists():
        raise ValueError(f"{str(folder)!r} already exists; remove it or choose another output name")
    tmpdir = Path(tempfile.mkdtemp(prefix=f".{folder.name}.", suffix=".partial", dir=p.parent))
    try:
        from PIL import Image

        Image.fromarray(face.image).save(tmpdir / "texture.png")
        cells = np.hstack([np.full((len(face.faces), 1), 3), face.faces])
        entries = []
        for t in range(anim.n_frames):
            mesh = pv.PolyData(verts[t], cells)
            mesh.active_texture_coordinates = face.uv.astype(np.float32)
            mesh.cell_data["mouth"] = face.mouth.astype(np.uint8)
            mesh.cell_data["teeth"] = face.teeth.astype(np.uint8)
            mesh.cell_data["colour"] = face.colours
            name = f"frame_{t:06d}.vtp"
            mesh.save(tmpdir / name)
            entries.append(f'    <DataSet timestep="{t / anim.fps:.9g}" group="" part="0" '
                           f'file="{folder.name}/{name}"/>')
        xml = ('<?xml version="1.0"?>\n<VTKFile type="Collection" version="0.1" byte_order="LittleEndian">\n'
               "  <Collection>\n" + "\n".join(entries) + "\n  </Collection>\n</VTKFile>\n")
        with atomic_path(p, (".pvd",), "VTK series") as tmp:
            publish(tmpdir, folder)
            try:
                tmp.write_text(xml, encoding="utf-8")
            except BaseException:
                shutil.rmtree(folder, ignore_errors=True)
                raise
    finally:
        if tmpdir.exists():
            shutil.rmtree(tmpdir)
    return p


def _gltf_frame(face: FaceMesh, scale: float):
    """Image pixels -> glTF metres (y up, z towards the viewer), centred on the landmarks."""
    centre = np.r_[face.landmarks.mean(axis=0), 0.0]

    def to_gltf(v):
        out = (np.asarray(v) - centre) * scale
        out[..., 1] = -out[..., 1]
        return out

    return to_gltf


def write_glb(anim: Animation, path, face: Optional[FaceMesh] = None, mode: str = "au", neutral=None,
              max_targets: int = 32, face_width_m: float = 0.065) -> dict:
    """An animated glTF 2.0 binary: the face mesh with morph targets and one animation of their
    weights (linear interpolation, one key per frame, times ``t / fps``).

    ``mode="au"``: the morph targets are the action units (:data:`~voicepuppet.render.retargeting.ACTION_UNITS`,
    named in the mesh's ``extras.targetNames``) and the weights their least-squares activations.
    ``mode="vertex"``: the targets are the principal components of the per-frame vertex
    displacements (at most ``max_targets``), so the vertex motion is reproduced up to that rank.
    Units are metres, scaled so the inter-ocular distance is ``face_width_m``; the photo is
    embedded as the (unlit) base colour texture; the mouth's interior behind the lips (cavity,
    tongue, teeth) is a second primitive in vertex colours.

    Parameters
    ----------
    anim : Animation
        the animation to export.
    path : str or path-like
        ``.glb``.
    face : FaceMesh, optional
        the face to drive (default: :func:`default_face`).
    mode : {"au", "vertex"}
        the morph targets: action units or principal components.
    neutral : ndarray, shape (P, 2), optional
        the rest face the motion is measured from (default: :attr:`Animation.rest`).
    max_targets : int
        at most this many principal components (``mode="vertex"``).
    face_width_m : float
        the inter-ocular distance in metres.

    Returns
    -------
    dict
        ``targets``, ``frames``, ``duration``, ``max_error_m`` (the largest difference between
        the morph-target reconstruction and the driven mesh, in metres); with ``mode="au"`` also
        ``au_rms_error_iod`` (the landmark motion the basis cannot express, mean RMS per
        coordinate in inter-ocular distances).

    Raises
    ------
    ValueError
        pygltflib is missing, the output exists or is not ``.glb``, an unknown ``mode``, an
        animation that does not move (``mode="vertex"``), or the errors of
        :func:`voicepuppet.render.retargeting.mesh_animation`.
    """
    try:
        import pygltflib as g
    except ImportError:
        raise ValueError("writing .glb needs pygltflib: pip install pygltflib") from None
    from PIL import Image

    check_output_path(path, (".glb",), "glTF file")
    face = default_face(anim, neutral) if face is None else face
    if mode == "au":
        res = mesh_animation(anim, face, mode="au", neutral=neutral)
        targets, weights, names = res["targets"], res["activations"], list(ACTION_UNITS)
        verts = res["vertices"]
    elif mode == "vertex":
        verts = mesh_animation(anim, face, mode="vertex", neutral=neutral)["vertices"]
        D = (verts - face.vertices[None]).reshape(anim.n_frames, -1)
        u, s, vt = np.linalg.svd(D, full_matrices=False)
        keep = s > s[0] * 1e-9 if s.size and s[0] > 0 else np.zeros(0, bool)
        k = int(min(max_targets, keep.sum()))
        if k == 0:
            raise ValueError("the animation does not move; nothing to animate in glTF")
        targets = vt[:k].reshape(k, len(face.vertices), 3)
        weights = u[:, :k] * s[:k]
        names = [f"component_{i}" for i in range(k)]
    else:
        raise ValueError(f"mode must be 'au' or 'vertex', got {mode!r}")
    iod = float(np.linalg.norm(face.landmarks[36] - face.landmarks[45])) if face.n_landmarks == 68 else \
        float(np.ptp(face.landmarks[:, 0]))
    scale = face_width_m / iod
    to_gltf = _gltf_frame(face, scale)
    base = to_gltf(face.vertices).astype(np.float32)
    tg = np.stack([to_gltf(face.vertices + t) - to_gltf(face.vertices) for t in targets]).astype(np.float32)
    recon = base[None] + np.einsum("tk,kvc->tvc", weights, tg.astype(np.float64))
    max_err = float(np.max(np.abs(recon - to_gltf(verts)))) if len(verts) else 0.0

    blob = bytearray()
    views, accessors = [], []

    def add(arr: np.ndarray, component: int, kind: str, target: Optional[int] = None, minmax: bool = False) -> int:
        while len(blob) % 4:
            blob.append(0)
        data = np.ascontiguousarray(arr).tobytes()
        views.append(g.BufferView(buffer=0, byteOffset=len(blob), byteLength=len(data), target=target))
        blob.extend(data)
        flat = arr.reshape(len(arr), -1)
        acc = g.Accessor(bufferView=len(views) - 1, componentType=component, count=len(arr), type=kind)
        if minmax:
            acc.min = flat.min(axis=0).astype(float).tolist()
            acc.max = flat.max(axis=0).astype(float).tolist()
        accessors.append(acc)
        return len(accessors) - 1

    pos = add(base, g.FLOAT, g.VEC3, g.ARRAY_BUFFER, minmax=True)
    uv = face.uv.copy()
    uv[:, 1] = 1.0 - uv[:, 1]  # glTF texture v runs down the image
    tex = add(uv.astype(np.float32), g.FLOAT, g.VEC2, g.ARRAY_BUFFER)
    target_acc = [add(t, g.FLOAT, g.VEC3, g.ARRAY_BUFFER, minmax=True) for t in tg]
    skin_idx = add(face.faces[~face.flat].astype(np.uint32).reshape(-1), g.UNSIGNED_INT, g.SCALAR,
                   g.ELEMENT_ARRAY_BUFFER, minmax=True)
    times = add((np.arange(anim.n_frames) / anim.fps).astype(np.float32), g.FLOAT, g.SCALAR, minmax=True)
    wts = add(weights.astype(np.float32).reshape(-1), g.FLOAT, g.SCALAR)
    png = BytesIO()
    Image.fromarray(face.image).save(png, format="PNG")
    while len(blob) % 4:
        blob.append(0)
    views.append(g.BufferView(buffer=0, byteOffset=len(blob), byteLength=len(png.getvalue())))
    blob.extend(png.getvalue())
    image_view = len(views) - 1
    attrs_targets = [{"POSITION": a} for a in target_acc]
    primitives = [g.Primitive(attributes=g.Attributes(POSITION=pos, TEXCOORD_0=tex), indices=skin_idx, material=0,
                              targets=attrs_targets)]
    materials = [g.Material(name="face", pbrMetallicRoughness=g.PbrMetallicRoughness(
        baseColorTexture=g.TextureInfo(index=0), metallicFactor=0.0, roughnessFactor=1.0),
        extensions={"KHR_materials_unlit": {}}, doubleSided=True)]
    if face.flat.any():  # the mouth's interior, in its colours (each vertex in one of its faces' colour)
        vc = np.zeros((len(face.vertices), 3), np.float32)
        vc[face.faces[face.flat]] = face.colours[face.flat][:, None] / 255.0
        colour = add(vc, g.FLOAT, g.VEC3, g.ARRAY_BUFFER)
        flat_idx = add(face.faces[face.flat].astype(np.uint32).reshape(-1), g.UNSIGNED_INT, g.SCALAR,
                       g.ELEMENT_ARRAY_BUFFER, minmax=True)
        primitives.append(g.Primitive(attributes=g.Attributes(POSITION=pos, COLOR_0=colour), indices=flat_idx,
                                      material=1, targets=attrs_targets))
        materials.append(g.Material(name="mouth", pbrMetallicRoughness=g.PbrMetallicRoughness(
            baseColorFactor=[1.0, 1.0, 1.0, 1.0], metallicFactor=0.0, roughnessFactor=1.0),
            extensions={"KHR_materials_unlit": {}}, doubleSided=True))
    gltf = g.GLTF2(
        asset=g.Asset(version="2.0", generator="voicepuppet"),
        extensionsUsed=["KHR_materials_unlit"],
        scene=0, scenes=[g.Scene(nodes=[0])],
        nodes=[g.Node(mesh=0, name="face")],
        meshes=[g.Mesh(name="face", primitives=primitives, weights=[0.0] * len(names),
                       extras={"targetNames": names})],
        materials=materials,
        images=[g.Image(bufferView=image_view, mimeType="image/png")],
        samplers=[g.Sampler(magFilter=g.LINEAR, minFilter=g.LINEAR)],
        textures=[g.Texture(source=0, sampler=0)],
        animations=[g.Animation(name="voicepuppet", samplers=[g.AnimationSampler(input=times, output=wts,
                                                                                 interpolation="LINEAR")],
                                channels=[g.AnimationChannel(
                                    sampler=0, target=g.AnimationChannelTarget(node=0, path="weights"))])],
        accessors=accessors, bufferViews=views, buffers=[g.Buffer(byteLength=len(blob))],
    )
    gltf.set_binary_blob(bytes(blob))
    with atomic_path(path, (".glb",), "glTF file") as tmp:
        gltf.save_binary(str(tmp))
    summary = {"targets": len(names), "frames": anim.n_frames, "duration": anim.duration, "max_error_m": max_err}
    if mode == "au":
        summary["au_rms_error_iod"] = float(np.mean(res["rms_error"])) / iod
    return summary


# --------------------------------------------------------------------------- dispatch

def export(anim: Animation, path, fmt: Optional[str] = None, *, face: Optional[FaceMesh] = None,
           mode: Optional[str] = None, neutral=None, sound_file: str = "", report=None) -> Path:
    """Writes ``anim`` in one of the formats of :data:`FORMATS`.

    Parameters
    ----------
    anim : Animation
        the animation to export.
    path : str or path-like
        the output; its suffix must be the format's.
    fmt : str, optional
        a key of :data:`FORMATS`; default: from the suffix, ``.json`` meaning Rhubarb cues and
        ``.csv`` landmarks.
    face : FaceMesh, optional
        the face of ``pvd`` and ``gltf`` (default: :func:`default_face`).
    mode : {"vertex", "au"}, optional
        mesh driving (default: ``vertex`` for ``pvd``, ``au`` for ``gltf``).
    neutral : ndarray, shape (P, 2), optional
        the rest face the motion is measured from (default: :attr:`Animation.rest`).
    sound_file : str
        the sound's name recorded in Rhubarb ``.json`` metadata.
    report : callable, optional
        called with the summary of :func:`write_glb` for the glTF format.

    Returns
    -------
    Path
        ``path``.

    Raises
    ------
    ValueError
        an unknown format, a format the suffix does not match, or the writer's errors.
    """
    p = Path(path)
    if fmt is None:
        by_suffix = {".csv": "csv", ".npz": "npz", ".pvd": "pvd", ".glb": "gltf", ".json": "rhubarb",
                     ".tsv": "rhubarb-tsv"}
        fmt = by_suffix.get(p.suffix.lower())
        if fmt is None:
            raise ValueError(f"cannot tell the export format from {str(p)!r}; pass one of {', '.join(FORMATS)}")
    if fmt not in FORMATS:
        raise ValueError(f"unknown export format {fmt!r}; use one of {', '.join(FORMATS)}")
    if p.suffix.lower() != FORMATS[fmt]:
        raise ValueError(f"format {fmt!r} writes {FORMATS[fmt]} files, but the output is {str(p)!r}; "
                         f"name it {str(p.with_suffix(FORMATS[fmt]))!r}")
    if fmt in ("csv", "npz"):
        return save_animation(anim, p)
    if fmt in ("arkit", "arkit-json"):
        return write_arkit(anim, p, neutral)
    if fmt in ("rhubarb", "rhubarb-tsv"):
        return write_rhubarb(anim, p, neutral, sound_file)
    if fmt == "pvd":
        return write_pvd(anim, p, face, mode or "vertex", neutral)
    summary = write_glb(anim, p, face, mode or "au", neutral)
    if report is not None:
        report(summary)
    return p
