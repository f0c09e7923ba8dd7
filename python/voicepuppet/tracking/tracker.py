"""Facial landmark tracking: the spring-mesh SSD tracker of Voice Puppetry §4.1.

A mesh of sub-pixel SSD trackers (one per landmark) coupled by springs, relaxed jointly in each
frame by the C++ kernel (``cpp/include/voicepuppet/tracker.hpp``). Spring lengths and
stiffnesses are re-estimated from the mean and variance of the tracked distances, and the
sequence is tracked again, ``passes`` times in all (the paper's "few repetitions").

This module runs the passes (:func:`track_frames`, :func:`track_video`); the mesh's edges and
lip springs are in :mod:`voicepuppet.tracking.springs`, the working scale of large faces in
:mod:`voicepuppet.tracking.scale`, the search for a lost face in
:mod:`voicepuppet.tracking.reacquire`, face detection in :mod:`voicepuppet.tracking.detect`,
and the result and its files in :mod:`voicepuppet.tracking.landmarks`.

Command line: ``voicepuppet track VIDEO -o landmarks.npz [--init points.json|auto]
[--overlay out.mp4]`` (:mod:`voicepuppet.cli.track`). File formats are those of DESIGN.md
("Files users exchange").
"""

from __future__ import annotations

import itertools
import os
import warnings
from dataclasses import replace
from typing import Callable, Iterable, Sequence

import numpy as np
from tqdm.auto import tqdm

from voicepuppet import _core
from voicepuppet.layout import INNER_LIP_PAIRS, MOUTH
from voicepuppet.tracking import video
from voicepuppet.tracking._checks import as_grey, check_inside, check_points
from voicepuppet.tracking.detect import NoFaceError, first_face, landmark_model, landmarks_near
from voicepuppet.tracking.landmarks import TrackResult, load_init_points
from voicepuppet.tracking.reacquire import REACQUIRE_FRAMES, REACQUIRE_LOST_SHARE, FaceSearch
from voicepuppet.tracking.scale import points_to_full, points_to_working, working_scale_factor
from voicepuppet.tracking.springs import (FACE_FRAME_POINTS, LIP_GROUP_SEARCH_IOD, LIP_SEARCH_IOD,
                                          LIP_SPRING_FLOOR_IOD, LIP_SPRING_OUTLIER, LOWER_LIP,
                                          OUTER_MOUTH_CORNERS, OUTER_UPPER_LIP, checked_lip_edges,
                                          delaunay_edges, eye_corner_sides, lip_patch_sides, lip_springs,
                                          soften_opening)

#: How far (inter-ocular distances) an inner lip may overlap its partner before the tracker moves
#: the pair apart: closed lips meet within this of each other in the tracker's noise.
INNER_LIP_OVERLAP_IOD = 0.005

#: Detector anchors (``detector_anchors``): each lip point (48-67) is pulled toward dlib's answer
#: on its frame by a spring of standard deviation ANCHOR_SIGMA_IOD that is slack within
#: ANCHOR_SLACK_IOD (inter-ocular distances): the patches place the lips within dlib's noise, and
#: dlib stops their drift onto teeth, tongue and the mouth's cavity (docs/tracking.md, "Detector
#: anchors": chosen there, on the shared real clips, over sds of 0.003-0.1 and slacks of 0-0.045).
ANCHOR_SIGMA_IOD = 0.005
ANCHOR_SLACK_IOD = 0.01
#: The outer mouth corners' anchors are stiffer (standard deviation ANCHOR_CORNER_SIGMA_IOD, slack
#: ANCHOR_CORNER_SLACK_IOD), and the corners are then left out of the reference search: the mouth's
#: width changes by a few hundredths of the inter-ocular distance in speech, which the patches,
#: sliding along the lip contour, follow worse than dlib does (docs/tracking.md, "Detector anchors").
ANCHOR_CORNER_SIGMA_IOD = 0.001
ANCHOR_CORNER_SLACK_IOD = 0.0

__all__ = ["track_frames", "track_video", "VariableFrameRateWarning"]


