"""Rendering: a face mesh from a photo or a head scan, driven by a landmark animation, drawn
with pyvista and written as video; interchange formats (:mod:`.export`)."""

from voicepuppet.render.mesh import FaceMesh, build_face_mesh, load_face, render, render_frames, write_video

__all__ = ["FaceMesh", "build_face_mesh", "load_face", "render", "render_frames", "write_video"]
