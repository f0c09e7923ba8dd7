"""The real recordings that ship inside packages: the list and its files, their forced alignment
against the audio's energy, words the dictionary lacks, and the performer that speaks them."""

import numpy as np
import pytest
import soundfile as sf

from voicepuppet import synth
from voicepuppet.phonemes import labels as phonemes
from voicepuppet import data as samples
from voicepuppet.cli.main import main
from voicepuppet.evaluation.corpus import _label_readers, split_clip
from voicepuppet.synth.speech import recording_utterance

DURATIONS = {"arctic_a0009": 3.10, "arctic_a0007": 4.00, "librivox_0870": 7.10, "librivox_0880": 2.99,
             "librivox_0890": 5.30, "librivox_0920": 6.05, "librivox_0930": 3.29, "sonnet_1": 53.27}


@pytest.fixture(scope="module")
def recordings():
    return samples.real_recordings()


@pytest.fixture(scope="module")
def utterances(recordings):
    return {r.name: recording_utterance(r) for r in recordings}


def test_the_real_recordings_are_listed_with_their_words(recordings):
    assert [r.name for r in recordings] == list(samples.REAL_RECORDINGS) == list(DURATIONS)
    for r in recordings:
        info = sf.info(r.wav)
        assert info.samplerate == 16000 and info.channels == 1
        assert info.duration == pytest.approx(DURATIONS[r.name], abs=0.02), r.name
        assert len(r.text.split()) >= 7 and r.speaker and r.source
    assert len({r.speaker for r in recordings}) == 4
    assert [r.name for r in samples.real_recordings(["sonnet_1", "arctic_a0007"])] == ["sonnet_1", "arctic_a0007"]
    with pytest.raises(ValueError, match="unknown recordings \\['a0001'\\]"):
        samples.real_recordings(["a0001"])


def _speech_vs_pause_db(u, shift=0.0):
    """Median 10 ms energy inside the phones over that inside the pauses (dB)."""
    hop = u.rate // 100
    x = u.samples.astype(np.float64)
    e = np.array([np.mean(x[i:i + hop] ** 2) for i in range(0, len(x) - hop, hop)]) + 1e-10
    t = (np.arange(len(e)) + 0.5) / 100
    speech = np.zeros(len(e), bool)
    for p in u.phones:
        if p.label != "_":
            speech |= (t >= p.start + shift) & (t < p.end + shift)
    return 10 * np.log10(np.median(e[speech]) / np.median(e[~speech]))


def test_the_aligned_phones_cover_each_recording_and_follow_its_voice(utterances):
    """Forced alignment (hand labels for a0009) puts the phones where the sound is: the median
    energy inside them is at least 15 dB above that in the pauses (measured 17.6-30.2 dB); moved
    by 0.3 s the same phones fall to 3.6-13.7 dB on half of the recordings."""
    moved = []
    for name, u in utterances.items():
        assert u.phones[0].start == 0.0 and u.phones[-1].end == pytest.approx(u.duration), name
        assert all(a.end == pytest.approx(b.start) for a, b in zip(u.phones, u.phones[1:])), name
        assert sum(p.label != "_" for p in u.phones) >= 20, name
        assert _speech_vs_pause_db(u) >= 15.0, name
        moved.append(min(_speech_vs_pause_db(u, 0.3), _speech_vs_pause_db(u, -0.3)))
    assert sum(m < 15.0 for m in moved) >= 4


def test_words_the_dictionary_lacks_get_their_phones(recordings, tmp_path, capsys):
    sonnet = next(r for r in recordings if r.name == "sonnet_1")
    with pytest.raises(phonemes.AlignmentError, match="churl.*--pronounce"):
        phonemes.align(sonnet.wav, sonnet.text)
    segs = phonemes.align(sonnet.wav, sonnet.text, pronunciations=sonnet.pronunciations)
    assert segs[-1].end == pytest.approx(DURATIONS["sonnet_1"], abs=0.01)
    with pytest.raises(ValueError, match="pronunciation of 'churl'.*XX not phones"):
        phonemes.align(sonnet.wav, sonnet.text, pronunciations={"churl": "CH XX L"})
    # the command line: a word of a0007's transcript spelt out of the dictionary, then given
    a0007 = next(r for r in recordings if r.name == "arctic_a0007")
    text = a0007.text.replace("superlative", "superlatyve")
    out = tmp_path / "a.lab"
    assert main(["align", a0007.wav, "-t", text, "-o", str(out)]) == 2
    assert "superlatyve" in capsys.readouterr().err and not out.exists()
    assert main(["align", a0007.wav, "-t", text, "--pronounce", "superlatyve=S UW P ER L AH T IH V",
                 "-o", str(out)]) == 0
    assert out.exists()
    assert main(["align", a0007.wav, "-t", text, "--pronounce", "superlatyve", "-o", str(out)]) == 2
    assert "--pronounce takes WORD='PH PH ...'" in capsys.readouterr().err


def test_the_performer_speaks_the_real_recordings(tmp_path):
    """Small frames and a low rate to keep it quick: the training clip is the two LibriVox readers
    with pauses, the test clips the two ARCTIC speakers; the second call reads the cache."""
    corpus = synth.make_real_corpus(tmp_path, fps=10.0, size=(96, 96), progress=False)
    train_speech = sum(DURATIONS[n] for n in synth.REAL_TRAIN)
    assert train_speech + 6 * 0.25 <= corpus.train.duration <= train_speech + 6 * 0.6 + 0.1
    assert [c.source.split(" ")[0] for c in corpus.test] == list(synth.REAL_TEST)
    assert corpus.train.points.shape == (corpus.train.n_frames, 68, 2)
    again = synth.make_real_corpus(tmp_path, fps=10.0, size=(96, 96), progress=False)
    np.testing.assert_array_equal(again.train.points, corpus.train.points)
    # the face moves with the voice: the lips part more in the phones than in the pauses
    gap = np.linalg.norm(corpus.train.points[:, 62] - corpus.train.points[:, 66], axis=1)
    t = (np.arange(len(gap)) + 0.5) / corpus.fps
    speech = np.zeros(len(gap), bool)
    for p in corpus.train.phones:
        if p.label != "_":
            speech |= (t >= p.start) & (t < p.end)
    assert gap[speech].mean() > 2 * gap[~speech].mean()
    # who reads each sequence: the Sonnet's reader up to the cut in the silence around her reading's end
    # (which may fall a little before the end of its recording, in its trailing silence)
    seqs = split_clip(corpus.train, name="train")
    seqs += [split_clip(c, min_pause=1e9, name=f"test_{i:02d}")[0] for i, c in enumerate(corpus.test)]
    _label_readers(seqs, corpus)
    by = {r.name: r.speaker for r in samples.real_recordings()}
    first = [s for s in seqs if s.meta["reader"] == by["sonnet_1"]]
    assert seqs[:len(first)] == first and len(first) < len(seqs) - 2
    read = sum(len(s.points) for s in first) / corpus.fps
    assert DURATIONS["sonnet_1"] - 1.0 <= read <= DURATIONS["sonnet_1"] + 0.6
    assert {s.meta["reader"] for s in seqs[len(first):-2]} == {by["librivox_0870"]}
    assert [s.meta["reader"] for s in seqs[-2:]] == [by[n] for n in synth.REAL_TEST]