class VariableFrameRateWarning(UserWarning):
    """:func:`track_video` found a video whose frames are not at ``k / fps`` (their time stamps
    are kept in ``TrackResult.times``)."""


_OPTION_NAMES = ("patch_radius", "levels", "max_iterations", "tolerance", "intensity_sigma",
                 "spring_weight", "ncc_floor", "ncc_full", "lost_confidence", "drift_tolerance",
                 "damping", "patch_sides", "search_radius", "frame_points", "spring_outlier", "outlier_edges",
                 "search_groups", "group_search_radius", "reference_points", "reference_sides",
                 "reference_search_radius", "reference_search_ncc", "order_pairs", "order_axis", "order_margin",
                 "anchor_precision", "anchor_slack")


def _options(opts: dict) -> "_core.TrackerOptions":
    o = _core.TrackerOptions()
    for k, v in opts.items():
        if k not in _OPTION_NAMES:
            raise ValueError(f"unknown tracker option {k!r}; choose from {', '.join(_OPTION_NAMES)}")
        setattr(o, k, v)
    return o


def _one_pass(frames: Callable[[], Iterable[np.ndarray]], init: np.ndarray, mesh, options,
              n_hint: int | None, progress: bool, desc: str, reacquire: bool = True, anchors=None):
    pts, conf, lost = [], [], []
    reacquired = []
    model = landmark_model() if anchors is not None else None  # once, not per frame
    tracker = search = first = None
    shape = None
    streak = 0  # frames in a row with more than REACQUIRE_LOST_SHARE of the points lost
    with tqdm(total=n_hint, desc=desc, unit="frame", disable=not progress, leave=False) as bar:
        for t, frame in enumerate(frames()):
            g = as_grey(frame, t, shape)
            if tracker is None:
                if anchors is not None and not anchors:
                    anchors.append(init.copy())
                shape = g.shape
                check_inside(init, shape)
                tracker = _core.SpringMeshTracker(g, init, mesh, options)
                first = g
                pts.append(init.copy())
                conf.append(np.ones(len(init)))
                lost.append(np.zeros(len(init), dtype=bool))
            else:
                if anchors is not None and len(anchors) <= t:
                    detected = landmarks_near(g, pts[-1], model)
                    anchors.append(np.full((len(init), 2), np.nan) if detected is None else detected)
                step = (lambda: tracker.track(g)) if anchors is None else (lambda: tracker.track(g, anchors[t]))
                r = step()
                if reacquire and streak >= REACQUIRE_FRAMES:
                    # Lost for long enough: look for the face over the whole frame, restart the
                    # mesh where it is found and track this frame again from there (the search's
                    # templates are cut from the first frame when it is first needed).
                    search = search or FaceSearch(first, init)
                    found = search.find(g, init)
                    if found is not None:
                        tracker.relocate(found[0])
                        r = step()
                        if np.mean(r.lost) <= REACQUIRE_LOST_SHARE:
                            reacquired.append(t)
                streak = streak + 1 if np.mean(r.lost) > REACQUIRE_LOST_SHARE else 0
                pts.append(np.asarray(r.points))
                conf.append(np.asarray(r.confidence))
                lost.append(np.asarray(r.lost, dtype=bool))
                if reacquire and streak >= REACQUIRE_FRAMES:
                    # The face is gone: the few points that still match something (a hand's
                    # texture, the background) are not on it, so every point of these frames is
                    # lost (and the springs re-estimated from the pass do not learn from them):
                    # the run's first frames when it is recognised, then each frame of it.
                    for q in range(1, (REACQUIRE_FRAMES if streak == REACQUIRE_FRAMES else 1) + 1):
                        lost[-q] = np.ones(len(init), dtype=bool)
            bar.update(1)
    if tracker is None:
        raise ValueError("the sequence holds no frames; nothing to track")
    return np.stack(pts), np.stack(conf), np.stack(lost), reacquired


