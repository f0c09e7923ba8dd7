"""The demo end to end on a small corpus (the full one is `voicepuppet demo`)."""
import json

import numpy as np
import pytest

from voicepuppet import synth
from voicepuppet.cli import demo

pytestmark = pytest.mark.skipif(not synth.espeak_available(),
                                reason="the synthetic performer needs espeak-ng (apt-get install espeak-ng)")


@pytest.mark.slow
def test_demo_writes_everything(tmp_path):
    logs = []
    s = demo.run(tmp_path, train_seconds=12, n_test=1, n_states=6, compare_conventional=False,
                 progress=False, log=logs.append)
    for name in ("puppet.vpp", "animation.npz", "heldout.wav", "demo.mp4", "head.mp4", "metrics.json", "results.md"):
        assert (tmp_path / name).stat().st_size > 0, name
    saved = json.loads((tmp_path / "metrics.json").read_text())
    assert saved["train_frames"] == s["train_frames"] > 300
    rows = saved["models"]["entropic"]["rows"]
    assert set(rows) == {"states", "voice", "voice, most probable", "voice-posterior", "voice, unguided (Brand §4.5)",
                         "mean-face", "ridge"}
    for row in rows.values():
        assert all(np.isfinite(v) for split in row.values() for v in split.values())
    assert rows["mean-face"]["train"]["err"] == pytest.approx(1.0, abs=0.05)
    # the share of b, p, m whose lips close: never for the mean face (open), a share for the rest
    assert rows["mean-face"]["test"]["closed"] == 0.0
    assert all(0.0 <= row[split]["closed"] <= 1.0 for row in rows.values() for split in row)
    assert "closed train | closed test" in (tmp_path / "results.md").read_text()
    assert 0 < saved["tracker_rmse_iod"] < 0.2
    assert saved["trained_on"] == "tracked"  # the default: the puppet learns what the tracker found
    assert any("[5/5]" in line for line in logs)
    with pytest.raises(ValueError, match="train_on"):
        demo.run(tmp_path, train_on="guess")


def test_demo_with_real_speech_uses_the_real_speech_performer(tmp_path, monkeypatch):
    """``speech="real"`` builds its corpus with ``make_real_corpus`` in ``corpus-real`` (stood in
    for here by a small espeak corpus: the real one is tested in test_real_speech.py)."""
    calls, logs = [], []

    def small_real(out_dir, seed=0, progress=True):
        calls.append((out_dir, seed))
        return synth.make_corpus(tmp_path / "small", train_seconds=12, n_test=1, seed=0, real_test=False,
                                 progress=False)

    monkeypatch.setattr(synth, "make_real_corpus", small_real)
    s = demo.run(tmp_path / "out", speech="real", seed=2, n_states=6, compare_conventional=False,
                 render_video=False, progress=False, log=logs.append)
    assert calls == [(tmp_path / "out" / "corpus-real", 2)]
    assert "real recordings" in logs[0] and s["train_frames"] > 300
    # The option for voices never heard is measured beside the default on the real-speech split.
    assert sorted(s["models"]) == ["entropic", "projected"]
    assert "projected puppet" in (tmp_path / "out" / "results.md").read_text()
    with pytest.raises(ValueError, match="speech must be 'espeak' or 'real'"):
        demo.run(tmp_path, speech="klingon")
