"""The voice puppet end to end on planted data: training recovers a planted state machine, animation
equals the kernels composed by hand, the puppet file round-trips and refuses damage."""
import json
import os

import numpy as np
import pytest

from voicepuppet import _core
from voicepuppet.puppet import model as vpuppet
from voicepuppet.face import observations
from voicepuppet.puppet.model import Puppet, load
from voicepuppet.puppet.training import TRAIN_DEFAULTS, remap

from support import planted_puppet_data


@pytest.fixture(scope="module")
def trained():
    rng = np.random.default_rng(7)
    pts, feats, states = planted_puppet_data(rng)
    p = Puppet.train([pts], features_list=[feats], fps=30.0, n_states=8, n_iter=25, n_components=3)
    test_pts, test_feats, test_states = planted_puppet_data(np.random.default_rng(8), T=300)
    return p, (pts, feats, states), (test_pts, test_feats, test_states)


def test_planted_machine_is_recovered(trained):
    p, _, (pts, feats, states) = trained
    r = p.animate(features=feats)
    decoded = r.states[:, 0]
    # Each decoded state belongs to one planted state (purity), and the face follows.
    purity = sum(np.bincount(states[decoded == s]).max() for s in np.unique(decoded)) / len(states)
    assert purity > 0.95
    truth, _ = p.face_space.encode(pts)
    err = np.sum((r.face - truth) ** 2) / np.sum((truth - truth.mean(0)) ** 2)
    assert err < 0.1
    assert p.n_states() <= 8 and p.metadata["training"]["parts"][0]["states"] == p.n_states()


def test_full_motion_widens_the_trajectory_by_the_gains_learnt_in_training(trained):
    """Training learns per face coordinate how much less its cross-validated animations of the
    training audio moved than the faces (at the chosen guide weight); animate's default widens
    the most probable trajectory by it, full_motion=False or another guide weight does not."""
    from voicepuppet.trajectory import MAX_MOTION_GAIN

    p, _, (_, feats, _) = trained
    gain = p.arrays["face/motion_gain"]
    assert gain.shape == (p.face_space.n_dims,) and np.all(gain >= 1) and np.all(gain <= MAX_MOTION_GAIN)
    assert np.any(gain > 1.01), "this puppet's animations are not timid: nothing tested"
    plain, full = p.animate(features=feats, full_motion=False), p.animate(features=feats)
    np.testing.assert_allclose(full.face.std(axis=0), gain * plain.face.std(axis=0), rtol=1e-9)
    np.testing.assert_allclose(full.face.mean(axis=0), plain.face.mean(axis=0), atol=1e-9)
    np.testing.assert_allclose(full.animation.points, p.face_space.decode(full.face), atol=1e-9)
    np.testing.assert_array_equal(full.states, plain.states)
    own = p.animate(features=feats, guide_weight=p.guide_weight)  # its own weight, given: widened
    np.testing.assert_array_equal(own.face, full.face)
    other = p.animate(features=feats, guide_weight=p.guide_weight + 1.0)  # another weight: not widened
    np.testing.assert_array_equal(other.face, p.animate(features=feats, guide_weight=p.guide_weight + 1.0,
                                                        full_motion=False).face)


def test_novel_audio_may_start_in_any_state(trained):
    # Audio starts anywhere in the performer's manner, not where the training video began: a
    # start vector learned from one training sequence is a point mass on its first state; the
    # puppet's is half that and half the state occupancy of the training frames.
    p, (_, train_feats, train_states), _ = trained
    start = p.part_arrays(0)["startprob"]
    path = p.animate(features=train_feats).states[:, 0]
    share = np.bincount(path, minlength=p.n_states()) / len(path)
    first = start - share / 2
    assert np.all(start > 1e-3) and first.argmax() == path[0]
    np.testing.assert_allclose(first, np.eye(p.n_states())[path[0]] / 2, atol=0.02)
    planted = {s: np.bincount(train_states[path == s], minlength=3).argmax() for s in np.unique(path)}
    starts = 0
    for seed in range(20, 40):
        _, feats, states = planted_puppet_data(np.random.default_rng(seed), T=90)
        if states[0] == train_states[0]:
            continue
        starts += 1
        first = p.animate(features=feats).states[0, 0]
        assert planted[first] == states[0], f"seed {seed}: the first frame decoded as the training's start"
    assert starts >= 8