def _track(frames: Callable[[], Iterable[np.ndarray]], init_points, *, fps: float, edges=None,
           passes: int = 2, relative_sigma: float = 0.05, min_sigma: float = 0.5,
           initial_min_sigma: float | None = None, lips: bool | None = None, eyes: bool | None = None,
           n_hint: int | None = None, progress: bool = True, names=None, scale: float = 1.0,
           work_shape=None, reacquire: bool = True, detector_anchors: bool = False, **options) -> TrackResult:
    """Tracks ``frames`` (already resized by ``scale``, of shape ``work_shape``) from the
    full-resolution ``init_points``; the tracker runs in the resized frames, the result is
    mapped back to full-resolution pixels."""
    init = check_points(init_points, "init_points")
    if scale != 1.0:
        # A point on the last full-resolution pixel can map past the last resized one (the
        # resized size is rounded): clamp into the resized image.
        h, w = work_shape
        init = np.clip(points_to_working(init, scale), 0.0, [w - 1.0, h - 1.0])
    if lips is None:
        lips = len(init) == 68
    if eyes is None:
        eyes = len(init) == 68
    for flag, on in (("lips", lips), ("eyes", eyes)):
        if on and len(init) != 68:
            raise ValueError(f"{flag}=True needs the 68 points of the iBUG 300-W layout, got {len(init)} points; "
                             f"pass {flag}=False (or patch_sides and search_radius yourself)")
    if lips or eyes:
        # Half patches: the lips on the side away from the mouth opening, the eye corners on the
        # side away from their eye.
        options.setdefault("patch_sides", (lip_patch_sides(init) if lips else 0.0)
                           + (eye_corner_sides(init) if eyes else 0.0))
    if lips:
        iod = float(np.linalg.norm(init[45] - init[36]))
        options.setdefault("search_radius", LIP_SEARCH_IOD * iod)
        groups = np.where(np.isin(np.arange(68), LOWER_LIP), 0, -1).astype(np.int64)
        options.setdefault("search_groups", groups)
        options.setdefault("group_search_radius", LIP_GROUP_SEARCH_IOD * iod)
        options.setdefault("spring_outlier", LIP_SPRING_OUTLIER)
        searched = OUTER_UPPER_LIP if detector_anchors else OUTER_MOUTH_CORNERS + OUTER_UPPER_LIP
        options.setdefault("reference_points", np.asarray(searched, dtype=np.int64))
        reference_sides = np.zeros((68, 2))
        reference_sides[list(OUTER_UPPER_LIP)] = lip_patch_sides(init)[62]  # up the face
        options.setdefault("reference_sides", reference_sides)
        options.setdefault("reference_search_radius", LIP_SEARCH_IOD * iod)
        # The inner lips never cross: ordered along the face's vertical (eyes to mouth).
        options.setdefault("order_pairs", np.asarray(INNER_LIP_PAIRS, dtype=np.int64))
        options.setdefault("order_axis", init[48:68].mean(axis=0) - 0.5 * (init[36] + init[45]))
        options.setdefault("order_margin", INNER_LIP_OVERLAP_IOD * iod)
        lip_floor = LIP_SPRING_FLOOR_IOD * iod
    if passes < 1:
        raise ValueError(f"passes must be >= 1 (tracking passes with spring re-estimation), got {passes}")
    if edges is None:
        edges = delaunay_edges(init)
    edges = np.ascontiguousarray(edges, dtype=np.int64)
    if edges.ndim != 2 or edges.shape[1] != 2 or len(edges) == 0:
        raise ValueError(f"edges must have shape (E, 2) with E >= 1, got {edges.shape}")
    mesh = _core.springs_from_points(init, edges, relative_sigma,
                                     0.0 if initial_min_sigma is None else initial_min_sigma)
    if lips:
        mesh = lip_springs(init, edges, mesh, relative_sigma, min_sigma, lip_floor)
        options.setdefault("outlier_edges", checked_lip_edges(edges))
    # The head pose the templates, half patches and springs follow: the nose and eye corners of
    # a 68-point face, otherwise all points (frame_points=() for the image frame).
    options.setdefault("frame_points", np.asarray(FACE_FRAME_POINTS if len(init) == 68 else range(len(init)),
                                                  dtype=np.int64))
    # Detector anchors: dlib's lips on every frame (found in the box the previous frame's points
    # give), computed in the first pass and kept for the others.
    anchors = None
    if detector_anchors:
        if len(init) != 68:
            raise ValueError(f"detector_anchors=True needs the 68 points of the iBUG 300-W layout, got {len(init)} "
                             "points; pass detector_anchors=False")
        iod = float(np.linalg.norm(init[45] - init[36]))
        precision = np.zeros(68)
        precision[MOUTH] = 1.0 / (ANCHOR_SIGMA_IOD * iod) ** 2
        precision[list(OUTER_MOUTH_CORNERS)] = 1.0 / (ANCHOR_CORNER_SIGMA_IOD * iod) ** 2
        slack = np.full(68, ANCHOR_SLACK_IOD * iod)
        slack[list(OUTER_MOUTH_CORNERS)] = ANCHOR_CORNER_SLACK_IOD * iod
        options.setdefault("anchor_precision", precision)
        options.setdefault("anchor_slack", slack)
        anchors = []
    if np.ndim(options.get("anchor_slack", ())) == 0:  # one slack for every point
        options["anchor_slack"] = np.full(len(init), float(options["anchor_slack"]))
    opts = _options(options)
    # The first pass's lip springs are guesses: their check on the data (spring_outlier) waits
    # for the springs re-estimated from a pass.
    first_opts = _options({**options, "spring_outlier": 0.0}) if lips else opts
    frame_points = np.asarray(options.get("frame_points", np.zeros(0)), dtype=np.int64)
    history = []
    prev = None
    for k in range(passes):
        pts, conf, lost, reacquired = _one_pass(frames, init, mesh, first_opts if k == 0 else opts, n_hint,
                                                progress, f"tracking pass {k + 1}/{passes}", reacquire,
                                                anchors)
        row = {"pass": k + 1, "lost_fraction": float(lost.mean()), "reacquired": reacquired,
               "mean_point_change": None if prev is None else float(np.linalg.norm(pts - prev, axis=2).mean()),
               "max_rel_length_change": None, "max_length_change": None}
        if k + 1 < passes:
            new = _core.estimate_springs(pts.reshape(len(pts), -1), lost, mesh, min_sigma, frame_points)
            old_len = np.asarray(mesh.rest_length)
            change = np.abs(np.asarray(new.rest_length) - old_len)
            row["max_rel_length_change"] = float(np.max(change / old_len))
            row["max_length_change"] = float(np.max(change))
            mesh = soften_opening(new, edges, lip_floor) if lips else new
        history.append(row)
        prev = pts
    rest_length, stiffness = np.asarray(mesh.rest_length), np.asarray(mesh.stiffness)
    if scale != 1.0:  # back to full-resolution pixels
        pts = points_to_full(pts, scale)
        rest_length, stiffness = rest_length / scale, stiffness * scale**2
        for row in history:
            for key in ("mean_point_change", "max_length_change"):
                if row[key] is not None:
                    row[key] /= scale
    return TrackResult(points=pts, confidence=conf, lost=lost, fps=float(fps), edges=edges,
                       rest_length=rest_length, stiffness=stiffness,
                       passes=history, names=list(names) if names is not None else None, working_scale=scale,
                       reacquired=list(reacquired))


