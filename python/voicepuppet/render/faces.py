"""The face to render on, from the command line's ``--face``: a photo, a video, a 3-D head or a
palette's name (Brand §6: the animator picks a face).

:func:`resolve_face` turns ``--face`` (and ``--face-points``, ``--palette``) into a
:class:`voicepuppet.render.mesh.FaceMesh`: a photo's mesh (:func:`voicepuppet.render.photo.build_face_mesh`)
with its points given or detected (dlib), a video's frame nearest the animation's rest face
(looked for among its first :data:`REST_SCAN_S` seconds), or a textured 3-D head
(:func:`voicepuppet.render.head.load_head`).
"""

from __future__ import annotations

import itertools
import warnings
from pathlib import Path

import numpy as np
from tqdm.auto import tqdm

from voicepuppet import layout as face_layout
from voicepuppet.animation import load_animation
from voicepuppet.face import shape_distance
from voicepuppet.render.head import HEAD_SUFFIXES, load_head
from voicepuppet.render.mesh import FaceMesh
from voicepuppet.render.photo import OPEN_MOUTH_IOD, build_face_mesh, lip_gap_iod
from voicepuppet.tracking import PROBE_MAX_PIXELS, NoFaceError, auto_init, first_face, load_init_points
from voicepuppet.tracking import video as tracking_video

__all__ = ["REST_STRIDE_S", "REST_SCAN_S", "load_face", "face_palette", "resolve_face"]

#: ``--face VIDEO`` with the animation's rest face: the video's frames looked at for the face
#: at rest, one every REST_STRIDE_S seconds over its first REST_SCAN_S (dlib on each: ~10 ms a
#: 320x320 frame).
REST_STRIDE_S = 0.5
REST_SCAN_S = 30.0


def load_face(image_path, points_path=None, rest=None, progress: bool = False) -> FaceMesh:
    """A face mesh from a photo file, or a video (the puppet's own, say), and its points: JSON
    ``{"points": [[x, y], ...]}``, CSV ``x,y`` rows, or an animation or landmarks ``.npz`` (its
    first frame; for a video, its frames). Without points, the 68 landmarks are detected (dlib,
    see :func:`voicepuppet.tracking.detect.auto_init`) on the photo.

    A video gives one of its frames. With ``rest`` (P, 2), the rest face the animation moves
    from (:attr:`voicepuppet.animation.Animation.rest`), it is the frame whose face is nearest
    it (:func:`voicepuppet.face.shape_distance`), so the photo is the face at rest whatever the
    video begins with: among the frames of a landmarks ``.npz``, or without points among those
    dlib finds a face on, one every :data:`REST_STRIDE_S` s over the first :data:`REST_SCAN_S`
    s. Without ``rest``: the first frame with a face (:func:`voicepuppet.tracking.detect.first_face`),
    or with points the first frame.

    A textured 3-D head (``.obj``), with its 68 points in 3-D or without (detected on its front
    view), gives :func:`voicepuppet.render.head.load_head`.

    Parameters
    ----------
    image_path : str or path-like
        a picture, a video or a textured ``.obj`` head.
    points_path : str or path-like, optional
        the face's points (JSON, CSV, ``.npz``; a head's in 3-D: JSON or menpo ``.ljson``);
        None: detected.
    rest : ndarray, shape (P, 2), optional
        the animation's rest face, to pick a video's frame by.
    progress : bool
        show progress while a video is searched or a head's points are found.

    Returns
    -------
    FaceMesh

    Raises
    ------
    ValueError
        the file is missing or neither a picture, a video nor a head; no face is found; the
        points do not fit the picture.
    """
    from PIL import Image, UnidentifiedImageError

    ip = Path(image_path)
    if not ip.is_file():
        raise ValueError(f"face image {str(ip)!r} does not exist")
    if ip.suffix.lower() in HEAD_SUFFIXES:
        return load_head(ip, points_path, progress=progress)
    given = None if points_path is None else _face_points(points_path)
    try:
        with Image.open(ip) as im:
            img = np.asarray(im.convert("RGB"))
    except (UnidentifiedImageError, OSError) as exc:
        img, pts = _video_face(ip, given, rest, why=exc, progress=progress)
        return build_face_mesh(img, pts)
    if given is None:
        import cv2

        try:
            return build_face_mesh(img, auto_init(cv2.cvtColor(img, cv2.COLOR_RGB2GRAY),
                                                  instead="--face-points points.json"))
        except NoFaceError:
            raise ValueError(f"no face found in the photo {str(ip)!r} (dlib's detector: a frontal, upright, "
                             "lit face); pass its 68 landmarks with --face-points points.json") from None
    return build_face_mesh(img, given[0])


def _face_points(path) -> np.ndarray:
    """The points of ``--face-points``: (N, P, 2), the frames of an ``.npz``, else one frame."""
    pp = Path(path)
    if pp.suffix.lower() == ".npz":
        return load_animation(pp).points
    return load_init_points(pp)[0][None]