def test_animate_is_the_kernels_composed(trained):
    p, _, (_, feats, _) = trained
    arr = p.part_arrays(0)
    w = int(p.arrays["audio/delta_width"][0])
    assert w == 2
    T = len(feats)
    at = lambda k: feats[np.clip(np.arange(T) + k, 0, T - 1)]  # noqa: E731
    deltas = sum(k * (at(k) - at(-k)) for k in (1, 2)) / 10.0
    z = (np.hstack([feats, deltas]) - p.arrays["audio/mean"]) / p.arrays["audio/std"]
    n, a = arr["vocal_means"].shape
    log_b = _core.gaussian_log_density(z, arr["vocal_means"], arr["vocal_covars"].reshape(n * a, a), "full")
    _, path = _core.viterbi(log_b, arr["startprob"], arr["transmat"], np.array([len(z)]))
    d = arr["face_means"].shape[1] // 2
    model = _core.TrajectoryModel(arr["face_means"][:, :d], arr["face_means"][:, d:],
                                  arr["face_covars"].reshape(-1, 2 * d), "full", 1.0)
    Y = _core.solve_trajectory(model, path)
    r = p.animate(full_motion=False, features=feats, guide_weight=0)  # Brand's solve; with the guide: test_guide.py
    np.testing.assert_array_equal(r.states[:, 0], path)
    np.testing.assert_allclose(r.animation.points, p.face_space.decode(Y), atol=1e-9)
    # Other output rates: twice the frames; edited states read back give the same animation.
    assert p.animate(full_motion=False, features=feats, fps=60.0).animation.n_frames == 2 * len(feats)
    again = p.animate(full_motion=False, states=r.states)
    np.testing.assert_allclose(again.animation.points, r.animation.points, atol=1e-12)
    post = p.animate(full_motion=False, features=feats, posterior=True)
    assert post.animation.n_frames == len(feats) and post.log_likelihood >= r.log_likelihood - 1e-6


def test_save_load_round_trip_and_damage(trained, tmp_path):
    p, _, (_, feats, _) = trained
    path = p.save(tmp_path / "p.vpp")
    q = load(path)
    np.testing.assert_array_equal(q.animate(features=feats).animation.points,
                                  p.animate(features=feats).animation.points)
    assert q.metadata == json.loads(json.dumps(p.metadata))
    data = path.read_bytes()
    (tmp_path / "trunc.vpp").write_bytes(data[:-100])
    with pytest.raises(ValueError, match="truncated"):
        load(tmp_path / "trunc.vpp")
    flipped = bytearray(data)
    flipped[-50] ^= 1
    (tmp_path / "flip.vpp").write_bytes(bytes(flipped))
    with pytest.raises(ValueError, match="checksum"):
        load(tmp_path / "flip.vpp")
    newer = bytearray(data)
    newer[8] = 99
    (tmp_path / "new.vpp").write_bytes(bytes(newer))
    with pytest.raises(ValueError, match="newer"):
        load(tmp_path / "new.vpp")
    (tmp_path / "x.vpp").write_bytes(b"not a puppet at all, just some text that is long enough")
    with pytest.raises(ValueError, match="not a voicepuppet"):
        load(tmp_path / "x.vpp")
    with pytest.raises(ValueError, match="does not exist"):
        load(tmp_path / "missing.vpp")
    with pytest.raises(ValueError, match=".vpp"):
        p.save(tmp_path / "p.txt")
    assert sorted(os.listdir(tmp_path)) == ["flip.vpp", "new.vpp", "p.vpp", "trunc.vpp", "x.vpp"]


