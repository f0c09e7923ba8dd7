"""Tracking: video in, 68 landmarks per frame out (Voice Puppetry §4.1).

The modules, by subject:

- :mod:`.video`: video reading (grey frames, frame times, frame rates) and overlay videos.
- :mod:`.detect`: face detection and initialisation with dlib (``--init auto``).
- :mod:`.springs`: the spring mesh's edges, and the lip and eye-corner handling of a 68-point face.
- :mod:`.scale`: the working scale at which a large face is tracked.
- :mod:`.reacquire`: the whole-frame search for a lost face.
- :mod:`.tracker`: the spring-mesh SSD tracker's passes around the C++ kernel.
- :mod:`.landmarks`: the tracker's result, landmark and init-point files, frame-rate regridding.
"""

from voicepuppet.tracking.detect import (DLIB_MODEL_PATHS, PROBE_MAX_PIXELS, SURE_FACE_SCORE, NoFaceError,
                                         auto_init, first_face)
from voicepuppet.tracking.landmarks import (TrackResult, load_init_points, load_landmarks, on_uniform_grid,
                                            save_landmarks)
from voicepuppet.tracking.scale import (LARGE_FACE_IOD, LARGE_FACE_RMS_RADIUS, WORKING_IOD, WORKING_RMS_RADIUS,
                                        face_size, points_to_full, points_to_working, working_scale_factor)
from voicepuppet.tracking.springs import delaunay_edges, eye_corner_sides, lip_patch_sides
from voicepuppet.tracking.tracker import VariableFrameRateWarning, track_frames, track_video

__all__ = ["TrackResult", "track_frames", "track_video", "VariableFrameRateWarning", "NoFaceError", "auto_init",
           "first_face", "load_init_points", "load_landmarks", "save_landmarks", "on_uniform_grid",
           "delaunay_edges", "lip_patch_sides", "eye_corner_sides", "face_size", "working_scale_factor",
           "points_to_working", "points_to_full", "DLIB_MODEL_PATHS", "PROBE_MAX_PIXELS", "SURE_FACE_SCORE",
           "LARGE_FACE_IOD", "WORKING_IOD", "LARGE_FACE_RMS_RADIUS", "WORKING_RMS_RADIUS"]