def _video_face(path: Path, given: np.ndarray | None, rest, why: Exception,
                progress: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """(RGB frame, its points) of the video ``path`` for :func:`load_face`: ``given`` points
    (N, P, 2) or dlib's, the frame nearest ``rest`` or the first (with a face). ``why`` is the
    picture reader's refusal, reported when ``path`` is no video either."""
    import cv2

    try:
        info = tracking_video.probe_video(path)
        first = tracking_video.frame_at(path, 0, grey=False)
    except ValueError:
        raise ValueError(f"face image {str(path)!r} is neither a readable picture ({why}) nor a video "
                         "OpenCV can open; give a .png / .jpg photo or an .mp4 video of the face") from None
    if first is None:
        raise ValueError(f"face video {str(path)!r} holds no decodable frames; give a photo or another video")
    fps = info.fps or 29.97
    if given is not None:
        k = 0
        if rest is not None and len(given) > 1 and given.shape[1] == len(rest):
            k = int(np.argmin(shape_distance(given, rest)))
        frame = first if k == 0 else tracking_video.frame_at(path, k, grey=False)
        if frame is None:
            raise ValueError(f"face video {str(path)!r} has fewer frames than its --face-points ({k + 1} needed); "
                             "give the video's own landmarks")
        return cv2.cvtColor(frame, cv2.COLOR_BGR2RGB), given[k]
    try:
        t, frame, pts = first_face(path, first, fps, grey=False)
    except NoFaceError as exc:
        raise ValueError(f"face video: {exc}; pass a photo with --face, or the first frame's 68 landmarks "
                         "with --face-points") from None
    if rest is not None and len(rest) == len(pts):
        frame, pts = _rest_frame(path, fps, rest, (frame, pts), start=t, progress=progress)
    return cv2.cvtColor(frame, cv2.COLOR_BGR2RGB), pts


def _rest_frame(path: Path, fps: float, rest, found, start: int, progress: bool = False):
    """The (BGR frame, dlib points) nearest ``rest`` among ``found`` (the first face, at frame
    ``start``) and the probes after it, one every :data:`REST_STRIDE_S` s up to
    :data:`REST_SCAN_S` s."""
    import cv2

    stride = max(1, int(round(REST_STRIDE_S * fps)))
    last = int(REST_SCAN_S * fps)
    best, best_d = found, float(shape_distance(found[1][None], rest)[0])
    frames = tracking_video.iter_frames(path, grey=False)
    try:
        probes = itertools.islice(frames, start + stride, last + 1, stride)
        for frame in tqdm(probes, total=max(0, (last - start) // stride), desc="looking for the face at rest",
                          unit="frame", disable=not progress, leave=False):
            try:
                pts = auto_init(cv2.cvtColor(frame, cv2.COLOR_BGR2GRAY), max_pixels=PROBE_MAX_PIXELS)
            except NoFaceError:
                continue
            d = float(shape_distance(pts[None], rest)[0])
            if d < best_d:
                best, best_d = (frame, pts), d
    finally:
        frames.close()
    return best


_IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff", ".webp")
_POINT_SUFFIXES = (".json", ".csv", ".npz")


def face_palette(folder) -> dict:
    """The faces of a palette folder (Brand §6: the animator picks a face by name).

    Every picture ``NAME.png`` (or .jpg, ...) is a face; its points are ``NAME.json`` / ``.csv`` /
    ``.npz`` beside it (without them the 68 landmarks are detected).

    Parameters
    ----------
    folder : str or path-like
        the palette's folder.

    Returns
    -------
    dict
        ``{name: (image_path, points_path or None)}`` sorted by name.

    Raises
    ------
    ValueError
        ``folder`` is not a folder or holds no pictures.
    """
    d = Path(folder)
    if not d.is_dir():
        raise ValueError(f"face palette {str(d)!r} is not a folder; give a folder of NAME.png + NAME.json faces")
    faces = {}
    for img in sorted(d.iterdir()):
        if img.suffix.lower() in _IMAGE_SUFFIXES and not img.name.startswith("."):
            pts = next((img.with_suffix(s) for s in _POINT_SUFFIXES if img.with_suffix(s).is_file()), None)
            faces[img.stem] = (img, pts)
    if not faces:
        raise ValueError(f"face palette {str(d)!r} holds no pictures ({', '.join(_IMAGE_SUFFIXES)})")
    return faces


def resolve_face(face: str, points=None, palette=None, rest=None, progress: bool = False) -> FaceMesh:
    """A face mesh from ``face``: a picture or video file (with ``points`` or detected landmarks;
    a video's frame nearest ``rest``, see :func:`load_face`) or, with a ``palette`` folder, a
    face name in it. With ``rest``, a 68-point face whose lips are more than
    :data:`voicepuppet.render.photo.OPEN_MOUTH_IOD` further apart than the rest face's is warned
    about (it is not at rest: every frame would show the mouth that much more open).

    Parameters
    ----------
    face : str
        a picture, video or ``.obj`` file, or a face's name in ``palette``.
    points : str or path-like, optional
        the face's points (see :func:`load_face`); for a palette's face, instead of its own.
    palette : str or path-like, optional
        a folder of faces (:func:`face_palette`).
    rest : ndarray, shape (P, 2), optional
        the animation's rest face.
    progress : bool
        show progress (see :func:`load_face`).

    Returns
    -------
    FaceMesh

    Raises
    ------
    ValueError
        ``face`` is not in the palette, or the errors of :func:`load_face`.
    """
    if palette is not None and not Path(face).is_file():
        faces = face_palette(palette)
        if face not in faces:
            raise ValueError(f"face {face!r} is not in the palette {str(palette)!r}; choose one of "
                             f"{', '.join(faces)}")
        image, pts = faces[face]
        mesh = load_face(image, points if points is not None else pts, rest, progress)
    else:
        mesh = load_face(face, points, rest, progress)
    if rest is not None and mesh.n_landmarks == len(rest) == face_layout.N_POINTS:
        photo, still = lip_gap_iod(mesh.landmarks), lip_gap_iod(rest)
        if photo - still > OPEN_MOUTH_IOD:
            warnings.warn(f"the face {str(face)!r} has its lips {photo:.2f} inter-ocular distances apart and the "
                          f"animation's rest face {still:.2f}: every frame shows the mouth that much more open "
                          "and closures do not close; give a photo with the mouth closed at rest (or a video: "
                          "its frame nearest the rest face is taken)", stacklevel=2)
    return mesh