def track_frames(frames: Sequence[np.ndarray] | np.ndarray, init_points, *, fps: float = 29.97,
                 edges=None, passes: int = 2, progress: bool = False, working_scale="auto",
                 **options) -> TrackResult:
    """Tracks landmarks through frames held in memory.

    Parameters
    ----------
    frames : ndarray, shape (T, H, W), uint8, or sequence of ndarray
        Grey frames, or a sequence of (H, W) uint8 grey or (H, W, 3) uint8 BGR frames.
    init_points : array_like, shape (P, 2)
        Positions (x, y) on frame 0, P >= 3, inside the image.
    fps : float, default 29.97
        Frame rate recorded in the result.
    edges : array_like, shape (E, 2), int, optional
        Spring edges; default: the Delaunay triangulation of ``init_points``
        (:func:`voicepuppet.tracking.springs.delaunay_edges`).
    passes : int, default 2
        Tracking passes; after each but the last, spring lengths and stiffnesses are
        re-estimated from the tracked distances (mean and variance), as in the paper.
    progress : bool, default False
        Show a tqdm progress bar.
    working_scale : {"auto"} or float, default "auto"
        ``"auto"`` or a factor in (0, 1]: a face larger than the one the tracker was tuned on
        (outer eye corners more than ``LARGE_FACE_IOD`` = 128 px apart; other layouts: see
        :func:`voicepuppet.tracking.scale.face_size`) is tracked on frames resized down by one
        factor for the whole sequence (area averaging), so that they are ``WORKING_IOD`` = 112
        px apart; faces at or below 128 px are tracked at full resolution, as before. The
        points are returned in full-resolution pixels and the factor as
        ``TrackResult.working_scale``; pixel-valued options (``patch_radius``,
        ``search_radius``, ``min_sigma``, ...) are pixels of the resized frames. See
        :func:`voicepuppet.tracking.scale.working_scale_factor`.
    **options
        Fields of the C++ ``TrackerOptions`` (patch_radius, levels, ncc_floor, ..., ``patch_sides``
        (P, 2) half-patch directions, ``search_radius`` px, ``frame_points``: the points whose
        similarity to frame 0 is the head pose that the first-frame templates, half patches, search
        radii and spring lengths follow through in-plane rotation and scale; default the nose and
        eye corners of a 68-point face (``FACE_FRAME_POINTS``), all points otherwise; ``()`` for the
        image frame) and ``relative_sigma`` (initial spring std as a fraction of length),
        ``min_sigma`` (px floor of re-estimated spring std), ``initial_min_sigma`` (px floor of the
        initial spring std; default none), ``lips`` (lip tracking for a 68-point iBUG layout:
        :func:`voicepuppet.tracking.springs.lip_patch_sides` half patches, a search radius of 0.065
        inter-ocular distances, initial springs from the lips to the face no stiffer than a std of
        0.025 inter-ocular distances, offset springs between lip points (a Gaussian on the
        face-frame vector between them: stiff along the lip contours, soft along the face's vertical
        axis across the mouth opening; ``frame_points`` the nose and eye corners), the lower lip
        searched for as one group within 0.15 inter-ocular distances (``search_groups``,
        ``group_search_radius``) and, from the second pass, a lip point further than 6 standard
        deviations of its within-lip springs (and a mouth corner's springs to the lower lip) from
        where they put it handed to them for the frame (``spring_outlier``, ``outlier_edges``), the
        outer mouth corners searched for against their first-frame patches within the lip search
        radius and the outer upper lip against the upper half of theirs along the face's vertical
        (``reference_points``, ``reference_sides``, ``reference_search_radius``,
        ``reference_search_ncc``); default: on when there are 68 points; explicit options win),
        ``eyes`` (the eye corners 36, 39, 42, 45 of a 68-point layout tracked on the half of their
        patches away from their eye, so the lids do not drag them in blinks:
        :func:`voicepuppet.tracking.springs.eye_corner_sides`; default: on when there are 68
        points), ``reacquire`` (default True: a face lost for
        :data:`voicepuppet.tracking.reacquire.REACQUIRE_FRAMES` frames, more than
        :data:`voicepuppet.tracking.reacquire.REACQUIRE_LOST_SHARE` of its points lost, is searched
        for over the whole frame each frame until found, the mesh restarted where it is
        (``TrackResult.reacquired``), and the frames it is gone have every point lost; False: points
        stay where they were lost), ``detector_anchors`` (default False; a 68-point face only: dlib's
        shape predictor is run on every frame in the box the previous frame's points give
        (:func:`voicepuppet.tracking.detect.landmarks_near`), and each lip point is pulled toward
        its answer by a spring that is slack within :data:`ANCHOR_SLACK_IOD` inter-ocular
        distances (:data:`ANCHOR_SIGMA_IOD`): on real faces the patches alone drift onto teeth,
        tongue and the mouth's cavity; ``track_video`` with ``init="auto"`` turns it on).

    Returns
    -------
    voicepuppet.tracking.landmarks.TrackResult
        The tracked points, their confidences and lost flags, the springs of the last pass and
        a summary of each pass.

    Raises
    ------
    ValueError
        No frames, frames that are not uint8 images of one size, initial points that are not
        at least 3 finite positions inside the first frame, ``lips`` or ``eyes`` without 68
        points, ``passes`` below 1, bad ``edges``, an unknown option or a bad
        ``working_scale``.
    """
    if len(frames) == 0:
        raise ValueError("frames is empty: the sequence holds no frames; nothing to track")
    scale = working_scale_factor(init_points, working_scale)
    work_shape = None
    if scale != 1.0:
        first = as_grey(frames[0], 0, None)
        check_inside(check_points(init_points, "init_points"), first.shape)
        frames = [video.downscale(as_grey(f, t, first.shape), scale) for t, f in enumerate(frames)]
        work_shape = frames[0].shape
    return _track(lambda: iter(frames), init_points, fps=fps, edges=edges, passes=passes,
                  n_hint=len(frames), progress=progress, scale=scale, work_shape=work_shape, **options)


