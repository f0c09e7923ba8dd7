"""Re-acquisition: finding a lost face again by a whole-frame search for its first-frame look.

When most of the mesh's points have been lost for a few frames (the face left the frame or was
covered), the tracker looks for the first frame's face region over each following frame
(:class:`FaceSearch`) and restarts the mesh where it is found. The constants below set when the
search starts and what it accepts.
"""

from __future__ import annotations

import numpy as np

__all__ = ["FaceSearch", "REACQUIRE_LOST_SHARE", "REACQUIRE_FRAMES", "REACQUIRE_NCC", "REACQUIRE_LEVEL",
           "REACQUIRE_MARGIN", "REACQUIRE_ANGLES", "REACQUIRE_SCALES"]


# Re-acquisition: when more than REACQUIRE_LOST_SHARE of the points have been lost for
# REACQUIRE_FRAMES frames in a row (the face left the frame or was covered), every following
# frame is searched for the first frame's face region (the bounding box of the first-frame
# points, REACQUIRE_MARGIN of its size added on each side), seen through 25 in-plane rotations
# and scales (REACQUIRE_ANGLES x REACQUIRE_SCALES about the points' centroid), by normalised
# cross-correlation (cv2.matchTemplate, TM_CCOEFF_NORMED) at pyramid level REACQUIRE_LEVEL
# (1/4 size), the best peak refined at full size within one coarse step; a peak of at least
# REACQUIRE_NCC restarts the mesh there (the first-frame points through the found similarity,
# SpringMeshTracker.relocate) and the frame is tracked again from it. Until then every point of
# the frames in the run is lost. The share is above puppet_cli's training cut (0.3): a partial
# occlusion that leaves most points found never searches (the performer's clips and carphone:
# at most 0.12 and 0.37 of a frame's points lost). REACQUIRE_NCC lies between the highest
# peak on faceless images (0.48 over 14 scikit-image pictures, 0.39 on a card of smooth noise,
# 0.38 on another face, carphone's) and the lowest of the performer's face back in the frame
# (0.84 over rotations to 20 degrees and scales 0.85-1.3; upright 0.905): docs/tracking.md,
# "Re-acquiring a lost face".
REACQUIRE_LOST_SHARE = 0.5
REACQUIRE_FRAMES = 3
REACQUIRE_NCC = 0.65
REACQUIRE_LEVEL = 2
REACQUIRE_MARGIN = 0.1
REACQUIRE_ANGLES = (0.0, -10.0, 10.0, -20.0, 20.0)
REACQUIRE_SCALES = (1.0, 0.89, 1.12, 0.8, 1.25)


class FaceSearch:
    """The whole-frame search for a lost face: the first frame's face region (bounding box of
    the first-frame points plus :data:`REACQUIRE_MARGIN`), seen through each in-plane rotation
    of :data:`REACQUIRE_ANGLES` and scale of :data:`REACQUIRE_SCALES` about the points' centroid,
    matched by normalised cross-correlation over the frame at pyramid level
    :data:`REACQUIRE_LEVEL`; the best peak is refined at full size within one coarse step.
    ``find`` returns the first-frame points mapped to where the face is, and the full-size
    correlation, or None when the best coarse peak is below :data:`REACQUIRE_NCC`.

    Needs OpenCV (``opencv-contrib-python-headless``).

    Parameters
    ----------
    first : ndarray, shape (H, W), uint8
        The first frame, grey.
    init : ndarray, shape (P, 2)
        The first-frame points (x, y).

    Attributes
    ----------
    hypotheses : list of tuple
        One per rotation and scale: the (2, 3) map of the first frame, its template, the
        template at the search's pyramid level, and the template's top-left corner (x, y).
    """

    def __init__(self, first: np.ndarray, init: np.ndarray):
        import cv2

        self._cv2 = cv2
        h, w = first.shape
        centre = init.mean(axis=0)
        self.hypotheses = []  # (2x3 map of the first frame, template, coarse template, origin)
        for scale in REACQUIRE_SCALES:
            for angle in REACQUIRE_ANGLES:
                M = cv2.getRotationMatrix2D((float(centre[0]), float(centre[1])), float(angle), float(scale))
                seen = first if angle == 0 and scale == 1 else cv2.warpAffine(
                    first, M, (w, h), flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
                pts = init @ M[:, :2].T + M[:, 2]
                lo, hi = pts.min(axis=0), pts.max(axis=0)
                pad = REACQUIRE_MARGIN * (hi - lo)
                x0, y0 = np.floor(np.maximum(lo - pad, 0)).astype(int)
                x1, y1 = np.ceil(np.minimum(hi + pad, [w - 1, h - 1])).astype(int)
                template = np.ascontiguousarray(seen[y0:y1 + 1, x0:x1 + 1])
                self.hypotheses.append((M, template, self._down(template), np.array([x0, y0])))

    def _down(self, image: np.ndarray) -> np.ndarray:
        for _ in range(REACQUIRE_LEVEL):
            image = self._cv2.pyrDown(image)
        return image

    def peak(self, frame: np.ndarray) -> tuple[float, int, np.ndarray] | None:
        """The best coarse correlation peak over the frame.

        Parameters
        ----------
        frame : ndarray, shape (H, W), uint8
            A grey frame.

        Returns
        -------
        tuple of (float, int, ndarray of shape (2,)) or None
            The peak's correlation, the index of its hypothesis and its template's top-left
            corner in full-size pixels; None when the frame is smaller than every template.
        """
        small = self._down(frame)
        best = None
        for k, (_, _, coarse, _) in enumerate(self.hypotheses):
            th, tw = coarse.shape
            if small.shape[0] < th or small.shape[1] < tw or min(th, tw) < 4:
                continue
            score = self._cv2.matchTemplate(small, coarse, self._cv2.TM_CCOEFF_NORMED)
            _, value, _, (bx, by) = self._cv2.minMaxLoc(score)
            if best is None or value > best[0]:
                best = (float(value), k, np.array([bx, by]) * (1 << REACQUIRE_LEVEL))
        return best

    def find(self, frame: np.ndarray, init: np.ndarray) -> tuple[np.ndarray, float] | None:
        """Where the face is on a frame, if the search finds it.

        Parameters
        ----------
        frame : ndarray, shape (H, W), uint8
            A grey frame.
        init : ndarray, shape (P, 2)
            The first-frame points the search was built from.

        Returns
        -------
        tuple of (ndarray of shape (P, 2), float) or None
            The first-frame points mapped to where the face is, and the full-size correlation
            there; None when the best coarse peak is below :data:`REACQUIRE_NCC`.
        """
        found = self.peak(frame)
        if found is None or not found[0] >= REACQUIRE_NCC:
            return None
        M, template, _, origin = self.hypotheses[found[1]]
        step = 1 << REACQUIRE_LEVEL
        th, tw = template.shape
        h, w = frame.shape
        x0, y0 = np.clip(found[2] - step, 0, [w - tw, h - th])
        x1, y1 = np.clip(found[2] + step, 0, [w - tw, h - th])
        window = frame[y0:y1 + th, x0:x1 + tw]
        score = self._cv2.matchTemplate(window, template, self._cv2.TM_CCOEFF_NORMED)
        _, value, _, (bx, by) = self._cv2.minMaxLoc(score)
        shift = np.array([x0 + bx, y0 + by], dtype=np.float64) - origin
        return init @ M[:, :2].T + M[:, 2] + shift, float(value)