def test_remap_is_the_weighted_gaussian(rng):
    T, N, A = 400, 3, 4
    X = rng.normal(size=(T, A))
    g = rng.dirichlet(np.ones(N), size=T)
    means, covs = remap(g, X, "full", floor=0.0)
    kappa, mu, pooled = A, X.mean(0), np.cov(X, rowvar=False, bias=True)
    for i in range(N):
        w = g[:, i]
        m = (w @ X + kappa * mu) / (w.sum() + kappa)
        np.testing.assert_allclose(means[i], m, rtol=1e-12)
        d = X - m
        np.testing.assert_allclose(covs[i], ((d.T * w) @ d + kappa * pooled) / (w.sum() + kappa), rtol=1e-10)
        np.linalg.cholesky(covs[i])
    _, diag = remap(g, X, "diag", floor=0.0)
    np.testing.assert_allclose(diag, np.array([np.diag(c) for c in covs]), rtol=1e-10)


def test_bad_training_input(rng):
    pts = rng.normal(size=(100, 5, 2)) * 10 + 100
    with pytest.raises(ValueError, match=r"100 training frames \(4\.0 s at 25 fps\) are too few for 40 states: .*"
                                         r"400 frames \(16\.0 s\) of video, or fewer states .*--states 10\)"):
        Puppet.train([pts], features_list=[rng.normal(size=(100, 3))], n_states=40, fps=25.0)
    with pytest.raises(ValueError, match="one audio per landmark"):
        Puppet.train([pts, pts], features_list=[rng.normal(size=(100, 3))], n_states=4)
    with pytest.raises(TypeError, match="n_state"):
        Puppet.train([pts], features_list=[rng.normal(size=(100, 3))], n_state=4)
    bad = pts.copy()
    bad[10, 2, 1] = np.nan
    with pytest.raises(ValueError, match="frame 10, point 2"):
        Puppet.train([bad], features_list=[rng.normal(size=(100, 3))], n_states=4)
    with pytest.raises(ValueError, match="shape"):
        Puppet.train([pts], features_list=[rng.normal(size=(90, 3))], n_states=4)


def test_bad_animation_input(trained):
    p, _, (_, feats, _) = trained
    with pytest.raises(ValueError, match="columns"):
        p.animate(features=feats[:, :3])
    with pytest.raises(ValueError, match="give audio or features"):
        p.animate()
    with pytest.raises(ValueError, match=r"\[0, "):
        p.animate(states=np.full(10, 99))
    with pytest.raises(ValueError, match="NaN"):
        p.animate(features=np.full((5, feats.shape[1]), np.nan))


def test_separate_face_parts():
    pts, feats, states = planted_puppet_data(np.random.default_rng(7))
    parts = {"upper": range(0, 6), "lower": range(6, 12)}
    p = Puppet.train([pts], features_list=[feats], fps=30.0, n_states=5, n_iter=10, n_components=2,
                     parts=parts)
    assert p.part_names == ["upper", "lower"] and p._core.n_parts == 2
    r = p.animate(full_motion=False, features=feats, guide_weight=0)  # Brand's solve; with the guide: test_guide.py
    assert r.states.shape == (len(feats), 2) and r.face.shape == (len(feats), p.face_space.n_dims)
    # Each part is synthesised from its own machine: the whole equals the parts side by side.
    for k, sl in enumerate(p.face_space.part_slices):
        arr = p.part_arrays(k)
        d = arr["face_means"].shape[1] // 2
        model = _core.TrajectoryModel(arr["face_means"][:, :d], arr["face_means"][:, d:],
                                      arr["face_covars"].reshape(-1, 2 * d), "full", 1.0)
        np.testing.assert_allclose(r.face[:, sl], _core.solve_trajectory(model, r.states[:, k]), atol=1e-9)
    np.testing.assert_allclose(p.animate(full_motion=False, states=r.states).animation.points, r.animation.points, atol=1e-12)


def test_training_on_a_dask_cluster_equals_one_process():
    from voicepuppet.hmm import distributed

    rng = np.random.default_rng(11)
    seqs = [planted_puppet_data(rng, T=300) for _ in range(3)]
    pts, feats = [s[0] for s in seqs], [s[1] for s in seqs]
    opts = dict(fps=30.0, n_states=6, n_iter=8, n_components=3, anneal=False)
    one = Puppet.train(pts, features_list=feats, **opts)
    with distributed.connect(None, 2, timeout=60) as client:
        many = Puppet.train(pts, features_list=feats, client=client, **opts)
    assert set(one.arrays) == set(many.arrays)
    for name, value in one.arrays.items():
        np.testing.assert_allclose(many.arrays[name], value, rtol=1e-10, atol=1e-10, err_msg=name)


