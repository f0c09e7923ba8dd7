"""``voicepuppet bench peers``: its cases in the bench JSON schema (DESIGN.md, "Benchmarks"), on a
small planted performance; the suite says what is missing when Rhubarb or PyTorch is."""
import json
from types import SimpleNamespace

import numpy as np
import pytest
import soundfile as sf

from support import FPS, RATE, performance
from voicepuppet.bench import peers
from voicepuppet.cli.main import main
from voicepuppet.evaluation.rhubarb import RECOGNIZERS, RhubarbError, find_rhubarb


def _small_corpus(tmp_path):
    rng = np.random.default_rng(7)
    pts, audio, _ = performance(rng, 450)  # 40 states need 400 frames
    _, test, _ = performance(rng, 90)
    sf.write(tmp_path / "train.wav", audio, RATE)
    sf.write(tmp_path / "test.wav", test, RATE)
    return SimpleNamespace(train=SimpleNamespace(points=pts, audio=str(tmp_path / "train.wav"), fps=FPS),
                           test=[SimpleNamespace(audio=str(tmp_path / "test.wav"))])


@pytest.mark.skipif(find_rhubarb() is None, reason="Rhubarb Lip Sync not found: set VOICEPUPPET_RHUBARB or put "
                                                   "it at ../shared/peers/rhubarb/rhubarb")
def test_bench_peers_json_schema(tmp_path, monkeypatch, capsys):
    pytest.importorskip("torch")
    monkeypatch.setattr(peers, "_corpus", lambda seconds, n_test: _small_corpus(tmp_path))
    out = tmp_path / "peers.json"
    assert main(["bench", "peers", "--quick", "--repeats", "1", "--json", str(out)]) == 0
    doc = json.loads(out.read_text())
    assert doc["suite"] == "peers" and {"platform", "cpus", "core"} <= set(doc["machine"])
    names = [c["name"] for c in doc["cases"]]
    assert names == ["train: learned", "animate: learned", *(f"animate: {r}" for r in RECOGNIZERS)]
    for c in doc["cases"]:
        assert {"name", "size", "ours_s", "peer", "peer_s", "ratio", "agree"} <= set(c)
        assert c["ours_s"] > 0 and c["peer_s"] > 0 and c["ratio"] == pytest.approx(c["peer_s"] / c["ours_s"])
        assert c["agree"] is None and c["realtime_factor"] > 0 and c["peer_realtime_factor"] > 0
    for c in doc["cases"][1:]:
        assert c["seconds_per_audio_second"] == pytest.approx(1 / c["realtime_factor"])
        assert "3.6 s of held-out speech" in c["size"]


def test_bench_peers_says_what_is_missing(monkeypatch, tmp_path):
    monkeypatch.setenv("VOICEPUPPET_RHUBARB", str(tmp_path / "nowhere"))
    with pytest.raises(RhubarbError, match="not at .*nowhere"):
        peers.run(quick=True, repeats=1)
