"""Face vectors: landmarks without head pose, in a compact basis, with velocities.

Voice Puppetry models facial *shape* (pose and velocity of the features), not where the head is in
the picture. :class:`FaceSpace` removes the head pose from each frame by a weighted similarity
Procrustes fit to the mean shape (the pose is kept as its own track and can be re-applied), then
optionally projects the normalised shape onto principal components. :func:`observations` builds
the HMM's observations ``o_t = [y_t, y_t - y_{t-1}]`` (Voice Puppetry eq. 3).

Conventions
-----------
- Landmarks are pixel coordinates ``points [T, P, 2]`` (x, y), as in every landmark file.
- A pose is ``(log s, θ, tx, ty)``: pixel point = ``s · R(θ) · shape point + (tx, ty)``, with the
  normalised shape centred on the (weighted) centroid and scaled like the average training face,
  so face coordinates are in pixels of an average-sized, upright face.
- Procrustes weights: for the 68-point iBUG layout, the points that move least with speech
  (nose, eye corners) carry the fit (weight 1) and the rest a small weight (0.05), so an opening
  jaw is not mistaken for a head that grows or turns. Any other layout weighs points equally
  unless ``weights`` is given.
- Parts (Voice Puppetry §5.1, separate upper- and lower-face models): a partition of the points;
  each part has its own principal components, and face coordinates are the parts' coordinates
  side by side (``part_slices`` says where).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from voicepuppet.layout import RIGID

#: iBUG 68-point layout: the upper face (brows, eyes, nose) and the lower face (jaw line, mouth).
IBUG68_PARTS = {"upper": tuple(range(17, 48)), "lower": tuple(range(0, 17)) + tuple(range(48, 68))}


def check_landmarks(points, name: str = "points") -> np.ndarray:
    """``points`` as float64 [T, P, 2], finite, with T >= 1 and P >= 3; ValueError otherwise.

    Parameters
    ----------
    points : array_like, shape (T, P, 2)
        Landmarks, pixel coordinates (x, y).
    name : str
        What the points are, for the error messages (default ``"points"``).

    Returns
    -------
    ndarray, shape (T, P, 2)
        ``points`` as float64.

    Raises
    ------
    ValueError
        Not of shape (T, P, 2), fewer than 1 frame or 3 points, or NaN or infinite coordinates.
    """
    arr = np.asarray(points, dtype=np.float64)
    if arr.ndim != 3 or arr.shape[2] != 2:
        raise ValueError(f"{name} must have shape (frames, points, 2) of pixel (x, y); got {arr.shape}")
    if arr.shape[0] < 1 or arr.shape[1] < 3:
        raise ValueError(f"{name} needs at least 1 frame of at least 3 points; got {arr.shape}")
    if not np.all(np.isfinite(arr)):
        bad = np.argwhere(~np.isfinite(arr).all(axis=2))[0]
        raise ValueError(f"{name} has NaN or infinite coordinates (first at frame {bad[0]}, point "
                         f"{bad[1]}); interpolate lost points or drop those frames")
    return arr


def default_weights(n_points: int) -> np.ndarray:
    """Procrustes weights per point (see the module notes).

    Parameters
    ----------
    n_points : int
        Number of landmarks P.

    Returns
    -------
    ndarray, shape (P,)
        For 68 points: 1 on :data:`voicepuppet.layout.RIGID` (nose, eye corners), 0.05
        elsewhere; for any other layout all ones.
    """
    if n_points == 68:
        w = np.full(68, 0.05)
        w[list(RIGID)] = 1.0
        return w
    return np.ones(n_points)


def _align(z: np.ndarray, ref: np.ndarray, w: np.ndarray):
    """Similarity fit of complex shapes ``z [T, P]`` onto ``ref [P]`` (weighted, ref centred).

    Returns the aligned shapes ``a·(z − c)`` and the per-frame ``a`` (complex: scale and rotation)
    and centroid ``c``.
    """
    c = (z * w).sum(axis=1, keepdims=True) / w.sum()
    zc = z - c
    num = (w * np.conj(zc) * ref).sum(axis=1)
    den = (w * np.abs(zc) ** 2).sum(axis=1)
    if np.any(den <= 1e-12 * max(1.0, float(den.max()))):
        t = int(np.argmax(den <= 1e-12 * max(1.0, float(den.max()))))
        raise ValueError(f"frame {t}: the landmarks all coincide (no extent to fit a pose to); "
                         "check the tracking")
    a = num / den
    return a[:, None] * zc, a, c[:, 0]


def shape_distance(shapes, rest) -> np.ndarray:
    """How far each shape of ``shapes`` (N, P, 2) is from ``rest`` (P, 2) once the best
    similarity (translation, scale, rotation; every point weighed alike) maps it onto ``rest``:
    the residual's RMS over the points relative to ``rest``'s RMS radius, (N,).

    Parameters
    ----------
    shapes : array_like, shape (N, P, 2)
        Shapes, pixel coordinates.
    rest : array_like, shape (P, 2)
        The reference shape.

    Returns
    -------
    ndarray, shape (N,)
        Relative residual of each shape (0: a similar copy of ``rest``).

    Raises
    ------
    ValueError
        ``shapes`` not finite landmarks (see :func:`check_landmarks`), or a shape whose points
        all coincide.
    """
    S = check_landmarks(shapes, "shapes")
    r = np.asarray(rest, dtype=np.float64)
    w = r[:, 0] + 1j * r[:, 1]
    w = w - w.mean()
    aligned, _, _ = _align(S[..., 0] + 1j * S[..., 1], w, np.ones(S.shape[1]))
    return np.sqrt((np.abs(aligned - w) ** 2).sum(axis=1) / max(float((np.abs(w) ** 2).sum()), 1e-300))


@dataclass
class FaceSpace:
    """Head-pose normalisation and a per-part principal-component basis of face shapes.

    Build with :meth:`fit` (or :meth:`from_arrays`). Attributes are plain arrays (a puppet
    file stores them); each parameter is kept as the attribute of the same name.

    Parameters
    ----------
    mean_shape : ndarray, shape (P, 2)
        Normalised mean shape (weighted centroid at the origin, average training size).
    weights : ndarray, shape (P,)
        Procrustes weights.
    mean_pose : ndarray, shape (4,)
        Average training pose ``(log s, θ, tx, ty)``, used when decoding without a pose.
    parts : list of ndarray
        Point indices of each part (a partition of ``range(P)``).
    part_names : list of str
        A name per part.
    bases : list of ndarray, shape (K_p, 2 P_p)
        Orthonormal rows: coordinates ``y = basis · (shape_p − mean_p)`` (x, y interleaved).
    variances : list of ndarray, shape (K_p,)
        Training variance along each basis row (default empty).

    Attributes
    ----------
    n_points : int
        P.
    n_dims : int
        K: face coordinates per frame (all parts).
    part_slices : list of slice
        Column slice of each part within the face coordinates.
    """

    mean_shape: np.ndarray
    weights: np.ndarray
    mean_pose: np.ndarray
    parts: list
    part_names: list
    bases: list
    variances: list = field(default_factory=list)

    # ------------------------------------------------------------------------------- building
    @classmethod
    def fit(cls, points_list, n_components=None, *, max_components: int | None = None,
            parts=None, weights=None, n_iter: int = 10) -> "FaceSpace":
        """Fit the mean shape (generalised Procrustes) and the per-part bases.

        Parameters
        ----------
        points_list : array (T, P, 2) or list of them
            Training landmarks, pixel coordinates; all sequences share the layout.
        n_components : None, int or float in (0, 1]
            Basis size per part: None keeps every direction (no reduction; the coordinates are
            the normalised shape itself, up to rotation), an int keeps that many, a float keeps
            the fewest components explaining that fraction of the variance.
        max_components : int, optional
            Upper bound on the basis size per part.
        parts : None, "upper_lower" or dict name -> point indices
            None: one part with every point. "upper_lower": the iBUG-68 upper/lower split.
        weights : array (P,), optional
            Procrustes weights (default :func:`default_weights`).
        n_iter : int
            Generalised Procrustes iterations (default 10).

        Returns
        -------
        FaceSpace
            The fitted face space.

        Raises
        ------
        ValueError
            No sequence or fewer than 2 frames in all, landmarks that are not finite (T, P, 2)
            arrays, sequences with different P, invalid ``weights``, ``parts``,
            ``n_components`` or ``max_components``, or a frame whose points all coincide.
        """
        if isinstance(points_list, np.ndarray) or not isinstance(points_list, (list, tuple)):
            points_list = [points_list]
        if not points_list:
            raise ValueError("FaceSpace.fit needs at least one landmark sequence")
        arrays = [check_landmarks(p, f"points_list[{i}]") for i, p in enumerate(points_list)]
        P = arrays[0].shape[1]
        for i, a in enumerate(arrays):
            if a.shape[1] != P:
                raise ValueError(f"points_list[{i}] has {a.shape[1]} points but the first sequence "
                                 f"has {P}; all sequences must share one landmark layout")
        pts = np.concatenate(arrays)
        if pts.shape[0] < 2:
            raise ValueError("FaceSpace.fit needs at least 2 frames")
        w = default_weights(P) if weights is None else np.asarray(weights, dtype=np.float64)
        if w.shape != (P,) or not np.all(np.isfinite(w)) or np.any(w < 0) or w.sum() <= 0:
            raise ValueError(f"weights must be {P} finite non-negative numbers, not all zero")
        part_idx, names = _parse_parts(parts, P)

        z = pts[..., 0] + 1j * pts[..., 1]
        c = (z * w).sum(axis=1, keepdims=True) / w.sum()
        size = np.sqrt((w * np.abs(z - c) ** 2).sum(axis=1) / w.sum())
        ref = z[0] - c[0]
        for _ in range(max(1, int(n_iter))):
            aligned, a, _ = _align(z, ref, w)
            new = aligned.mean(axis=0)
            new -= (new * w).sum() / w.sum()
            # Keep the first frame's orientation and the average training size.
            rot = np.vdot(new, ref)  # conj(new)·ref
            new *= rot / abs(rot) if abs(rot) > 0 else 1.0
            new *= size.mean() / np.sqrt((w * np.abs(new) ** 2).sum() / w.sum())
            if np.allclose(new, ref, atol=1e-10 * size.mean()):
                ref = new
                break
            ref = new
        aligned, a, c = _align(z, ref, w)
        inv = 1.0 / a
        mean_pose = np.array([np.mean(np.log(np.abs(inv))), _mean_angle(np.angle(inv)),
                              c.real.mean(), c.imag.mean()])
        mean_shape = np.stack([ref.real, ref.imag], axis=1)
        shapes = np.stack([aligned.real, aligned.imag], axis=2)  # [T, P, 2]

        bases, variances = [], []
        for idx in part_idx:
            X = shapes[:, idx, :].reshape(len(shapes), -1) - mean_shape[idx].reshape(-1)
            _, s, vt = np.linalg.svd(X, full_matrices=False)
            var = s ** 2 / max(len(X) - 1, 1)
            k = _n_keep(var, n_components, max_components, X.shape[1])
            bases.append(np.ascontiguousarray(vt[:k]))
            variances.append(var[:k])
        return cls(mean_shape, w, mean_pose, [np.asarray(i, dtype=np.int64) for i in part_idx],
                   names, bases, variances)

    # ---------------------------------------------------------------------------- properties
    @property
    def n_points(self) -> int:
        """P: landmarks per frame."""
        return int(self.mean_shape.shape[0])

    @property
    def n_dims(self) -> int:
        """K: face coordinates per frame (all parts)."""
        return int(sum(b.shape[0] for b in self.bases))

    @property
    def part_slices(self) -> list:
        """Column slice of each part within the face coordinates."""
        out, start = [], 0
        for b in self.bases:
            out.append(slice(start, start + b.shape[0]))
            start += b.shape[0]
        return out

    # ----------------------------------------------------------------------------- mappings
    def normalize(self, points):
        """Remove the head pose.

        Parameters
        ----------
        points : array_like, shape (T, P, 2)
            Pixel landmarks in the layout the space was fitted on.

        Returns
        -------
        shapes : ndarray, shape (T, P, 2)
            Normalised shapes (fitted onto :attr:`mean_shape`).
        pose : ndarray, shape (T, 4)
            Pose per frame, ``(log s, θ, tx, ty)``.

        Raises
        ------
        ValueError
            Landmarks that are not finite (T, P, 2) with this space's P, or a frame whose points
            all coincide.
        """
        pts = self._check(points)
        z = pts[..., 0] + 1j * pts[..., 1]
        ref = self.mean_shape[:, 0] + 1j * self.mean_shape[:, 1]
        aligned, a, c = _align(z, ref, self.weights)
        inv = 1.0 / a
        pose = np.stack([np.log(np.abs(inv)), np.angle(inv), c.real, c.imag], axis=1)
        return np.stack([aligned.real, aligned.imag], axis=2), pose

    def encode(self, points):
        """Face coordinates and pose.

        Parameters
        ----------
        points : array_like, shape (T, P, 2)
            Pixel landmarks in the layout the space was fitted on.

        Returns
        -------
        Y : ndarray, shape (T, K)
            Face coordinates (the parts' coordinates side by side, :attr:`part_slices`).
        pose : ndarray, shape (T, 4)
            Pose per frame, ``(log s, θ, tx, ty)``.

        Raises
        ------
        ValueError
            As for :meth:`normalize`.
        """
        shapes, pose = self.normalize(points)
        cols = [(shapes[:, idx, :].reshape(len(shapes), -1) - self.mean_shape[idx].reshape(-1)) @ b.T
                for idx, b in zip(self.parts, self.bases)]
        return np.concatenate(cols, axis=1), pose

    def shapes(self, Y) -> np.ndarray:
        """Normalised shapes from face coordinates.

        Parameters
        ----------
        Y : array_like, shape (T, K)
            Face coordinates.

        Returns
        -------
        ndarray, shape (T, P, 2)
            Normalised shapes (no pose).

        Raises
        ------
        ValueError
            ``Y`` not of shape (T, K).
        """
        Y = np.asarray(Y, dtype=np.float64)
        if Y.ndim != 2 or Y.shape[1] != self.n_dims:
            raise ValueError(f"face coordinates must have shape (frames, {self.n_dims}); got {Y.shape}")
        out = np.empty((Y.shape[0], self.n_points, 2))
        for idx, b, sl in zip(self.parts, self.bases, self.part_slices):
            out[:, idx, :] = (Y[:, sl] @ b + self.mean_shape[idx].reshape(-1)).reshape(len(Y), -1, 2)
        return out

    def decode(self, Y, pose=None) -> np.ndarray:
        """Pixel landmarks from face coordinates, at a pose.

        Parameters
        ----------
        Y : array_like, shape (T, K)
            Face coordinates.
        pose : array_like, shape (T, 4) or (4,), optional
            Pose ``(log s, θ, tx, ty)`` per frame or for all frames (default: the mean training
            pose, :attr:`mean_pose`).

        Returns
        -------
        ndarray, shape (T, P, 2)
            Pixel landmarks.

        Raises
        ------
        ValueError
            ``Y`` not of shape (T, K), or ``pose`` not finite of shape (4,) or (T, 4).
        """
        s = self.shapes(Y)
        pose = self.mean_pose if pose is None else np.asarray(pose, dtype=np.float64)
        pose = np.broadcast_to(pose, (len(s), 4)) if pose.ndim == 1 else pose
        if pose.shape != (len(s), 4) or not np.all(np.isfinite(pose)):
            raise ValueError(f"pose must be finite, shape (4,) or ({len(s)}, 4); got {pose.shape}")
        m = np.exp(pose[:, 0] + 1j * pose[:, 1])[:, None]
        z = m * (s[..., 0] + 1j * s[..., 1]) + (pose[:, 2] + 1j * pose[:, 3])[:, None]
        return np.stack([z.real, z.imag], axis=2)

    def _check(self, points) -> np.ndarray:
        pts = check_landmarks(points)
        if pts.shape[1] != self.n_points:
            raise ValueError(f"these landmarks have {pts.shape[1]} points but the face space was "
                             f"fitted on {self.n_points}; use the same landmark layout")
        return pts

    # ---------------------------------------------------------------------------- storage
    def to_arrays(self, prefix: str = "face/") -> dict:
        """Plain arrays for a puppet file (see :meth:`from_arrays`).

        Parameters
        ----------
        prefix : str
            Prefix of every key (default ``"face/"``).

        Returns
        -------
        dict
            Keys ``{prefix}mean_shape``, ``{prefix}weights``, ``{prefix}mean_pose`` and, for
            each part k, ``{prefix}part{k}/points``, ``{prefix}part{k}/basis`` and
            ``{prefix}part{k}/variances``. The part names are not included:
            :meth:`from_arrays` takes them separately.
        """
        out = {prefix + "mean_shape": self.mean_shape, prefix + "weights": self.weights,
               prefix + "mean_pose": self.mean_pose}
        for k, (idx, b, v) in enumerate(zip(self.parts, self.bases, self.variances)):
            out[f"{prefix}part{k}/points"] = idx.astype(np.int64)
            out[f"{prefix}part{k}/basis"] = b
            out[f"{prefix}part{k}/variances"] = v
        return out

    @classmethod
    def from_arrays(cls, arrays: dict, part_names, prefix: str = "face/") -> "FaceSpace":
        """The face space stored by :meth:`to_arrays`.

        Parameters
        ----------
        arrays : mapping
            The arrays (e.g. an open puppet ``.npz``).
        part_names : list of str
            The parts' names, in order (one per stored part).
        prefix : str
            Prefix of every key (default ``"face/"``).

        Returns
        -------
        FaceSpace
            The stored face space.
        """
        parts, bases, variances = [], [], []
        for k in range(len(part_names)):
            parts.append(np.asarray(arrays[f"{prefix}part{k}/points"], dtype=np.int64))
            bases.append(np.asarray(arrays[f"{prefix}part{k}/basis"], dtype=np.float64))
            variances.append(np.asarray(arrays[f"{prefix}part{k}/variances"], dtype=np.float64))
        return cls(np.asarray(arrays[prefix + "mean_shape"]), np.asarray(arrays[prefix + "weights"]),
                   np.asarray(arrays[prefix + "mean_pose"]), parts, list(part_names), bases, variances)


def _mean_angle(theta: np.ndarray) -> float:
    return float(np.angle(np.mean(np.exp(1j * theta))))


def _parse_parts(parts, P: int):
    if parts is None:
        return [np.arange(P)], ["face"]
    if isinstance(parts, str):
        if parts != "upper_lower":
            raise ValueError(f"parts must be None, 'upper_lower' or a dict name -> point indices; "
                             f"got {parts!r}")
        if P != 68:
            raise ValueError(f"parts='upper_lower' needs the 68-point iBUG layout; these landmarks "
                             f"have {P} points (give parts as a dict instead)")
        parts = IBUG68_PARTS
    names, idx = [], []
    seen = np.zeros(P, dtype=int)
    for name, ids in dict(parts).items():
        ids = np.asarray(ids, dtype=np.int64).ravel()
        if ids.size < 2 or ids.min() < 0 or ids.max() >= P:
            raise ValueError(f"part {name!r} must list at least 2 point indices in [0, {P}); got {ids.tolist()}")
        seen[ids] += 1
        names.append(str(name))
        idx.append(np.sort(ids))
    if np.any(seen != 1):
        bad = np.flatnonzero(seen != 1)[:5].tolist()
        raise ValueError(f"parts must partition the {P} points (each in exactly one part); points "
                         f"{bad} are in none or several")
    return idx, names


def _n_keep(var: np.ndarray, n_components, max_components, full: int) -> int:
    k = full
    if n_components is not None:
        if isinstance(n_components, (float, np.floating)) and 0 < n_components <= 1 and not float(n_components).is_integer():
            total = var.sum()
            k = full if total <= 0 else int(np.searchsorted(np.cumsum(var) / total, n_components) + 1)
        elif int(n_components) == n_components and n_components >= 1:
            k = int(n_components)
        else:
            raise ValueError(f"n_components must be None, a positive int or a fraction in (0, 1); "
                             f"got {n_components!r}")
    if max_components is not None:
        if int(max_components) < 1:
            raise ValueError(f"max_components must be >= 1, got {max_components!r}")
        k = min(k, int(max_components))
    return max(1, min(k, full, len(var)))


def observations(Y, lengths=None) -> np.ndarray:
    """HMM observations ``o_t = [y_t, y_t − y_{t−1}]`` (pose and velocity), shape (T, 2K).

    The first frame of each sequence has no predecessor; it takes the velocity of the
    sequence's second frame (zero for a one-frame sequence).

    Parameters
    ----------
    Y : array_like, shape (T, K)
        Face coordinates of one or more sequences, concatenated.
    lengths : array_like of int, optional
        Frames of each sequence (default one sequence of T frames); velocities do not cross
        sequence boundaries.

    Returns
    -------
    ndarray, shape (T, 2K)
        ``[Y, V]``: coordinates and velocities side by side.

    Raises
    ------
    ValueError
        ``Y`` not 2-D with at least one frame, or ``lengths`` not positive or not summing to T.
    """
    Y = np.asarray(Y, dtype=np.float64)
    if Y.ndim != 2 or Y.shape[0] == 0:
        raise ValueError(f"face coordinates must have shape (frames, dims); got {Y.shape}")
    lengths = [len(Y)] if lengths is None else [int(n) for n in np.asarray(lengths).ravel()]
    if sum(lengths) != len(Y) or min(lengths) < 1:
        raise ValueError(f"lengths {lengths} must be positive and sum to the {len(Y)} frames")
    V = np.zeros_like(Y)
    start = 0
    for n in lengths:
        seg = slice(start, start + n)
        if n > 1:
            V[start + 1:start + n] = np.diff(Y[seg], axis=0)
            V[start] = V[start + 1]
        start += n
    return np.hstack([Y, V])