def test_remap_tied_is_the_pooled_within_state_covariance(rng):
    T, N, A = 600, 4, 3
    labels = rng.integers(0, N, T)
    X = rng.normal(size=(N, A))[labels] * 3 + rng.normal(size=(T, A)) @ rng.normal(size=(A, A))
    # Hard occupancies, no shrinkage, no floor: the within-class covariance of linear
    # discriminant analysis (scikit-learn's, with the class frequencies as priors).
    from sklearn.discriminant_analysis import LinearDiscriminantAnalysis

    lda = LinearDiscriminantAnalysis(solver="lsqr", store_covariance=True).fit(X, labels)
    means, covs = remap(np.eye(N)[labels], X, "tied", floor=0.0, shrinkage=0.0)
    np.testing.assert_allclose(means, lda.means_, rtol=1e-12)
    for i in range(N):
        np.testing.assert_allclose(covs[i], lda.covariance_, rtol=1e-10)
    # Soft occupancies with shrinkage: the means are those of "full", the covariance the
    # occupancy-weighted scatter about them over all frames, plus the floor, in every state.
    g = rng.dirichlet(np.ones(N), size=T)
    full_means, _ = remap(g, X, "full")
    means, covs = remap(g, X, "tied", floor=1e-3)
    np.testing.assert_allclose(means, full_means, rtol=1e-12)
    S = sum(((X - means[i]).T * g[:, i]) @ (X - means[i]) for i in range(N)) / T + 1e-3 * np.eye(A)
    for i in range(N):
        np.testing.assert_allclose(covs[i], S, rtol=1e-10)
    with pytest.raises(ValueError, match="covariance must be one of"):
        remap(g, X, "spherical")


def _two_spreads(rng, spreads, T=900, P=12):
    """The planted performer of ``_planted`` with a voice whose audio spread differs per state:
    ``spreads[s]`` is the standard deviation of state s's features (a speaker's own spread)."""
    pts, _, states = planted_puppet_data(rng, T=T, P=P)
    world = np.random.default_rng(1)
    audio_means = world.normal(0, 3, (3, 5))
    feats = audio_means[states] + rng.normal(0, 1.0, (T, 5)) * np.asarray(spreads)[states][:, None]
    return pts, feats, states


def test_tied_vocal_covariance_decodes_a_voice_it_never_heard():
    # Trained on a voice that is tight in two states and loose in the third; a new voice spreads
    # every state alike. A state's own covariance lets the loose state catch the new voice's
    # frames of the other two; one covariance for all states decodes by the nearest mean.
    pts, feats, _ = _two_spreads(np.random.default_rng(7), [0.3, 0.3, 2.0])
    test_pts, test_feats, test_states = _two_spreads(np.random.default_rng(8), [1.2, 1.2, 1.2], T=600)
    errs = {}
    for cov in ("full", "tied"):
        p = Puppet.train([pts], features_list=[feats], fps=30.0, n_states=6, n_iter=20, n_components=3,
                         vocal_covariance=cov, audio_deltas=0)
        r = p.animate(features=test_feats, guide_weight=0)  # the decoder's doing alone: a guide
        # (λ = 4) pulls the full-covariance face to 0.065 from the ridge's prediction
        truth, _ = p.face_space.encode(test_pts)
        errs[cov] = np.sum((r.face - truth) ** 2) / np.sum((truth - truth.mean(0)) ** 2)
        if cov == "tied":
            vc = p.part_arrays(0)["vocal_covars"]
            np.testing.assert_array_equal(vc, np.repeat(vc[:1], len(vc), axis=0))
            assert p.metadata["training"]["options"]["vocal_covariance"] == "tied"
    assert errs["tied"] < 0.2 and errs["full"] > 2 * errs["tied"], errs


