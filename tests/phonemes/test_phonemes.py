"""Tests of voicepuppet.phonemes.labels: the phone set, label mapping, frame labels by majority vote
(against a brute-force per-frame count), TextGrid and HTS round trips, and pocketsphinx forced
alignment on CMU ARCTIC a0009 against its hand-checked labels."""

from __future__ import annotations

import numpy as np
import pytest

from voicepuppet.phonemes import labels as ph

SEED = 20261123


def test_phone_set_is_arpabet_plus_silence_and_breath():
    assert ph.N_PHONES == 41 and len(set(ph.PHONES)) == 41
    assert ph.PHONES[:2] == ("SIL", "BR")
    for p in "AA AE AH AO AW AY B CH D DH EH ER EY F G HH IH IY JH K L M N NG OW OY P R S SH T TH " \
             "UH UW V W Y Z ZH".split():
        assert p in ph.PHONE_INDEX


@pytest.mark.parametrize("label,alphabet,expected", [
    ("aa1", "arpabet", "AA"), ("AH0", "arpabet", "AH"), ("pau", "arpabet", "SIL"), ("sil", "arpabet", "SIL"),
    ("ax", "arpabet", "AH"), ("dx", "arpabet", "D"), ("br", "arpabet", "BR"), ("D", "arpabet", "D"),
    ("D", "espeak", "DH"), ("T", "espeak", "TH"), ("S", "espeak", "SH"), ("N", "espeak", "NG"),
    ("tS", "espeak", "CH"), ("aI", "espeak", "AY"), ("@2", "espeak", "AH"), ("_:", "espeak", "SIL"),
    ("i@3", "espeak", "IY"), ("O2", "espeak", "AO"), ("t[", "espeak", "T"),
])
def test_to_phone(label, alphabet, expected):
    assert ph.to_phone(label, alphabet) == expected


def test_unknown_phone_is_a_clear_error():
    with pytest.raises(ValueError, match="unknown arpabet phone 'QQ'"):
        ph.to_phone("QQ")
    with pytest.raises(ValueError, match="alphabet"):
        ph.to_phone("a", "ipa")
    with pytest.raises(ValueError, match="overlap"):
        ph.normalize([("aa", 0.0, 0.5), ("b", 0.4, 0.6)])


def test_espeak_modifier_merges_into_previous_phone():
    segs = ph.normalize([("n", 0.0, 0.1), (";", 0.1, 0.12), ("u:", 0.12, 0.3)], "espeak")
    assert segs == [ph.Segment("N", 0.0, 0.12), ph.Segment("UW", 0.12, 0.3)]


def brute_force_labels(segs, n_frames, fps, step=0.01):
    """Per video frame, count the 10 ms frames of each phone one by one."""
    out = []
    n_sound = int(np.ceil(n_frames / fps / step))
    for t in range(n_frames):
        counts = {}
        order = []
        for k in range(n_sound):
            c = (k + 0.5) * step
            if min(int(c * fps), n_frames - 1) != t:
                continue
            lab = "SIL"
            for s in segs:
                if s.start <= c < s.end or (c >= segs[-1].end and s is segs[-1]):
                    lab = s.label
                    break
            counts[lab] = counts.get(lab, 0) + 1
            order.append(lab)
        best = max(counts.values())
        out.append(ph.PHONE_INDEX[next(lab for lab in order if counts[lab] == best)])
    return np.array(out)


def test_frame_labels_majority_vote_matches_brute_force():
    rng = np.random.default_rng(SEED)
    print("seed", SEED)
    for trial in range(5):
        t, rows = 0.0, []
        while t < 3.0:
            d = float(rng.uniform(0.015, 0.2))
            rows.append((ph.PHONES[int(rng.integers(ph.N_PHONES))], t, t + d))
            t += d
        segs = ph.normalize(rows)
        fps = [29.97, 25.0, 60.0, 30.0, 24.0][trial]
        n = int(3.0 * fps)
        got = ph.frame_labels(rows, n, fps)
        assert got.shape == (n,) and got.dtype == np.int64
        np.testing.assert_array_equal(got, brute_force_labels(segs, n, fps))


def test_frame_labels_planted_runs():
    # 1 s of AA then 1 s of M at 25 fps: 25 + 25 frames exactly
    got = ph.frame_labels([("aa", 0, 1.0), ("m", 1.0, 2.0)], 50, 25.0)
    assert list(got) == [ph.PHONE_INDEX["AA"]] * 25 + [ph.PHONE_INDEX["M"]] * 25
    back = ph.label_intervals(got, 25.0)
    assert back == [ph.Segment("AA", 0.0, 1.0), ph.Segment("M", 1.0, 2.0)]


