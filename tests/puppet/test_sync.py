"""The audio-video offset: planted offsets on the synthetic performer and on real recordings
(measured with an independent detector's landmarks) are recovered, and training corrects them."""

import numpy as np
import pytest
import soundfile as sf

from voicepuppet.audio import load_audio, prepare
from voicepuppet.evaluation.real import real_clips
from voicepuppet.layout import neutral_landmarks
from voicepuppet.puppet.sources import av_offsets, training_sequences
from voicepuppet.puppet.sync import estimate_av_offset, estimate_shared_av_offset, mouth_opening, shift_audio

FPS = 30000 / 1001


@pytest.fixture(scope="module")
def performer():
    """12.5 s of the synthetic performer: espeak-ng speech and the landmarks articulating it."""
    from voicepuppet.synth import speech
    from voicepuppet.synth.articulation import articulate

    texts = ["Please remember to feed the fish.", "Who knows where the ferry goes?",
             "You can hear the waves on the shore.", "The quick brown fox jumps over the lazy dog.",
             "She sells sea shells by the sea shore."]
    u = speech.concatenate([speech.speak(t) for t in texts], [0.4] * len(texts))
    art = articulate(u.phones, u.samples, u.rate, neutral_landmarks(), fps=FPS, seed=1)
    return art.points, prepare(u.samples, u.rate)


@pytest.mark.parametrize("planted_ms", [40, -40, 100, -100, 200, -200])
def test_planted_offsets_on_the_performer_are_recovered_within_a_frame(performer, planted_ms):
    points, audio = performer
    base = estimate_av_offset(points, audio, FPS)
    late = estimate_av_offset(points, shift_audio(audio, -planted_ms / 1000), FPS)
    assert base.reliable and late.reliable
    assert abs(late.seconds * 1000 - planted_ms) * FPS / 1000 <= 1.0
    # the estimate moves with the plant, whatever the performer's own lead
    assert abs((late.seconds - base.seconds) * 1000 - planted_ms) * FPS / 1000 <= 0.25
    assert late.correlation > 0.4 and late.correlation >= late.correlation_in_sync


def _real_clip(name):
    """A real recording inside the package, its face given by the reference's mouth opening
    (MediaPipe's, independent of voicepuppet's tracker) placed in the 68-point layout: eye corners
    one unit apart, the inner lips' middles that opening apart, all that the opening reads."""
    clip = next(c for c in real_clips(speaker="obama") if c.key == f"obama/{name}")
    points = np.full((len(clip.opening), 68, 2), np.nan)
    points[:, 36], points[:, 45], points[:, 62] = (0.0, 0.0), (1.0, 0.0), (0.5, 0.3)
    points[:, 66, 0], points[:, 66, 1] = 0.5, 0.3 + clip.opening
    return points, load_audio(clip.video), clip.fps


@pytest.mark.parametrize("clip", ["oval_office_20s", "white_house_30s"])
@pytest.mark.parametrize("planted_ms", [-100, 100])
def test_planted_offsets_on_real_recordings_are_recovered_within_a_frame(clip, planted_ms):
    """Real faces (an independent detector's landmarks) with their own voices: a planted shift
    moves the estimate by itself, to a frame; the recordings' own offsets (their sound stored
    apart and muxed back) come out reliable and late, as their source says (about 100 ms)."""
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        points, audio, fps = _real_clip(clip)
    own = estimate_av_offset(points, audio, fps)
    assert own.reliable and 0.06 <= own.seconds <= 0.2
    moved = estimate_av_offset(points, shift_audio(audio, -planted_ms / 1000), fps)
    assert moved.reliable
    assert abs((moved.seconds - own.seconds) * 1000 - planted_ms) * fps / 1000 <= 1.0


def test_short_or_unrelated_recordings_are_not_reliable(performer, rng):
    points, audio = performer
    short = estimate_av_offset(points[:90], audio, FPS)
    assert not short.reliable and "under 5 s" in short.reason
    noise = prepare(rng.normal(0, 0.1, len(audio.samples)), audio.rate)
    assert not estimate_av_offset(points, noise, FPS).reliable
    with pytest.raises(ValueError, match="68-point"):
        mouth_opening(points[:, :10])
    with pytest.raises(ValueError, match="fps"):
        estimate_av_offset(points, audio, 0.0)


def test_shift_audio_moves_the_samples_and_keeps_the_length():
    audio = prepare(np.arange(1, 17, dtype=np.float64) / 100, 16000, remove_dc=False)
    late = shift_audio(audio, 4 / 16000)  # the sound ran 4 samples late: it starts 4 samples in
    np.testing.assert_array_equal(late.samples, np.r_[audio.samples[4:], np.zeros(4)])
    early = shift_audio(audio, -4 / 16000)
    np.testing.assert_array_equal(early.samples, np.r_[np.zeros(4), audio.samples[:-4]])
    assert shift_audio(audio, 0.0) is audio
    assert not shift_audio(audio, 1.0).samples.any()


