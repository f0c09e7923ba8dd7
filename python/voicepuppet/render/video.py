"""Rendering a driven face mesh off screen and writing it as video (Brand §4.6).

Rendering uses pyvista off screen (headless EGL with Mesa, :mod:`voicepuppet.render._backend`)
with a parallel camera over the image, so the neutral frame reproduces the photo
(:class:`FaceRenderer`). Outputs (:func:`render`, :func:`write_video`): ``.mp4`` (H.264 through
imageio-ffmpeg, the audio muxed in from the start, cut to the animation's duration), ``.gif``, a
folder of ``.png`` frames; a side-by-side comparison (prediction | ground truth), or a recording
beside the prediction (video | prediction: the real face beside the puppet driven by its sound); a
fast 2-D landmark drawing instead of the mesh (``renderer="2d"``, :func:`draw_landmarks_2d`).
"""

from __future__ import annotations

import contextlib
import itertools
import os
import re
import shutil
import subprocess
import tempfile
from fractions import Fraction
from pathlib import Path
from typing import Iterable, Iterator, Optional

import numpy as np
from tqdm import tqdm

from voicepuppet import layout as face_layout
from voicepuppet._files import atomic_path, check_output_path, publish, signals_held
from voicepuppet.animation import Animation
from voicepuppet.audio.loading import load_audio
from voicepuppet.face import shape_distance
from voicepuppet.limits import LIMITS, check_limit
from voicepuppet.render._backend import import_pyvista
from voicepuppet.render.mesh import FaceMesh
from voicepuppet.render.photo import build_face_mesh, portrait_image
from voicepuppet.render.retargeting import mesh_animation
from voicepuppet.tracking import video as tracking_video

__all__ = ["VIDEO_SUFFIXES", "DEFAULT_MAX_SIZE", "check_size", "default_size", "even", "FaceRenderer",
           "draw_landmarks_2d", "render_frames", "write_video", "render"]

VIDEO_SUFFIXES = (".mp4", ".gif")

_FRAME_CHUNK = 512  # frames of vertices computed at once while rendering


def even(n: int) -> int:
    """``n`` rounded up to an even number (H.264's yuv420p needs even sizes).

    Parameters
    ----------
    n : int
        a size in pixels.

    Returns
    -------
    int
    """
    return int(n) + (int(n) % 2)


#: Without ``size``, a face image larger than this (long side, short side) renders scaled down to
#: fit it, its aspect kept: a 12-megapixel phone photo (4000x3000) renders at 1440x1080 instead of
#: 4000x3000 (a 3000x3000 photo rendered 4.9 frames/s, at 1080x1080 22.5 on the 2-core machine).
DEFAULT_MAX_SIZE = (1920, 1080)


def check_size(size, name: str = "size") -> tuple[int, int]:
    """An output size checked against :data:`voicepuppet.limits.LIMITS` ``["image_side"]``.

    Parameters
    ----------
    size : (width, height)
        Pixels, whole numbers.
    name : str
        What the size is, for the message (default ``"size"``).

    Returns
    -------
    (int, int)
        ``size`` as integers.

    Raises
    ------
    ValueError
        Not two whole numbers, or a side outside [16, 8192].
    """
    try:
        w, h = size
        if int(w) != w or int(h) != h:
            raise ValueError
    except (TypeError, ValueError, OverflowError):
        raise ValueError(f"{name} must be two whole numbers of pixels (width, height), got {size!r}") from None
    for side, v in (("width", w), ("height", h)):
        check_limit(v, "image_side", f"{name} {side}", "render at a size within the range (e.g. 1280x720)")
    return int(w), int(h)


def default_size(width: int, height: int) -> tuple[int, int]:
    """The output size for a ``width`` x ``height`` face image when none is given: the image's,
    scaled down (never up) to fit :data:`DEFAULT_MAX_SIZE` in its orientation, even numbers.

    Parameters
    ----------
    width, height : int
        the face image's size in pixels.

    Returns
    -------
    (int, int)
        the output's width and height.
    """
    long_side, short_side = DEFAULT_MAX_SIZE
    f = min(1.0, long_side / max(width, height), short_side / min(width, height))
    return even(int(round(width * f))), even(int(round(height * f)))


