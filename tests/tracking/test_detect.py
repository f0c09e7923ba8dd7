"""Face detection comes with pip install: dlib's wheel and its 68-point model from PyPI, without
Debian's libdlib-data or any setting."""

import numpy as np
import pytest

from voicepuppet.tracking import detect


def test_the_model_comes_with_the_python_install(monkeypatch):
    monkeypatch.setattr(detect, "DLIB_MODEL_PATHS", ())
    monkeypatch.delenv("VOICEPUPPET_DLIB_MODEL", raising=False)
    model = detect.landmark_model()
    assert model is not None and "face_recognition_models" in model and model.endswith(detect.DLIB_MODEL_NAME)


def test_a_real_face_is_found_with_the_pip_model_alone(monkeypatch):
    """The astronaut photo (a real face): 68 points around her face, from the pip-installed model."""
    import cv2
    from skimage import data

    monkeypatch.setattr(detect, "DLIB_MODEL_PATHS", ())
    monkeypatch.delenv("VOICEPUPPET_DLIB_MODEL", raising=False)
    grey = cv2.cvtColor(data.astronaut(), cv2.COLOR_RGB2GRAY)
    points = detect.auto_init(grey)
    assert points.shape == (68, 2)
    # her face, not the badge: eyes above the mouth, about 50 px apart, in the upper middle
    eyes, mouth = points[36:48].mean(axis=0), points[48:68].mean(axis=0)
    assert eyes[1] < mouth[1] and 30 < np.linalg.norm(points[36] - points[45]) < 90
    assert 150 < eyes[0] < 280 and 60 < eyes[1] < 160


def test_no_model_anywhere_is_a_clear_error(monkeypatch, tmp_path):
    monkeypatch.setattr(detect, "DLIB_MODEL_PATHS", ())
    monkeypatch.setattr(detect, "DLIB_MODEL_NAME", "no_such_model.dat")
    monkeypatch.delenv("VOICEPUPPET_DLIB_MODEL", raising=False)
    assert detect.landmark_model() is None
    with pytest.raises(ValueError, match="pip install face-recognition-models.*--init points.json"):
        detect.auto_init(np.zeros((64, 64), np.uint8))
    monkeypatch.setenv("VOICEPUPPET_DLIB_MODEL", str(tmp_path / "mine.dat"))
    (tmp_path / "mine.dat").write_bytes(b"")
    assert detect.landmark_model() == str(tmp_path / "mine.dat")
