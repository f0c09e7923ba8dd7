"""The live benchmark's cached puppets follow their corpus: a rebuilt corpus (another key in its
corpus.json) trains them again instead of loading a puppet of the old one."""
import json
from types import SimpleNamespace

import numpy as np
import soundfile as sf

from support import FPS, RATE, performance
from voicepuppet.bench.live import _cached_puppet


def test_cached_puppet_is_keyed_by_corpus_and_options(tmp_path):
    pts, audio, _ = performance(np.random.default_rng(5), 300)
    sf.write(tmp_path / "train.wav", audio, RATE)
    corpus = SimpleNamespace(out_dir=str(tmp_path),
                             train=SimpleNamespace(points=pts, audio=str(tmp_path / "train.wav"), fps=FPS))
    (tmp_path / "corpus.json").write_text(json.dumps({"key": "aaaa"}))
    first = _cached_puppet(corpus, quick=True)
    assert len(list(tmp_path.glob("puppet-*.vpp"))) == 1
    again = _cached_puppet(corpus, quick=True)  # loaded, not trained again
    assert again.arrays.keys() == first.arrays.keys()
    assert all(np.array_equal(again.arrays[k], first.arrays[k]) for k in first.arrays)
    projected = _cached_puppet(corpus, quick=True, vocal_features="projected", vocal_covariance="tied")
    assert projected._core.projected and not first._core.projected
    assert first._core.guided and projected._core.guided  # the default training: they stream guided
    assert len(list(tmp_path.glob("puppet-*.vpp"))) == 2
    (tmp_path / "corpus.json").write_text(json.dumps({"key": "bbbb"}))  # the corpus was rebuilt
    _cached_puppet(corpus, quick=True)
    assert len(list(tmp_path.glob("puppet-*.vpp"))) == 3