class FaceRenderer:
    """Off-screen pyvista renderer of a :class:`FaceMesh`; ``frame(vertices)`` returns RGB.

    Parameters
    ----------
    mesh : FaceMesh
        the face to draw.
    size : (width, height), optional
        output size in pixels (default: the photo's, scaled down to fit
        :data:`DEFAULT_MAX_SIZE` by :func:`default_size`; even numbers for H.264).
    shading : bool
        light the mesh (shows the depth); off by default so the neutral frame is the photo.
    turn : (yaw, pitch), optional
        degrees to turn the face from the front: yaw about its vertical axis (positive: to its
        left, the nose towards the viewer's right, its right cheek showing), then pitch about the
        horizontal (positive: the chin up); the camera orbits the view's centre at the depth of
        the face's landmarks, its projection still parallel.

    Raises
    ------
    ValueError
        pyvista is missing, or ``turn`` is not two finite angles within [-90, 90] degrees.
    """

    def __init__(self, mesh: FaceMesh, size: Optional[tuple[int, int]] = None, shading: bool = False,
                 turn: Optional[tuple[float, float]] = None):
        pv = import_pyvista()
        W, H = mesh.size
        if size is not None:
            size = check_size(size)
        self.size = default_size(W, H) if size is None else (even(size[0]), even(size[1]))
        self.mesh = mesh
        # no multisampling: llvmpipe renders 8x MSAA (pyvista's default) at a third of the speed,
        # and the texture already carries the photo's own anti-aliasing
        theme = pv.themes.DocumentTheme()
        theme.multi_samples = 0
        theme.anti_aliasing = None
        self._plotter = pv.Plotter(off_screen=True, window_size=list(self.size), theme=theme)
        self._plotter.set_background((0.0, 0.0, 0.0))
        skin_faces = mesh.faces[~mesh.flat]
        self._skin = pv.PolyData(self._world(mesh.vertices), np.hstack([np.full((len(skin_faces), 1), 3), skin_faces]))
        self._skin.active_texture_coordinates = mesh.uv.astype(np.float32)
        texture = pv.Texture(mesh.image)
        kw = {} if shading else {"ambient": 1.0, "diffuse": 0.0, "specular": 0.0}
        self._plotter.add_mesh(self._skin, texture=texture, lighting=shading, **kw)
        self._interior = None
        if mesh.flat.any():  # the mouth's interior, behind the skin: the depth buffer shows it
            flat_faces = mesh.faces[mesh.flat]
            self._interior = pv.PolyData(self._world(mesh.vertices),
                                         np.hstack([np.full((len(flat_faces), 1), 3), flat_faces]))
            self._interior.cell_data["colour"] = mesh.colours[mesh.flat]
            self._plotter.add_mesh(self._interior, scalars="colour", rgb=True, lighting=False)
        cam = self._plotter.camera
        cam.parallel_projection = True
        cx, cy = (W - 1) / 2.0, (H - 1) / 2.0
        cam.focal_point = (cx, -cy, 0.0)
        cam.position = (cx, -cy, 10.0 * max(W, H))
        cam.up = (0.0, 1.0, 0.0)
        # fit the photo in the window keeping its aspect ratio
        aspect_win = self.size[0] / self.size[1]
        cam.parallel_scale = max(H / 2.0, W / 2.0 / aspect_win)
        cam.clipping_range = (1.0, 20.0 * max(W, H))
        if turn is not None:
            yaw, pitch = (float(a) for a in turn)
            if not (np.isfinite(yaw) and np.isfinite(pitch) and abs(yaw) <= 90 and abs(pitch) <= 90):
                raise ValueError(f"turn must be yaw, pitch in degrees within [-90, 90], got {turn!r}")
            # the face turning one way is the camera orbiting the other way round its centre
            depth = float(np.mean(mesh.vertices[: mesh.n_landmarks, 2])) if mesh.n_landmarks else 0.0
            cam.focal_point = (cx, -cy, depth)
            cam.Azimuth(-yaw)
            cam.Elevation(-pitch)
            cam.OrthogonalizeViewUp()
            cam.clipping_range = (1.0, 20.0 * max(W, H))

    @staticmethod
    def _world(vertices: np.ndarray) -> np.ndarray:
        v = np.asarray(vertices, dtype=np.float64).copy()
        v[:, 1] = -v[:, 1]
        return v

    def frame(self, vertices: np.ndarray) -> np.ndarray:
        """Renders one frame.

        Parameters
        ----------
        vertices : ndarray, shape (V, 3)
            the mesh's vertex positions in image coordinates (x, y down, z).

        Returns
        -------
        ndarray, shape (height, width, 3), uint8
        """
        world = self._world(vertices)
        self._skin.points = world
        if self._interior is not None:
            self._interior.points = world
        self._plotter.render()
        return np.asarray(self._plotter.screenshot(return_img=True))[:, :, :3]

    def close(self) -> None:
        """Releases the off-screen window."""
        self._plotter.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()