def test_frame_labels_bad_input():
    with pytest.raises(ValueError, match="labels must cover the audio"):
        ph.frame_labels([("aa", 0, 1.0)], 60, 30.0)
    with pytest.raises(ValueError, match="start at"):
        ph.frame_labels([("aa", 0.5, 2.0)], 60, 30.0)
    with pytest.raises(ValueError, match="no phones"):
        ph.frame_labels([], 10, 30.0)
    with pytest.raises(ValueError, match="n_frames"):
        ph.frame_labels([("aa", 0, 1.0)], 0, 30.0)
    with pytest.raises(ValueError, match="unknown"):
        ph.frame_labels([("zz", 0, 1.0)], 30, 30.0)


def test_textgrid_and_hts_round_trip(tmp_path):
    segs = [ph.Segment("SIL", 0.0, 0.2), ph.Segment("HH", 0.2, 0.31), ph.Segment("AY", 0.31, 0.6),
            ph.Segment("SIL", 0.6, 0.8)]
    tg = tmp_path / "a.TextGrid"
    ph.write_textgrid(segs, tg)
    assert ph.read_textgrid(tg) == segs
    lab = tmp_path / "a.lab"
    ph.write_hts(segs, lab)
    assert lab.read_text().splitlines()[1] == "2000000 3100000 hh"
    assert ph.read_hts(lab) == segs
    # a failed write leaves nothing behind
    with pytest.raises(ValueError):
        ph.write_hts([("qq", 0, 1)], tmp_path / "b.lab")
    assert not (tmp_path / "b.lab").exists() and len(list(tmp_path.iterdir())) == 2
    (tmp_path / "bad.lab").write_text("0 x aa\n")
    with pytest.raises(ValueError, match="integers"):
        ph.read_hts(tmp_path / "bad.lab")


def test_hts_full_context_labels_of_arctic():
    from voicepuppet import data as samples

    _, lab = samples.arctic_a0009(with_labels=True)
    segs = ph.read_hts(lab)
    assert [s.label for s in segs[:4]] == ["SIL", "HH", "IY", "T"]
    assert segs[-1].label == "SIL"


@pytest.fixture(scope="module")
def arctic():
    from voicepuppet import data as samples

    wav, lab = samples.arctic_a0009(with_labels=True)
    return wav, ph.read_hts(lab)


def test_forced_alignment_on_arctic_a0009(arctic):
    wav, ref = arctic
    got = ph.align(wav, "He turned sharply, and faced Gregson across the table.")
    assert [s.label for s in got] == [s.label for s in ref]
    err = np.abs(np.array([s.start for s in got[1:]]) - np.array([s.start for s in ref[1:]]))
    med = float(np.median(err))
    print(f"arctic_a0009 boundaries: median error {1000 * med:.1f} ms, 90th percentile "
          f"{1000 * np.percentile(err, 90):.1f} ms over {err.size} boundaries")
    assert med <= 0.020
    assert got[0].start == 0.0 and abs(got[-1].end - 3.1) < 0.2


def test_forced_alignment_reports_mismatch(arctic):
    wav, _ = arctic
    with pytest.raises(ph.AlignmentError, match="not in the pronunciation dictionary: qwxzy"):
        ph.align(wav, "he turned qwxzy")
    with pytest.raises(ph.AlignmentError, match="does not match the audio"):
        ph.align(wav, "twenty seven elephants " * 12)


def test_phone_recognition_without_transcript(arctic):
    wav, ref = arctic
    got = ph.align(wav)
    # covers the audio, starts and ends in silence, finds most of the consonant-vowel structure
    assert got[0].label == "SIL" and got[-1].label == "SIL" and got[0].start == 0.0
    T = 300
    a = ph.frame_labels(got, T, 100.0, tolerance=0.05)
    b = ph.frame_labels(ref, T, 100.0, tolerance=0.05)
    agree = float(np.mean(a == b))
    print(f"phone recognition frame agreement {agree:.2f}")
    assert agree > 0.3


def test_align_verb_writes_labels(arctic, tmp_path, capsys):
    from voicepuppet.cli.main import main

    wav, ref = arctic
    out = tmp_path / "a.TextGrid"
    assert main(["align", wav, "-t", "He turned sharply, and faced Gregson across the table.",
                 "-o", str(out)]) == 0
    assert f"{sum(s.label != 'SIL' for s in ref)} phones" in capsys.readouterr().out
    assert [s.label for s in ph.read_textgrid(out)] == [s.label for s in ref]
    assert main(["align", wav, "-t", "twenty seven elephants " * 12, "-o", str(tmp_path / "b.lab")]) == 2
    assert "does not match the audio" in capsys.readouterr().err
    assert main(["align", wav, "-o", str(tmp_path / "c.txt")]) == 2
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.TextGrid"]
