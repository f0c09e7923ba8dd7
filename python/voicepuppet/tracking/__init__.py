"""Tracking: video in, 68 landmarks per frame out (Voice Puppetry §4.1).

Video reading (:mod:`.video`), face detection and initialisation, the spring-mesh SSD tracker's
orchestration around the C++ kernel, re-acquisition, and landmark files.
"""

from voicepuppet.tracking.tracker import (NoFaceError, TrackResult, VariableFrameRateWarning, auto_init,
                                          first_face, load_init_points, load_landmarks, on_uniform_grid,
                                          save_landmarks, track_frames, track_video)

__all__ = ["NoFaceError", "TrackResult", "VariableFrameRateWarning", "auto_init", "first_face",
           "load_init_points", "load_landmarks", "on_uniform_grid", "save_landmarks", "track_frames",
           "track_video"]