def draw_landmarks_2d(points: np.ndarray, size: tuple[int, int], background=(255, 255, 255)) -> np.ndarray:
    """The fast fallback: one frame of landmarks drawn as contours (68-point layout) or dots.

    Parameters
    ----------
    points : ndarray, shape (P, 2)
        the landmarks in pixels.
    size : (width, height)
        the picture's size in pixels.
    background : (int, int, int)
        RGB.

    Returns
    -------
    ndarray, shape (height, width, 3), uint8
    """
    from PIL import Image, ImageDraw

    im = Image.new("RGB", (int(size[0]), int(size[1])), tuple(background))
    d = ImageDraw.Draw(im)
    pts = np.asarray(points, dtype=np.float64)
    r = max(1.5, size[0] / 200.0)
    if len(pts) == face_layout.N_POINTS:
        closed = {"right_eye", "left_eye", "outer_lip", "inner_lip"}
        for g, idx in face_layout.GROUPS.items():
            seg = [tuple(p) for p in pts[list(idx)]]
            if g in closed:
                seg.append(seg[0])
            d.line(seg, fill=(200, 40, 60) if "lip" in g else (40, 60, 90), width=max(1, int(r)))
    for x, y in pts:
        d.ellipse([x - r, y - r, x + r, y + r], fill=(20, 20, 20))
    return np.asarray(im)


def _label(img: np.ndarray, text: str) -> np.ndarray:
    from PIL import Image, ImageDraw

    im = Image.fromarray(img)
    ImageDraw.Draw(im).text((6, 4), text, fill=(255, 255, 0))
    return np.asarray(im)


