"""Rendering: a textured face driven by landmark animations, drawn off screen and written as
video (Brand §4.6); interchange formats (:mod:`voicepuppet.render.export`).

The modules, in the order they build on each other:

- :mod:`.mesh`: :class:`FaceMesh`, the textured mesh in image coordinates, and its skin's depth.
- :mod:`.interior`: the mouth's interior behind the lips (cavity, tongue, teeth).
- :mod:`.photo`: the mesh from a photo and its landmarks (or a drawn portrait).
- :mod:`.retargeting`: the animation's motion carried onto the face (similarity transform),
  vertex driving by a thin-plate spline or through the action-unit basis, expressions.
- :mod:`.video`: the off-screen pyvista renderer, frames, ``.mp4`` / ``.gif`` / ``.png`` output.
- :mod:`.head`: the mesh from a textured 3-D head scan.
- :mod:`.faces`: the face a command names: a photo, a video's frame at rest, a head, a palette's.
- :mod:`voicepuppet.render.export`: landmarks, VTK series, glTF, ARKit weights, Rhubarb mouth cues.

``_backend`` (package-private) imports pyvista and sets it up for headless rendering.
"""

from voicepuppet.render.faces import REST_SCAN_S, REST_STRIDE_S, face_palette, load_face, resolve_face
from voicepuppet.render.head import HEAD_SUFFIXES, load_head, sample_head
from voicepuppet.render.interior import mouth_interior
from voicepuppet.render.mesh import FaceMesh, skin_depth
from voicepuppet.render.photo import OPEN_MOUTH_IOD, build_face_mesh, lip_gap_iod, portrait_image
from voicepuppet.render.retargeting import (ACTION_UNITS, action_unit_basis, expression_offset, fit_activations,
                                            mesh_animation, retarget, similarity)
from voicepuppet.render.video import (DEFAULT_MAX_SIZE, VIDEO_SUFFIXES, FaceRenderer, check_size, default_size,
                                      draw_landmarks_2d, render, render_frames, write_video)

__all__ = [
    # the mesh
    "FaceMesh", "skin_depth", "mouth_interior", "build_face_mesh", "portrait_image", "lip_gap_iod",
    "OPEN_MOUTH_IOD", "load_head", "sample_head", "HEAD_SUFFIXES",
    # driving it
    "ACTION_UNITS", "similarity", "retarget", "action_unit_basis", "fit_activations", "expression_offset",
    "mesh_animation",
    # drawing it
    "FaceRenderer", "draw_landmarks_2d", "render_frames", "write_video", "render", "check_size", "default_size",
    "DEFAULT_MAX_SIZE", "VIDEO_SUFFIXES",
    # the face a command names
    "load_face", "resolve_face", "face_palette", "REST_STRIDE_S", "REST_SCAN_S",
]
