"""The guide's weight chosen at training (``Puppet.train(guide_weight="cv")``, the default): two
planted worlds at the ends of the choice — one where the audio names the face's state but no
linear map of it predicts the face (the HMM must win: λ small), one where the face is a linear
map of the audio and has no states (the ridge must win: λ large) — the recorded errors, the
fixed weight, determinism and bad options."""
import numpy as np
import pytest

from voicepuppet.puppet.guide import GUIDE_WEIGHTS
from voicepuppet.puppet.model import Puppet
from voicepuppet.puppet.training import TRAIN_DEFAULTS

FPS = 30.0
OPTS = dict(fps=FPS, n_states=4, n_iter=8, n_components=2, audio_deltas=0, seed=0, guide_context=2)


def _face(rng, coords):
    """68 points moved by the two face coordinates ``coords`` (T, 2) along two fixed modes."""
    world = np.random.default_rng(1)
    base = world.normal(size=(68, 2)) * 40 + 160
    modes = world.normal(size=(2, 68, 2))
    return base + np.einsum("tk,kpd->tpd", coords, modes) + rng.normal(0, 0.05, (len(coords), 68, 2))


def _xor_world(rng, T):
    """Four states in runs of 15 frames; the audio sits at (±2, ±2) by state and the face shape
    is the sign of the product of the two: the mean of the face given any linear function of
    the audio is the same, so a ridge hears nothing, and the vocal HMM hears everything."""
    states = np.repeat(rng.integers(0, 4, T // 15 + 1), 15)[:T]
    corners = np.array([[2, 2], [-2, -2], [2, -2], [-2, 2]], dtype=float)
    audio = corners[states] + rng.normal(0, 0.3, (T, 2))
    shape = np.where(states < 2, 1.0, -1.0)
    coords = np.stack([3 * shape, np.zeros(T)], axis=1)
    return _face(rng, coords), np.hstack([audio, rng.normal(0, 1, (T, 1))])


def _linear_world(rng, T):
    """No states: the face coordinates are a smooth random walk and the audio a fixed linear map
    of them plus a little noise, so the ridge predicts the face almost exactly."""
    walk = np.cumsum(rng.normal(0, 0.3, (T, 2)), axis=0)
    walk -= walk.mean(axis=0)
    audio = walk @ np.array([[1.0, 0.5, -0.3], [-0.4, 1.0, 0.8]]) + rng.normal(0, 0.02, (T, 3))
    return _face(rng, walk), audio


def _train(world, **extra):
    pts, feats = world(np.random.default_rng(3), 900)
    # several sequences, so the folds are whole sequences
    cuts = np.array_split(np.arange(len(pts)), 6)
    return Puppet.train([pts[c] for c in cuts], features_list=[feats[c] for c in cuts], **OPTS, **extra)


@pytest.fixture(scope="module")
def xor_puppet():
    return _train(_xor_world)


@pytest.fixture(scope="module")
def linear_puppet():
    return _train(_linear_world)


def test_the_vocal_hmm_wins_where_the_audio_names_states_no_linear_map_reads(xor_puppet):
    assert TRAIN_DEFAULTS["guide_weight"] == "cv"
    cv = xor_puppet.metadata["training"]["guide"]["weight_cv"]
    assert cv["weights"] == list(GUIDE_WEIGHTS)
    assert xor_puppet.guide_weight <= 1.0, cv
    # the held-out error grows with the ridge's weight beyond the choice
    assert cv["mse"][-1] > 2 * min(cv["mse"]), cv


def test_the_ridge_wins_where_the_face_is_a_linear_map_of_the_audio(linear_puppet):
    cv = linear_puppet.metadata["training"]["guide"]["weight_cv"]
    assert linear_puppet.guide_weight >= 16.0, cv
    assert cv["mse"][0] > 2 * min(cv["mse"]), cv


def test_the_stored_weight_is_the_recorded_errors_argmin_and_the_file_keeps_it(linear_puppet, tmp_path):
    cv = linear_puppet.metadata["training"]["guide"]["weight_cv"]
    assert linear_puppet.guide_weight == GUIDE_WEIGHTS[int(np.argmin(cv["mse"]))]
    assert linear_puppet.metadata["training"]["guide"]["weight"] == linear_puppet.guide_weight
    from voicepuppet.puppet.model import load

    again = load(linear_puppet.save(tmp_path / "p.vpp"))
    assert again.guide_weight == linear_puppet.guide_weight


def test_a_fixed_weight_changes_nothing_but_the_weight(xor_puppet):
    fixed = _train(_xor_world, guide_weight=4.0)
    assert fixed.guide_weight == 4.0 and "weight_cv" not in fixed.metadata["training"]["guide"]
    # the gains of full motion are measured in the weight's cross-validation: a fixed weight has none
    assert set(fixed.arrays) == set(xor_puppet.arrays) - {"face/motion_gain"}
    for key, value in fixed.arrays.items():
        if key != "guide/weight":
            np.testing.assert_array_equal(value, xor_puppet.arrays[key], err_msg=key)
    # and the choice is deterministic
    again = _train(_xor_world)
    assert again.metadata["training"]["guide"] == xor_puppet.metadata["training"]["guide"]


@pytest.mark.parametrize("bad", ["auto", -1.0, float("nan"), float("inf"), True, [4.0]])
def test_bad_guide_weights_are_refused(bad):
    with pytest.raises(ValueError, match="guide_weight must be 'cv'"):
        _train(_linear_world, guide_weight=bad)


def test_a_weight_without_a_guide_is_refused():
    with pytest.raises(ValueError, match="guide='none'"):
        _train(_linear_world, guide="none", guide_weight=2.0)


def test_too_little_audio_to_cross_validate_says_so_and_a_fixed_weight_trains():
    rng = np.random.default_rng(0)
    pts = rng.normal(size=(68, 2)) * 40 + 160 + rng.normal(0, 1, (10, 68, 2))
    feats = rng.normal(size=(10, 3))
    opts = dict(fps=FPS, n_states=1, n_iter=3, n_components=2, audio_deltas=0, guide_context=1)
    with pytest.raises(ValueError, match=r"choosing the guide's weight by cross-validation on 10 training "
                                         r"frames: .* too few .*; or fix the weight \(guide_weight=4\)"):
        Puppet.train([pts], features_list=[feats], **opts)
    assert Puppet.train([pts], features_list=[feats], guide_weight=4.0, **opts).guide_weight == 4.0


@pytest.mark.parametrize("posterior", [False, True])
def test_one_decoding_for_all_weights_is_animate_at_each(linear_puppet, posterior):
    """The cross-validation's kernel (``_core.Puppet.animate_faces``) through the bindings."""
    _, feats = _linear_world(np.random.default_rng(9), 120)
    core = linear_puppet._core
    weights = [0.0, 2.0, 64.0, -1.0]  # -1: the file's weight
    faces = core.animate_faces(feats, weights, fps=45.0, posterior=posterior)
    assert len(faces) == len(weights)
    for w, face in zip(weights, faces):
        np.testing.assert_array_equal(face, core.animate(feats, 45.0, posterior, guide_weight=w)["face"])
    assert np.abs(faces[0] - faces[2]).max() > 1e-3