def render_frames(anim: Animation, *, face: Optional[FaceMesh] = None, mode: str = "vertex",
                  truth: Optional[Animation] = None, renderer: str = "mesh",
                  size: Optional[tuple[int, int]] = None, shading: bool = False,
                  turn: Optional[tuple[float, float]] = None,
                  neutral: Optional[np.ndarray] = None, beside=None,
                  progress: bool = False) -> Iterator[np.ndarray]:
    """Yields the frames (H, W, 3) uint8 of ``anim``; with ``truth``, side by side
    (prediction left, ground truth right, same face and frame count); with ``beside``, a video's
    frames on the left (video left, prediction right, frame for frame).

    ``face`` defaults to a drawn portrait (:func:`portrait_image`) on the animation's rest face
    (``neutral``, else :attr:`Animation.rest`; 68-point layout). Both sides move from
    ``neutral`` when it is given, else each from its own rest, a truth without a ``neutral``
    from its frame nearest the animation's (:func:`voicepuppet.face.shape_distance`).
    ``renderer="2d"`` draws the landmarks instead of the mesh; ``turn`` (yaw, pitch) views the
    mesh from an angle (:class:`FaceRenderer`).

    Parameters
    ----------
    anim : Animation
        the animation, P points per frame.
    face : FaceMesh, optional
        the face to drive (its landmarks in the animation's layout).
    mode : {"vertex", "au"}
        how landmark motion drives the mesh (:func:`voicepuppet.render.retargeting.mesh_animation`).
    truth : Animation, optional
        ground truth to show on the right, as many frames and points as ``anim``.
    renderer : {"mesh", "2d"}
        the textured mesh, or the landmarks drawn in 2-D.
    size : (width, height), optional
        output size of one side in pixels (default: :func:`default_size` of the face's, or for
        ``"2d"`` the landmarks' extent with a margin).
    shading : bool
        light the mesh.
    turn : (yaw, pitch), optional
        degrees to turn the face from the front.
    neutral : ndarray, shape (P, 2), optional
        the rest face both sides move from.
    beside : str or path-like, optional
        a video shown on the left, its frame ``t`` beside the animation's frame ``t`` (from its
        first frame, so the animation runs at the video's frame rate; scaled to one side's
        size): e.g. the recording whose sound drives the animation, on a face made from one of
        its frames. Not with ``truth``.
    progress : bool
        show a progress bar.

    Yields
    ------
    ndarray, shape (H, W, 3), uint8
        one frame (W twice one side's width with ``truth`` or ``beside``).

    Raises
    ------
    ValueError
        ``truth`` differs from ``anim`` in points or frames, both ``truth`` and ``beside``, a
        ``beside`` video that is unreadable or has fewer frames than ``anim``, an unknown
        ``renderer``, no face without the 68-point layout, a ``size`` refused by
        :func:`check_size`, 2-D landmarks spanning more than its largest side without a
        ``size``, or pyvista is missing.
    """
    if beside is not None:
        if truth is not None:
            raise ValueError("give either a ground truth or a video to show beside the prediction, not both")
        n = tracking_video.probe_video(beside).frame_count
        if 0 < n < anim.n_frames:  # a container's count may be missing (0): then checked while reading
            raise ValueError(f"the video beside the prediction, {str(beside)!r}, has {n} frames, the animation "
                             f"{anim.n_frames}; animate no more frames than the video has")
        yield from _video_beside(render_frames(anim, face=face, mode=mode, renderer=renderer, size=size,
                                               shading=shading, turn=turn, neutral=neutral, progress=progress),
                                 beside, anim.n_frames)
        return
    if size is not None:
        size = check_size(size)
    if truth is not None:
        if truth.n_points != anim.n_points:
            raise ValueError(f"ground truth has {truth.n_points} points per frame, the prediction {anim.n_points}; "
                             "compare animations in the same layout")
        if truth.n_frames != anim.n_frames:
            raise ValueError(f"ground truth has {truth.n_frames} frames, the prediction {anim.n_frames}; "
                             "resample one of them to the other's frame rate and length")
    if renderer == "2d":
        pts = anim.points
        lo, hi = pts.reshape(-1, 2).min(axis=0), pts.reshape(-1, 2).max(axis=0)
        if truth is not None:
            tp = truth.points.reshape(-1, 2)
            lo, hi = np.minimum(lo, tp.min(axis=0)), np.maximum(hi, tp.max(axis=0))
        margin = 0.1 * (hi - lo).max() + 4.0
        if size is not None:
            box = (even(size[0]), even(size[1]))
        else:
            span = hi - lo + 2 * margin
            if span.max() > LIMITS["image_side"][1]:
                raise ValueError(f"the landmarks span {span[0]:.4g}x{span[1]:.4g} px, more than the largest "
                                 f"picture ({LIMITS['image_side'][1]} px a side); give a size (e.g. 1280x720)")
            box = (even(int(np.ceil(span[0]))), even(int(np.ceil(span[1]))))
        shift = lo - margin
    frames = range(anim.n_frames)
    if progress:
        frames = tqdm(frames, desc="render", unit="frame")
    if renderer == "2d":
        for t in frames:
            img = draw_landmarks_2d(pts[t] - shift, box)
            if truth is not None:
                img = np.hstack([_label(img, "prediction"),
                                 _label(draw_landmarks_2d(truth.points[t] - shift, box), "ground truth")])
            yield img
        return
    if renderer != "mesh":
        raise ValueError(f"renderer must be 'mesh' or '2d', got {renderer!r}")
    ref = None if neutral is None else np.asarray(neutral, dtype=np.float64)
    pred_ref = anim.rest if ref is None else ref
    truth_ref = None if truth is None else (truth.rest if ref is None else ref)
    if ref is None and truth is not None and truth.neutral is None and anim.neutral is not None:
        # a truth of frames only (tracked, say) rests where it is nearest the prediction's rest,
        # not on its first frame, which may be mid-word
        truth_ref = truth.points[int(np.argmin(shape_distance(truth.points, anim.neutral)))]
    if face is None:
        if anim.n_points != face_layout.N_POINTS:
            raise ValueError(f"without a face photo the animation must use the 68-point layout "
                             f"(a drawn portrait is used), got {anim.n_points} points; "
                             "pass a face image and its points")
        lo, hi = pred_ref.min(axis=0), pred_ref.max(axis=0)
        margin = 0.45 * (hi - lo).max()
        shift = lo - margin
        W, H = even(int(hi[0] - lo[0] + 2 * margin)), even(int(hi[1] - lo[1] + 2 * margin))
        face = build_face_mesh(portrait_image(pred_ref - shift, W, H), pred_ref - shift)
    # vertices in chunks of frames: memory stays bounded for hour-long animations
    chunk = _FRAME_CHUNK
    pred = gt = None
    with FaceRenderer(face, size=size, shading=shading, turn=turn) as r:
        for t in frames:
            if t % chunk == 0:
                part = slice(t, t + chunk)
                pred = mesh_animation(Animation(anim.points[part], anim.fps), face, mode=mode,
                                      neutral=pred_ref)["vertices"]
                if truth is not None:
                    gt = mesh_animation(Animation(truth.points[part], truth.fps), face, mode=mode,
                                        neutral=truth_ref)["vertices"]
            img = r.frame(pred[t % chunk])
            if gt is not None:
                img = np.hstack([_label(img, "prediction"), _label(r.frame(gt[t % chunk]), "ground truth")])
            yield img