def test_tied_puppet_file_round_trip_and_log_density(tmp_path):
    from scipy.stats import multivariate_normal

    pts, feats, _ = planted_puppet_data(np.random.default_rng(7), T=600)
    p = Puppet.train([pts], features_list=[feats], fps=30.0, n_states=5, n_iter=10, n_components=3,
                     vocal_covariance="tied")
    q = load(p.save(tmp_path / "tied.vpp"))
    np.testing.assert_array_equal(q.animate(features=feats).animation.points,
                                  p.animate(features=feats).animation.points)
    # The C++ vocal densities of the loaded file against scipy's.
    arr = q.part_arrays(0)
    z = q._core.standardize(np.ascontiguousarray(feats))
    ours = q._core.vocal_log_density(z, 0)
    for i in range(len(arr["vocal_means"])):
        np.testing.assert_allclose(ours[:, i], multivariate_normal(arr["vocal_means"][i], arr["vocal_covars"][i]).logpdf(z),
                                   rtol=1e-10)
    with pytest.raises(ValueError, match="vocal_covariance must be one of"):
        Puppet.train([pts], features_list=[feats], fps=30.0, n_states=5, vocal_covariance="shared")


def test_the_band_of_the_training_audio_is_the_puppets(tmp_path):
    """Audio sampled at 8 kHz for training: the puppet band-limits every audio to 4 kHz
    (band_hz, said in a warning, kept in the file), so 16 kHz audio reaches its vocal model as
    band-limited as its training audio was. A whole-band puppet given 8 kHz audio warns and names
    --audio-band; 16 kHz audio gives no warning."""
    import warnings

    from voicepuppet.audio import AudioWarning, FeatureSet, extract, prepare

    pts, _, _ = planted_puppet_data(np.random.default_rng(3), T=600)
    g = np.random.default_rng(4)
    narrow = prepare(0.1 * g.standard_normal(20 * 8000), 8000)
    wide = prepare(0.1 * g.standard_normal(20 * 16000), 16000)
    kw = dict(fps=30.0, n_states=4, n_iter=5, guide_weight=4.0)
    with pytest.warns(AudioWarning, match="sampled at 8000 Hz .*band-limits all audio to 4000 Hz"):
        p = Puppet.train([pts], [narrow], **kw)
    assert p.feature_set.settings()["band_hz"] == 4000
    p.save(tmp_path / "narrow.vpp")
    q = load(tmp_path / "narrow.vpp")
    banded = extract(wide, fps=30.0, features=FeatureSet.named("puppet", band_hz=4000.0, level_db=-20.0)).values
    np.testing.assert_array_equal(q.audio_features(wide), banded)
    assert not np.allclose(extract(wide, fps=30.0).values, banded)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        whole = Puppet.train([pts], [wide], **kw)
        assert whole.feature_set.settings()["band_hz"] is None
        whole.animate(wide)
    with pytest.warns(AudioWarning, match=r"sampled at 8000 Hz.*up to 8000 Hz.*--audio-band 4000"):
        whole.animate(narrow)
    from voicepuppet.live import LivePuppet

    with pytest.warns(AudioWarning, match=r"the live audio is sampled at 8000 Hz.*--audio-band 4000"):
        LivePuppet(whole, rate=8000)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        LivePuppet(whole, rate=16000)
        LivePuppet(q, rate=8000)  # the band-limited puppet takes telephone audio as it is