def track_video(path: str | os.PathLike, init: str | os.PathLike | np.ndarray = "auto", *,
                names=None, edges=None, passes: int = 2, progress: bool = True, cache_bytes: int = 1 << 30,
                working_scale="auto", detector_anchors: bool | None = None, **options) -> TrackResult:
    """Tracks landmarks through a video file.

    Parameters
    ----------
    path : str or os.PathLike
        A video OpenCV can decode.
    init : array_like of shape (P, 2), str or os.PathLike, default "auto"
        Points (x, y) on the first frame, a JSON/CSV file of them (see
        :func:`voicepuppet.tracking.landmarks.load_init_points`), or ``"auto"`` for a landmark
        detector (:func:`voicepuppet.tracking.detect.auto_init`); with ``"auto"`` and no face on
        the first frame, one frame every :data:`voicepuppet.tracking.detect.AUTO_INIT_STRIDE_S`
        s of the first :data:`voicepuppet.tracking.detect.AUTO_INIT_SCAN_S` s is looked at
        (:func:`voicepuppet.tracking.detect.first_face`), and tracking starts on the earliest
        frame with a face (a warning says where; the frames before it are lost,
        ``TrackResult.start``).
    names : list of str, optional
        (P,) names of the points, with ``init`` given as an array (a points file carries its
        own).
    edges : array_like, shape (E, 2), int, optional
        As in :func:`track_frames`.
    passes : int, default 2
        As in :func:`track_frames`.
    progress : bool, default True
        Show tqdm progress bars.
    cache_bytes : int, default 1 << 30
        Decoded grey frames (at the working scale: resized ones when the face is large) are
        kept in memory up to this size when ``passes > 1``; longer videos are decoded again for
        each pass.
    working_scale : {"auto"} or float, default "auto"
        As in :func:`track_frames`.
    detector_anchors : bool, optional
        As in :func:`track_frames`; default: on with ``init="auto"`` (the detector that placed
        the first frame's points keeps the lips from drifting), off with given points (their
        layout need not be dlib's).
    **options
        As in :func:`track_frames`.

    Returns
    -------
    voicepuppet.tracking.landmarks.TrackResult
        The landmarks through the whole video (``times``: each frame's time stamp, when the
        container gives them).

    Raises
    ------
    ValueError
        A video that cannot be opened or holds no frames, bad points, ``names`` with a points
        file or ``"auto"``, or (with ``init="auto"``) no detector.
    voicepuppet.tracking.detect.NoFaceError
        With ``init="auto"``, no face in the frames looked at (a ``ValueError``).

    Warns
    -----
    VariableFrameRateWarning
        The video's frames are not at ``k / fps``.
    """
    info = video.probe_video(path)
    fps = info.fps if info.fps > 0 else 29.97
    if names is not None and (isinstance(init, (str, os.PathLike))):
        raise ValueError("names go with init points given as an array, not with a points file (which "
                         "carries its own) or 'auto'")
    frames_iter = video.iter_frames(path)
    first = next(frames_iter, None)
    frames_iter.close()  # releases the decoder now rather than at garbage collection
    if first is None:
        raise ValueError(f"video {str(path)!r} holds no decodable frames; check the file")
    times = video.frame_times(path)
    start = 0
    auto = isinstance(init, str) and init == "auto"
    if detector_anchors is None:
        detector_anchors = auto
    if auto:
        try:
            start, first, points = first_face(path, first, fps, progress)
        except NoFaceError as exc:
            raise NoFaceError(f"--init auto: {exc}; pass the first-frame points with --init points.json") from None
        if start:
            when = times[start] if times is not None and start < len(times) else start / fps
            warnings.warn(f"--init auto: no face on the first frame of {str(path)!r}; found one at "
                          f"frame {start} ({when:.2f} s), where tracking starts (the {start} frames "
                          "before it are lost)", stacklevel=2)
    elif isinstance(init, (str, os.PathLike)):
        points, names = load_init_points(init)
    else:
        points = init
    scale = working_scale_factor(points, working_scale)
    work_shape = None
    if scale != 1.0:
        check_inside(check_points(points, "init_points"), first.shape)
        first = video.downscale(first, scale)
        work_shape = first.shape

    def decode():
        return itertools.islice(video.iter_frames(path, scale=scale), start, None)

    need = max(info.frame_count - start, 0) * first.size
    if passes > 1 and 0 < need <= cache_bytes:
        frames = np.stack(list(decode()))
        source = lambda: iter(frames)  # noqa: E731
        n_hint = len(frames)
    else:
        source = decode
        n_hint = (info.frame_count - start) or None
    result = _track(source, points, fps=fps, edges=edges, passes=passes, n_hint=n_hint,
                    progress=progress, names=names, scale=scale, work_shape=work_shape,
                    detector_anchors=detector_anchors, **options)
    if start:
        result = _lost_before(result, start)
    if times is not None and len(times) == len(result.points):  # else OpenCV decoded others
        result.times = times
        slip = video.grid_slip(times, fps)
        if slip > video.MAX_GRID_SLIP:
            # The rate it runs at most of the time, not OpenCV's average: the grid train resamples onto.
            result.fps = video.nominal_rate(times)
            step = np.diff(times) * 1e3
            warnings.warn(f"{str(path)!r} has a variable frame rate (frames {step.min():.1f}-{step.max():.1f} ms "
                          f"apart: at OpenCV's average of {fps:g} fps a frame's index would put it up to "
                          f"{slip:.1f} frames off its time); each frame's time is kept (the landmarks' times "
                          f"and the .csv's time column), the frame rate is its most common, {result.fps:g} "
                          "fps, and train resamples onto it", VariableFrameRateWarning, stacklevel=2)
    return result


def _lost_before(result: TrackResult, start: int) -> TrackResult:
    """``result`` (tracked from frame ``start``) with the ``start`` frames before it prepended as
    lost, their points those of its first frame; frame indices and lost shares of the whole video."""
    T, P = result.lost.shape
    passes = [{**row, "lost_fraction": (row["lost_fraction"] * T + start) / (T + start),
               "reacquired": [t + start for t in row["reacquired"]]} for row in result.passes]
    return replace(result,
                   points=np.concatenate([np.repeat(result.points[:1], start, axis=0), result.points]),
                   confidence=np.concatenate([np.zeros((start, P)), result.confidence]),
                   lost=np.concatenate([np.ones((start, P), dtype=bool), result.lost]),
                   passes=passes, reacquired=[t + start for t in result.reacquired], start=start)