def test_training_corrects_the_offset_and_says_so(performer, tmp_path):
    """train's sequences: a planted 133 ms lateness is found and removed (the corrected sound
    then estimates in sync); --av-offset is applied as given; every recording gets a line."""
    points, audio = performer
    np.savez(tmp_path / "face.npz", points=points, fps=FPS)
    sf.write(tmp_path / "late.wav", shift_audio(audio, -0.133).samples, audio.rate)
    lines = []
    pts, sounds, fps, offsets = training_sequences(landmarks=[tmp_path / "face.npz"],
                                                   audio=[tmp_path / "late.wav"], report=lines.append)
    assert fps == pytest.approx(FPS) and len(pts) == 1
    assert abs(offsets[0] - 0.133) * FPS <= 1.0
    assert len(lines) == 1 and "the sound is" in lines[0] and "late" in lines[0] and "corrected" in lines[0]
    assert abs(estimate_av_offset(pts[0], sounds[0], fps).seconds) * FPS < 1.0

    lines.clear()
    _, sounds, _, offsets = training_sequences(landmarks=[tmp_path / "face.npz"], audio=[tmp_path / "late.wav"],
                                               av_offset=0.05, report=lines.append)
    assert offsets == [0.05] and "given" in lines[0]
    np.testing.assert_array_equal(sounds[0].samples, shift_audio(load_audio(tmp_path / "late.wav"), 0.05).samples)
    with pytest.raises(ValueError, match="offset"):
        training_sequences(landmarks=[tmp_path / "face.npz"], audio=[tmp_path / "late.wav"], av_offset=float("nan"))


def _cuts(points, audio, n, planted_s):
    """The performer cut into n recordings of equal length, each with its sound planted_s late."""
    edges = np.linspace(0, len(points), n + 1).astype(int)
    out = []
    for a, b in zip(edges[:-1], edges[1:]):
        s0, s1 = int(round(a / FPS * audio.rate)), int(round(b / FPS * audio.rate))
        piece = prepare(audio.samples[s0:s1], audio.rate, remove_dc=False)
        out.append((points[a:b], shift_audio(piece, -planted_s), FPS))
    return out


@pytest.mark.parametrize("planted_ms", [-100, 133])
def test_short_recordings_are_judged_together(performer, planted_ms):
    """Four 3 s cuts with one planted offset: each alone is too short to be reliable, together
    they recover it to a frame; a set of one judges as the recording alone."""
    points, audio = performer
    cuts = _cuts(points, audio, 4, planted_ms / 1000)
    assert not any(estimate_av_offset(*c).reliable for c in cuts)
    shared = estimate_shared_av_offset(cuts)
    assert shared.reliable and shared.correlation > 0.3
    base = estimate_av_offset(points, audio, FPS).seconds  # the performer's own lead
    assert abs((shared.seconds - base) * 1000 - planted_ms) * FPS / 1000 <= 1.0
    one = estimate_shared_av_offset(cuts[:1])
    assert one == estimate_av_offset(*cuts[0]) and "under 5 s" in one.reason
    with pytest.raises(ValueError, match="no recordings"):
        estimate_shared_av_offset([])


def test_training_corrects_short_recordings_together(performer):
    """av_offsets: the cuts that are unreliable alone get the shared offset, each says so."""
    points, audio = performer
    cuts = _cuts(points, audio, 4, 0.133)
    lines = []
    offsets = av_offsets([(p, a, f"cut{i}: ") for i, (p, a, _) in enumerate(cuts)], FPS, report=lines.append)
    assert all(abs(o - 0.133) * FPS <= 1.0 for o in offsets)
    assert len(lines) == 4 and all("judged with the 3 other" in line and "corrected" in line for line in lines)
    lines.clear()
    assert av_offsets([(p, a, "") for p, a, _ in cuts[:1]], FPS, report=lines.append) == [0.0]
    assert "not estimated reliably" in lines[0]


def test_real_sentence_cuts_share_their_offset():
    """The seven Obama sentence cuts (2-5 s each, an independent detector's landmarks): none is
    reliable alone; together their sound runs about 100 ms (3 frames) late, as the long clips of
    stored-apart sound do, and the opening then follows the loudness far better than in sync."""
    import warnings

    names = [f"sentence_{i}" for i in range(1, 8)]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        cuts = [_real_clip(n) for n in names]
    assert not any(estimate_av_offset(*c).reliable for c in cuts)
    shared = estimate_shared_av_offset(cuts)
    assert shared.reliable and 0.06 <= shared.seconds <= 0.14
    assert shared.correlation > shared.correlation_in_sync + 0.15