def _tone_performer(seed, T=900, fps=30.0, rate=16000):
    """_planted's three facial states, each frame's sound a tone of its state (300 / 1100 / 2600
    Hz, continuous phase): (points [T, P, 2], samples, rate, states)."""
    pts, _, states = planted_puppet_data(np.random.default_rng(seed), T=T)
    hz = np.array([300.0, 1100.0, 2600.0])[np.repeat(states, rate // int(fps))]
    x = 0.3 * np.sin(2 * np.pi * np.cumsum(hz) / rate)
    return pts, x, rate, states


def _resting_tone_performer(seed, T=900, fps=30.0, rate=16000, floor_db=None, gain=1.0):
    """_planted's three facial states, the rest state's sound digital silence (or white noise at
    ``floor_db`` dBFS: a room's floor, which speech masks and pure tones would not, so it is in the
    rests alone), the others tones of 1100 / 2600 Hz at -13.5 dBFS; times ``gain``: (points
    [T, P, 2], samples, rate, states)."""
    pts, _, states = planted_puppet_data(np.random.default_rng(seed), T=T)
    per = np.repeat(states, rate // int(fps))
    hz = np.array([0.0, 1100.0, 2600.0])[per]
    x = 0.3 * np.sin(2 * np.pi * np.cumsum(hz) / rate) * (per > 0)
    if floor_db is not None:
        x = x + (per == 0) * 10 ** (floor_db / 20) * np.random.default_rng(seed + 50).standard_normal(x.size)
    return pts, gain * x, rate, states


def test_animations_carry_the_face_the_puppet_makes_in_silence(trained, tmp_path):
    """Rendering and export move a photo at rest by an animation's displacements from its
    ``neutral``: the puppet sets it to its face in silence (the planted rest, whose sound was
    silence), not the first frame, which audio that starts mid-word has open."""
    from voicepuppet.animation import load_animation, save_animation
    from voicepuppet.audio import prepare

    pts, x, rate, states = _resting_tone_performer(5)
    p = Puppet.train([pts], [prepare(x, rate)], fps=30.0, n_states=6, n_iter=15, guide_weight=1.0, seed=2)
    rest = pts[states == 0].mean(axis=0)
    opened = pts[states == 1].mean(axis=0)
    assert np.abs(opened - rest).max() > 20 and np.abs(pts[states == 2].mean(axis=0) - rest).max() > 14
    assert np.abs(p.rest_face() - rest).max() < 2.5  # the output's pose is the mean shape's
    t = np.arange(rate) / rate  # the open state's tone from the first sample, then a rest
    a = p.animate(prepare(np.concatenate([0.3 * np.sin(2 * np.pi * 1100 * t[: rate // 2]), 0 * t]), rate))
    anim = a.animation
    assert np.abs(anim.points[0] - rest).max() > 10 and np.abs(anim.points[3] - opened).max() < 8
    np.testing.assert_array_equal(anim.neutral, p.rest_face())
    np.testing.assert_array_equal(anim.rest, anim.neutral)
    assert np.abs(anim.points[-10] - anim.neutral).max() < 0.5  # the rest at the end is the rest face
    save_animation(anim, tmp_path / "a.npz")
    np.testing.assert_array_equal(load_animation(tmp_path / "a.npz").neutral, anim.neutral)
    np.testing.assert_array_equal(load(p.save(tmp_path / "p.vpp")).rest_face(), p.rest_face())
    # trained on given features, a puppet does not know its silence: the first frame is the rest
    fp = trained[0]
    assert fp.rest_face() is None
    b = fp.animate(features=trained[2][1][:40]).animation
    assert b.neutral is None and np.array_equal(b.rest, b.points[0])


def test_the_speech_level_makes_a_room_and_a_quiet_recording_sound_like_the_training():
    """Trained where the rest state is digitally silent, a puppet hears a rest with a -60 dBFS
    noise floor (46 dB under the tones), and the recording 20 dB quieter, as in training when
    it brings every recording to one speech level with dither under it (audio_level, the
    default); as recorded (audio_level=None) it decodes the states of both worse."""
    from voicepuppet.audio import prepare

    pts, x, rate, _ = _resting_tone_performer(5)
    kw = dict(fps=30.0, n_states=6, n_iter=15, guide_weight=1.0, seed=2)

    def accuracy(p, floor_db, gain):
        _, tx, _, states = _resting_tone_performer(6, T=450, floor_db=floor_db, gain=gain)
        decoded = p.animate(prepare(tx, rate)).states[:len(states), 0]
        truth_of = {s: np.bincount(states[decoded == s]).argmax() for s in np.unique(decoded)}
        return float(np.mean([truth_of[s] for s in decoded] == states[:len(decoded)]))

    levelled = Puppet.train([pts], [prepare(x, rate)], **kw)
    assert levelled.feature_set.settings()["level_db"] == TRAIN_DEFAULTS["audio_level"] == -20.0
    raw = Puppet.train([pts], [prepare(x, rate)], audio_level=None, **kw)
    assert raw.feature_set.settings()["level_db"] is None
    conditions = ((None, 1.0), (-60.0, 1.0), (None, 0.1), (-60.0, 0.1))
    acc = {name: [accuracy(p, f, g) for f, g in conditions] for name, p in (("levelled", levelled), ("raw", raw))}
    print(acc)
    assert min(acc["levelled"]) > 0.9
    assert acc["raw"][0] > 0.9 and all(lv > raw + 0.04 for lv, raw in zip(acc["levelled"][1:], acc["raw"][1:]))
    with pytest.raises(ValueError, match="audio_level must be a speech level"):
        Puppet.train([pts], [prepare(x, rate)], audio_level="loud", **kw)


def test_noisy_copies_make_the_puppet_hear_through_noise():
    """noise_snrs=(0,): the vocal side (Gaussians and guide) also learns from the training sound
    with white noise at 0 dB SNR (the facial HMM from the face once, so its machine is the clean
    puppet's). On new tone-coded speech at 0 dB the clean-trained puppet decodes the states
    worse than the one with the noisy copy, which stays as good on clean sound; seeded, so
    trained twice it is the same file; refused without audio and with projected features."""
    from voicepuppet.audio import prepare

    pts, x, rate, _ = _tone_performer(5)
    test_pts, tx, _, test_states = _tone_performer(6, T=450)
    g = np.random.default_rng(7)
    noisy = prepare(tx + g.normal(0, np.sqrt(np.mean(tx ** 2)), tx.shape), rate)
    kw = dict(fps=30.0, n_states=6, n_iter=15, guide_weight=1.0, seed=2)
    clean = Puppet.train([pts], [prepare(x, rate)], **kw)
    robust = Puppet.train([pts], [prepare(x, rate)], noise_snrs=(0,), **kw)
    for key in ("transmat", "face_means"):  # one facial HMM
        np.testing.assert_array_equal(clean.arrays[f"hmm/part0/{key}"], robust.arrays[f"hmm/part0/{key}"])
    assert robust.metadata["training"]["options"]["noise_snrs"] == [0]

    def accuracy(p, audio):
        decoded = p.animate(audio).states[:len(test_states), 0]
        truth_of = {s: np.bincount(test_states[decoded == s]).argmax() for s in np.unique(decoded)}
        return float(np.mean([truth_of[s] for s in decoded] == test_states[:len(decoded)]))

    acc = {name: (accuracy(p, prepare(tx, rate)), accuracy(p, noisy)) for name, p in
           (("clean", clean), ("robust", robust))}
    print(acc)
    assert acc["robust"][1] > acc["clean"][1] + 0.1
    assert acc["robust"][0] > acc["clean"][0] - 0.03
    again = Puppet.train([pts], [prepare(x, rate)], noise_snrs=(0,), **kw)
    for key, v in robust.arrays.items():
        np.testing.assert_array_equal(again.arrays[key], v, err_msg=key)
    with pytest.raises(ValueError, match="noise_snrs adds noise to the training audio"):
        Puppet.train([pts], features_list=[np.zeros((len(pts), 3))], noise_snrs=(10,), **kw)
    with pytest.raises(ValueError, match="vocal_features='audio'"):
        Puppet.train([pts], [prepare(x, rate)], noise_snrs=(10,), vocal_features="projected", **kw)
    for bad in (10, "20,10", [20, float("nan")]):
        with pytest.raises(ValueError, match="noise_snrs must be a list of SNRs"):
            Puppet.train([pts], [prepare(x, rate)], noise_snrs=bad, **kw)


def test_the_package_gives_the_puppet_api_design_md_names():
    """DESIGN.md's Python API: ``voicepuppet.Puppet.train(...)``, ``voicepuppet.load(path)``."""
    import voicepuppet

    assert voicepuppet.Puppet is Puppet and voicepuppet.load is load
    assert {"Puppet", "load"} <= set(voicepuppet.__all__)
    with pytest.raises(AttributeError, match="no attribute 'Pupet'"):
        voicepuppet.Pupet


def test_a_damaged_motion_gain_is_refused_at_load(trained):
    p = trained[0]
    for bad in (p.arrays["face/motion_gain"][:-1], np.full_like(p.arrays["face/motion_gain"], 0.5),
                np.full_like(p.arrays["face/motion_gain"], np.nan)):
        with pytest.raises(ValueError, match="face/motion_gain"):
            Puppet(p.metadata, {**p.arrays, "face/motion_gain": bad})