def _video_beside(frames: Iterable[np.ndarray], video, n_frames: int) -> Iterator[np.ndarray]:
    """Each of ``frames`` with ``video``'s frame of the same index on its left, scaled to its size."""
    import cv2

    recorded = tracking_video.iter_frames(video, grey=False)
    try:
        for t, img in enumerate(frames):
            left = next(recorded, None)
            if left is None:
                raise ValueError(f"the video beside the prediction, {str(video)!r}, ended after {t} frames, the "
                                 f"animation has {n_frames}; animate no more frames than the video has")
            h, w = img.shape[:2]
            left = cv2.resize(left, (w, h), interpolation=cv2.INTER_AREA if left.shape[1] >= w else cv2.INTER_LINEAR)
            yield np.hstack([_label(np.ascontiguousarray(left[:, :, ::-1]), "video"), _label(img, "prediction")])
    finally:
        recorded.close()


def write_video(frames: Iterable[np.ndarray], path, fps: float, *, audio=None, n_frames: Optional[int] = None) -> Path:
    """Writes frames (H, W, 3) uint8 to ``.mp4`` (H.264, yuv420p, audio muxed as AAC and cut to
    the video's duration ``n_frames / fps``), ``.gif`` or a folder of ``frame_000000.png``
    (any other path without a suffix), atomically: nothing appears at ``path`` unless all frames
    were written.

    Parameters
    ----------
    frames : iterable of ndarray, shape (H, W, 3), uint8
        the frames, RGB.
    path : str or path-like
        ``.mp4``, ``.gif``, or a new (or empty) folder's name.
    fps : float
        frames per second.
    audio : str or path-like, optional
        sound to mux into an ``.mp4``.
    n_frames : int, optional
        the frame count, to cut the audio to the video's duration.

    Returns
    -------
    Path
        ``path``.

    Raises
    ------
    ValueError
        the audio file is missing or the output is not an ``.mp4`` with audio, the output exists
        or its folder is not writable, there are no frames, a frame is not (H, W, 3) uint8 like
        the first, or the encoder is missing or fails (FFmpeg's first error line).
    """
    p = Path(path)
    suffix = p.suffix.lower()
    if audio is not None:
        audio = Path(audio)
        if not audio.is_file():
            raise ValueError(f"audio file {str(audio)!r} does not exist")
        if suffix != ".mp4":
            raise ValueError(f"audio can only be muxed into .mp4, not {suffix or 'a folder of frames'}; drop the audio "
                             "or write an .mp4")
        # FFmpeg, given a file it cannot decode (or NaN samples), only breaks the pipe mid-video:
        # decode it first so that the user hears what is wrong before any frame is drawn.
        load_audio(audio, rate=None)
    if suffix == "":
        parent = p.parent if str(p.parent) else Path(".")
        if not parent.is_dir() or not os.access(parent, os.W_OK | os.X_OK):
            raise ValueError(f"output folder {str(parent)!r} must exist and be writable")
        if p.exists() and (not p.is_dir() or any(p.iterdir())):
            raise ValueError(f"output {str(p)!r} already exists and is not an empty folder; choose a new folder name")
        tmp = Path(tempfile.mkdtemp(prefix=f".{p.name}.", suffix=".partial", dir=parent))
        try:
            from PIL import Image

            for t, img in enumerate(frames):
                Image.fromarray(img).save(tmp / f"frame_{t:06d}.png")
            if p.exists():
                p.rmdir()
            publish(tmp, p)
        finally:
            if tmp.exists():
                shutil.rmtree(tmp)
        return p
    check_output_path(p, VIDEO_SUFFIXES + ("",), "video")
    with atomic_path(p, VIDEO_SUFFIXES, "video") as tmp:
        if suffix == ".gif":
            from PIL import Image

            images = [Image.fromarray(f) for f in frames]
            if not images:
                raise ValueError("no frames to write")
            images[0].save(tmp, format="GIF", save_all=True, append_images=images[1:],
                           duration=max(20, int(round(1000.0 / fps / 10.0)) * 10), loop=0)
        else:
            _write_mp4(frames, tmp, fps, audio, n_frames, p)
    return p


