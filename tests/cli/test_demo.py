"""The demo end to end on a small corpus and three of the real recordings (the full one is
`voicepuppet demo`)."""
import json
import subprocess

import numpy as np
import pytest

from voicepuppet import synth
from voicepuppet.cli import demo
from voicepuppet.cli.main import main
from voicepuppet.evaluation import real
from voicepuppet.tracking import video as tracking_video

pytestmark = pytest.mark.skipif(not synth.espeak_available(),
                                reason="the synthetic performer needs espeak-ng (apt-get install espeak-ng)")


@pytest.fixture
def small_recordings(tmp_path_factory, monkeypatch):
    """Three of the real recordings in two of Obama's sessions (the weekly address, 8 s; two
    sentence cuts, 4.7 s), made as the package's folder; their tracks in a cache of their own."""
    root = tmp_path_factory.mktemp("recordings")
    index = json.loads((real.RECORDINGS / "index.json").read_text())["clips"]
    keep = {k: index[k] for k in ("obama/weekly_address_8s", "obama/sentence_2", "obama/sentence_5")}
    (root / "index.json").write_text(json.dumps({"clips": keep}))
    (root / "reference.npz").symlink_to(real.RECORDINGS / "reference.npz")
    (root / "obama").mkdir()
    for info in keep.values():
        (root / info["file"]).symlink_to(real.RECORDINGS / info["file"])
    monkeypatch.setenv("VOICEPUPPET_CACHE", str(tmp_path_factory.mktemp("cache")))
    return root


def _streams(path):
    """(video frames, seconds, whether there is an audio stream) of an mp4, by FFmpeg."""
    import imageio_ffmpeg

    frames, seconds = imageio_ffmpeg.count_frames_and_secs(str(path))
    probe = subprocess.run([imageio_ffmpeg.get_ffmpeg_exe(), "-hide_banner", "-i", str(path)],
                           capture_output=True, text=True).stderr
    return frames, seconds, "Audio:" in probe


@pytest.mark.slow
def test_demo_writes_everything(tmp_path, small_recordings):
    logs = []
    s = demo.run(tmp_path, train_seconds=12, n_test=1, n_states=6, compare_conventional=False,
                 progress=False, log=logs.append, real_root=small_recordings)
    for name in ("puppet.vpp", "animation.npz", "heldout.wav", "demo.mp4", "head.mp4", "real.mp4", "metrics.json",
                 "results.md"):
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
    assert any("[5/6]" in line for line in logs) and any("[6/6]" in line for line in logs)
    # The real person: the session with the fewest frames (the two sentence cuts, 140 frames) is
    # held out and its longer clip shown; its puppet learnt from the other session only.
    video = saved["real"]["video"]
    assert video["clip"] == "obama/sentence_5" and video["trained_on"] == ["obama/weekly_address_8s"]
    assert video["frames"] == 74 and video["fps"] == 29.97
    assert video["size"] == [1280, 360]  # each side 640 x 360, the recording's 1280 x 720 halved
    frames, seconds, sound = _streams(tmp_path / "real.mp4")
    assert frames == 74 and seconds == pytest.approx(74 / 29.97, abs=0.05) and sound
    info = tracking_video.probe_video(tmp_path / "real.mp4")
    assert (info.width, info.height) == (1280, 360) and info.fps == pytest.approx(29.97, abs=0.01)
    # the real-data table: both sessions left out in turn, every model measured on all three clips
    loso = saved["real"]["evaluation"]["loso"]
    assert sorted(loso["sessions"]) == ["sentences", "weekly_address_8s"] and len(loso["clips"]) == 3
    assert set(video["measures"]) == set(real.MODELS) - {"rhubarb", "learned"}  # the peers need tools
    text = (tmp_path / "results.md").read_text()
    assert "## A real person" in text and "Leave one session out (obama, 3 held-out clips, 2 sessions)" in text
    assert f"Recordings of Barack Obama in {small_recordings}," in text
    assert "| voice puppet |" in text and "`real.mp4`: obama/sentence_5 (74 frames at 29.97 fps)" in text
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
                 render_video=False, progress=False, log=logs.append, real=False)
    assert calls == [(tmp_path / "out" / "corpus-real", 2)]
    assert "real recordings" in logs[0] and s["train_frames"] > 300 and "[1/5]" in logs[0] and "real" not in s
    # The option for voices never heard is measured beside the default on the real-speech split.
    assert sorted(s["models"]) == ["entropic", "projected"]
    assert "projected puppet" in (tmp_path / "out" / "results.md").read_text()
    with pytest.raises(ValueError, match="speech must be 'espeak' or 'real'"):
        demo.run(tmp_path, speech="klingon")


def test_demo_refuses_real_recordings_it_is_told_to_skip(capsys):
    assert main(["demo", "--no-real", "--real", "somewhere"]) == 2
    assert "--no-real" in capsys.readouterr().err