def _ffmpeg_command(path: Path, size: tuple[int, int], rate: Fraction, audio: Optional[Path],
                    n_frames: Optional[int]) -> list[str]:
    import imageio_ffmpeg

    # the same frames give the same bytes: one encoder thread (x264's automatic count follows
    # the CPUs the process may use: 3 frame threads on 2 cores, 1 under taskset) and no B-frames
    # (with them x264's macroblock tree reads heap memory it has not written; see synth.video)
    cmd = [imageio_ffmpeg.get_ffmpeg_exe(), "-y", "-f", "rawvideo", "-vcodec", "rawvideo", "-s", f"{size[0]}x{size[1]}",
           "-pix_fmt", "rgb24", "-r", str(rate), "-i", "-"]
    cmd += ["-an"] if audio is None else ["-i", str(audio)]
    if size != (even(size[0]), even(size[1])):  # yuv420p needs even sides: one black row or column more
        cmd += ["-vf", f"pad={even(size[0])}:{even(size[1])}"]
    cmd += ["-vcodec", "libx264", "-pix_fmt", "yuv420p", "-crf", "15", "-v", "error",
            "-movflags", "+faststart", "-preset", "veryfast", "-threads", "1", "-bf", "0"]
    if audio is not None:
        if n_frames is not None:
            cmd += ["-t", f"{n_frames / float(rate):.6f}"]
        cmd += ["-acodec", "aac", "-map", "0:v:0", "-map", "1:a:0"]
    return cmd + [str(path)]


def _write_mp4(frames, path: Path, fps: float, audio: Optional[Path], n_frames: Optional[int], name: Path) -> None:
    """H.264 through the FFmpeg that imageio-ffmpeg ships, fed raw RGB frames on its stdin, into
    ``path`` (the temporary file of the output ``name``, which the messages give).

    The encoder is this function's own process: on any exception (a Ctrl-C or SIGTERM too) it is
    killed and waited for before the exception leaves, so it cannot create ``path`` again after
    :func:`~voicepuppet._files.atomic_path` has removed it.
    """
    try:
        import imageio_ffmpeg  # noqa: F401  (it ships FFmpeg's executable)
    except ImportError:
        raise ValueError("writing .mp4 needs imageio-ffmpeg: pip install imageio-ffmpeg") from None

    it = iter(frames)
    try:
        first = next(it)
    except StopIteration:
        raise ValueError("no frames to write") from None
    if first.ndim != 3 or first.shape[2] != 3:
        raise ValueError(f"frames must be (height, width, 3) RGB; the first is {first.shape}")
    h, w = first.shape[:2]
    rate = Fraction(30000, 1001) if abs(fps - 30000 / 1001) < 1e-3 else Fraction(fps).limit_denominator(1001)
    cmd = _ffmpeg_command(path, (w, h), rate, audio, n_frames)
    proc = None
    with tempfile.TemporaryFile() as log:
        def failed() -> ValueError:
            proc.kill()
            proc.wait()
            log.seek(0)
            # the first line says why ("invalid width x height"); later ones are its consequences
            lines = [re.sub(r"^(\[[^]]* @ 0x[0-9a-f]+\]\s*)+", "", line).strip()
                     for line in log.read().decode("utf-8", "replace").splitlines()]
            why = next((line for line in lines if line), f"it stopped with exit code {proc.returncode}")
            return ValueError(f"FFmpeg could not write {str(name)!r}: {why}")

        try:
            with signals_held():  # the encoder started and its cleanup armed, or neither
                proc = subprocess.Popen(cmd, stdin=subprocess.PIPE, stdout=subprocess.DEVNULL, stderr=log,
                                        start_new_session=True)
            for img in itertools.chain([first], it):
                if img.shape != first.shape or img.dtype != np.uint8:
                    raise ValueError(f"every frame must be {h}x{w}x3 uint8 like the first; "
                                     f"one is {'x'.join(map(str, img.shape))} {img.dtype}")
                try:
                    proc.stdin.write(memoryview(np.ascontiguousarray(img)))
                except BrokenPipeError:
                    raise failed() from None
            try:
                proc.stdin.close()
            except BrokenPipeError:
                raise failed() from None
            if proc.wait() != 0:
                raise failed()
        finally:
            if proc is not None:
                with signals_held():  # killed and reaped: it writes nothing after this
                    if proc.poll() is None:
                        proc.kill()
                        proc.wait()
                    with contextlib.suppress(OSError):
                        proc.stdin.close()  # frames still buffered for a dead encoder: dropped


def render(anim: Animation, path, *, audio=None, face: Optional[FaceMesh] = None, mode: str = "vertex",
           truth: Optional[Animation] = None, renderer: str = "mesh", size: Optional[tuple[int, int]] = None,
           shading: bool = False, neutral: Optional[np.ndarray] = None, progress: bool = False,
           turn: Optional[tuple[float, float]] = None, beside=None) -> Path:
    """Renders ``anim`` to ``path`` (``.mp4``, ``.gif`` or a folder of ``.png`` frames),
    with ``audio`` muxed into an ``.mp4``.

    Parameters
    ----------
    anim : Animation
        the animation to render.
    path : str or path-like
        ``.mp4``, ``.gif``, or a folder's name for ``.png`` frames.
    audio : str or path-like, optional
        sound to mux into an ``.mp4``.
    face, mode, truth, renderer, size, shading, neutral, progress, turn, beside
        as for :func:`render_frames`.

    Returns
    -------
    Path
        ``path``.

    Raises
    ------
    ValueError
        an unknown output format, an existing output, a ``size`` refused by
        :func:`check_size`, or the errors of :func:`render_frames` and :func:`write_video`.
    """
    p = Path(path)
    if p.suffix.lower() not in VIDEO_SUFFIXES + ("",):
        raise ValueError(f"render output {str(p)!r} has an unknown format {p.suffix!r}; use .mp4, .gif, or a folder "
                         "name for .png frames (meshes and other formats: voicepuppet export)")
    if size is not None:
        size = check_size(size)
    if p.suffix:
        check_output_path(p, VIDEO_SUFFIXES, "render output")
    frames = render_frames(anim, face=face, mode=mode, truth=truth, renderer=renderer, size=size,
                           shading=shading, neutral=neutral, progress=progress, turn=turn, beside=beside)
    return write_video(frames, p, anim.fps, audio=audio, n_frames=anim.n_frames)
