"""A puppet file that passes its checksum is still checked for meaning: each mutant below is
re-encoded with a valid checksum (the way a hostile or buggy tool would write it) and ``load``
refuses it with a ValueError naming the field, never another exception. The checksum covers the
whole file, header included."""
import json
import struct
import zlib

import numpy as np
import pytest

from voicepuppet import _core
from voicepuppet.puppet.model import Puppet, load

from support import planted_puppet_data


@pytest.fixture(scope="module")
def good(tmp_path_factory):
    """A small trained puppet's file bytes, and features to animate it with."""
    rng = np.random.default_rng(7)
    pts, feats, _ = planted_puppet_data(rng, T=450)
    p = Puppet.train([pts], features_list=[feats], fps=30.0, n_states=5, n_iter=10, n_components=3)
    path = p.save(tmp_path_factory.mktemp("valid") / "p.vpp")
    return path.read_bytes(), feats[:60]


def reencode(data: bytes, edit_meta=None, edit_arrays=None, raw_meta: bytes | None = None) -> bytes:
    """``data`` decoded, its metadata (a dict) and arrays edited in place by the given
    functions, encoded again with a valid checksum."""
    text, arrays = _core.decode_puppet(data)
    meta = json.loads(text)
    if edit_meta:
        edit_meta(meta)
    if edit_arrays:
        edit_arrays(arrays)
    return _core.encode_puppet(raw_meta if raw_meta is not None else json.dumps(meta), arrays)


def with_crc(data: bytes) -> bytes:
    """``data`` with the checksum of format version 3 recomputed: bytes 0..23, 28..31, payload."""
    crc = zlib.crc32(data[32:], zlib.crc32(data[28:32], zlib.crc32(data[:24])))
    return data[:24] + struct.pack("<I", crc) + data[28:]


def _set(key, value):
    def edit(d):
        d[key] = value
    return edit


def _drop(key):
    def edit(d):
        del d[key]
    return edit


def _scale(key, factor):
    def edit(d):
        d[key] = d[key] * factor
    return edit


def _part_entry(key, value):
    def edit(meta):
        meta["training"]["parts"][0][key] = value
    return edit


def _not_pd(d):
    c = d["hmm/part0/face_covars"].copy()
    c[1] = -np.eye(c.shape[1])
    d["hmm/part0/face_covars"] = c


def _vocal_not_pd(d):
    c = d["hmm/part0/vocal_covars"].copy()
    c[0] = c[0] - 10 * np.abs(c[0]).max() * np.eye(c.shape[1])
    d["hmm/part0/vocal_covars"] = c


def _row_not_one(d):
    t = d["hmm/part0/transmat"].copy()
    t[0] *= 0.5
    d["hmm/part0/transmat"] = t


def _negative_start(d):
    s = d["hmm/part0/startprob"].copy()
    s[0] += 1.0
    s[1] -= 1.0
    d["hmm/part0/startprob"] = s


ARRAY_MUTANTS = [
    ("fps 1e9", _set("fps", np.array([1e9])), r"fps = 1e\+09 is outside \[1, 1000\]"),
    ("fps 0", _set("fps", np.array([0.0])), r"fps = 0 is outside \[1, 1000\]"),
    ("fps NaN", _set("fps", np.array([np.nan])), r"'fps' contains NaN"),
    ("missing transmat", _drop("hmm/part0/transmat"), "no array 'hmm/part0/transmat'"),
    ("points as floats", lambda d: d.update({"face/part0/points": d["face/part0/points"].astype(float)}),
     "'face/part0/points' must be int64"),
    ("covariance not positive definite", _not_pd, "'hmm/part0/face_covars' is not valid"),
    ("vocal covariance not positive definite", _vocal_not_pd, "'hmm/part0/vocal_covars' is not valid"),
    ("transition row sums to 0.5", _row_not_one, "transmat row 0 must sum to 1"),
    ("negative start probability", _negative_start, "startprob has negative entries"),
    ("vocal means of another width", lambda d: d.update(
        {"hmm/part0/vocal_means": np.hstack([d["hmm/part0/vocal_means"]] * 2)}), "'hmm/part0/vocal_means' must be"),
    ("face means of another state count", lambda d: d.update(
        {"hmm/part0/face_means": d["hmm/part0/face_means"][:-1]}), "'hmm/part0/face_means' must be"),
    ("a point index out of range", lambda d: d.update(
        {"face/part0/points": d["face/part0/points"] + 1000}), "names point"),
    ("infinite mean", lambda d: d.update({"hmm/part0/vocal_means": d["hmm/part0/vocal_means"] * np.inf}),
     "contains NaN or infinite"),
    ("huge vocal means", _scale("hmm/part0/vocal_means", 1e200), r"vocal_means' largest \|value\|"),
    ("huge scale", lambda d: d.update({"face/mean_pose": d["face/mean_pose"] + [200.0, 0, 0, 0]}),
     r"mean_pose\[0\] \(log scale\) = .* is outside \[-14, 14\]"),
    ("huge face means", _scale("hmm/part0/face_means", 1e40), r"px, outside \[-1e\+06, 1e\+06\]"),
    ("basis not orthonormal", _scale("face/part0/basis", 1e30), "orthonormal rows"),
    ("no face weights", _drop("face/weights"), "no array 'face/weights'"),
]


@pytest.mark.parametrize("edit, match", [m[1:] for m in ARRAY_MUTANTS], ids=[m[0] for m in ARRAY_MUTANTS])
def test_checksum_valid_puppets_with_wrong_arrays_are_refused(good, tmp_path, edit, match):
    path = tmp_path / "m.vpp"
    path.write_bytes(reencode(good[0], edit_arrays=edit))
    with pytest.raises(ValueError, match=match) as err:
        load(path)
    assert str(path) in str(err.value)


META_MUTANTS = [
    ("no part list", _drop("parts"), "lacks its part list"),
    ("parts a number", _set("parts", 5), "parts must be a list of 1 names"),
    ("two part names for one part", _set("parts", ["a", "b"]), "parts must be a list of 1 names"),
    ("feature set a list", _set("feature_set", [1, 2]), "feature_set must be JSON text"),
    ("feature set of another shape", _set("feature_set", "[1, 2]"), "feature_set does not describe"),
    ("feature set not JSON", _set("feature_set", "{"), "feature_set does not describe"),
    ("a feature set of 1e9 mel bands", lambda m: m.update(feature_set=json.dumps(
        {**json.loads(m["feature_set"]), "options": {"n_mels": 10 ** 9}})), "n_mels must be a whole number"),
    ("feature names a string", _set("feature_names", "mfcc"), "feature_names must be a list of 5 names"),
    ("feature names null", _set("feature_names", None), "feature_names must be a list of 5 names"),
    ("fps disagrees", _set("fps", 1e9), "fps must be the arrays' frame rate 30"),
    ("n_points a string", _set("n_points", "12"), "n_points must be the arrays' 12 points"),
    ("training a list", _set("training", [1]), "training must be an object"),
    ("huge state count", _part_entry("states", 1e308), r"training.parts\[0\].states must be a whole number"),
    ("state count text", _part_entry("states", "six"), r"training.parts\[0\].states must be a whole number"),
    ("state count of 400 digits", _part_entry("states", 10 ** 400), r"training.parts\[0\].states must be a whole"),
    ("perplexity of 400 digits", _part_entry("perplexity", 10 ** 400), r"parts\[0\].perplexity must be a number"),
    ("fps of 400 digits", _set("fps", 10 ** 400), "fps must be the arrays' frame rate 30"),
    ("perplexity text", _part_entry("perplexity", "high"), r"training.parts\[0\].perplexity must be a number"),
    ("no part name", _part_entry("part", None), r"training.parts\[0\].part must be the part's name"),
    ("cv lists of two lengths", lambda m: m["training"].setdefault("guide", {}).update(
        weight_cv={"weights": [0, 1], "mse": [1.0]}), "weight_cv must hold lists"),
]


@pytest.mark.parametrize("edit, match", [m[1:] for m in META_MUTANTS], ids=[m[0] for m in META_MUTANTS])
def test_checksum_valid_puppets_with_wrong_metadata_are_refused(good, tmp_path, edit, match):
    path = tmp_path / "m.vpp"
    path.write_bytes(reencode(good[0], edit_meta=edit))
    with pytest.raises(ValueError, match=match) as err:
        load(path)
    assert str(path) in str(err.value)


def _meta_text(good, tail: str) -> bytes:
    text, _ = _core.decode_puppet(good[0])
    return (text[:-1] + ", " + tail + "}").encode()


RAW_META = [
    ("deeply nested", lambda g: _meta_text(g, '"x": ' + "[" * 100_000 + "]" * 100_000),
     "nests arrays and objects deeper than 64 levels"),
    ("nested 65 levels", lambda g: _meta_text(g, '"x": ' + "[" * 65 + "]" * 65), "deeper than 64 levels"),
    ("not UTF-8", lambda g: _meta_text(g, '"x": "\xff"').replace(b"\xc3\xbf", b"\xff"), "not valid UTF-8"),
    ("a number of 5000 digits", lambda g: _meta_text(g, '"x": ' + "9" * 5000), "unreadable metadata"),
    ("a number beyond float", lambda g: _meta_text(g, '"fps": 1e999'), "fps must be the arrays' frame rate"),
    ("not JSON", lambda g: b"{parts", "unreadable metadata"),
    ("a JSON list", lambda g: b"[1, 2]", "lacks its part list"),
]


@pytest.mark.parametrize("make, match", [m[1:] for m in RAW_META], ids=[m[0] for m in RAW_META])
def test_checksum_valid_puppets_with_unreadable_metadata_are_refused(good, tmp_path, make, match):
    path = tmp_path / "m.vpp"
    path.write_bytes(reencode(good[0], raw_meta=make(good)))
    with pytest.raises(ValueError, match=match):
        load(path)


def test_brackets_inside_strings_do_not_count_as_nesting(good, tmp_path):
    path = tmp_path / "m.vpp"
    path.write_bytes(reencode(good[0], raw_meta=_meta_text(good, '"x": "' + "[{" * 1000 + '\\" ]"')))
    assert load(path).metadata["x"] == "[{" * 1000 + '" ]'


def test_the_checksum_covers_the_header(good, tmp_path):
    data = good[0]
    assert data[8] == 3 and _core.PUPPET_FORMAT_VERSION == 3
    path = tmp_path / "m.vpp"
    for offset, value in ((12, 1), (28, 1), (8, 2), (8, 1)):  # flags, reserved, version
        changed = bytearray(data)
        changed[offset] = value
        path.write_bytes(bytes(changed))
        with pytest.raises(ValueError, match="checksum mismatch"):
            load(path)
    flagged = bytearray(data)
    flagged[12] = 1
    path.write_bytes(with_crc(bytes(flagged)))  # a writer that sets flags this version does not know
    with pytest.raises(ValueError, match="header flags 1"):
        load(path)
    path.write_bytes(with_crc(data))
    assert load(path).n_points == 12


def test_a_version_1_header_on_a_guided_file_is_refused(good, tmp_path):
    # versions 1 and 2 checked their payload only: the header's version could change unnoticed
    data = bytearray(good[0])
    data[8] = 1
    data[24:28] = struct.pack("<I", zlib.crc32(bytes(data[32:])))
    path = tmp_path / "m.vpp"
    path.write_bytes(bytes(data))
    assert "guide/map" in _core.decode_puppet(good[0])[1]
    with pytest.raises(ValueError, match="format version 1 but holds a guide"):
        load(path)
    data[8] = 2
    path.write_bytes(bytes(data))
    assert load(path).guided


@pytest.mark.parametrize("key, factor, match", [
    ("guide/offset", 1e10, r"the animation puts point \d+ of frame \d+ at .* px, outside"),
    ("audio/std", 1e-10, r"audio feature \d+ of frame \d+ is .* standard deviations from the puppet's training mean"),
])
def test_an_animation_beyond_the_pixel_range_is_refused(good, tmp_path, key, factor, match):
    # the guide's prediction (scaled up) carries the face 1e10 px away, the standardised features
    # (the std scaled down) beyond any state: animate says so instead of returning it
    path = tmp_path / "m.vpp"
    path.write_bytes(reencode(good[0], edit_arrays=_scale(key, factor)))
    p = load(path)
    with pytest.raises(ValueError, match=match):
        p.animate(features=good[1])


def test_what_loads_animates_and_output_rates_are_limited(good, tmp_path):
    path = tmp_path / "p.vpp"
    path.write_bytes(good[0])
    p = load(path)
    feats = good[1]
    assert np.isfinite(p.animate(features=feats, fps=1000).animation.points).all()
    assert np.isfinite(p.animate(features=feats, fps=1).animation.points).all()
    for fps in (1e9, 0.5, float("nan"), float("inf")):
        with pytest.raises(ValueError, match=r"output fps = .* is outside \[1, 1000\]"):
            p.animate(features=feats, fps=fps)
    with pytest.raises(ValueError, match=r"output fps = 1e\+09 is outside \[1, 1000\]"):
        p._core.animate(np.ascontiguousarray(feats), 1e9)
    with pytest.raises(ValueError, match=r"states_fps = 1e\+09 is outside \[1, 1000\]"):
        p.animate(states=np.zeros(10, dtype=np.int64), states_fps=1e9)
    # a C++ caller gets the same checks: 10^7 frames at 1000 fps out of 30 would be 3.3e8 frames
    with pytest.raises(ValueError, match=r"output frames .* is outside \[1, 10000000\]"):
        p._core.animate_states(np.zeros((400_000, 1), dtype=np.int64), 30.0, 1000.0)


def test_standardised_features_beyond_reach_are_refused_before_decoding(good, tmp_path):
    # audio/mean moved 1e300 away: no state explains any frame (every log density -inf); once the
    # decoder's "zero probability" RuntimeError, now a ValueError naming the standardisation
    path = tmp_path / "m.vpp"
    path.write_bytes(reencode(good[0], edit_arrays=_scale("audio/mean", 1e300)))
    with pytest.raises(ValueError, match=r"standard deviations from the puppet's training mean, beyond 1e\+06"):
        load(path).animate(features=good[1])


# Values that break numerics: zeros, signs, the ends of the double range, NaN and infinities.
_EXTREMES = [0.0, -1.0, 0.5, 1e-300, 1e-12, 1e12, 1e300, np.nan, np.inf, -np.inf]


def test_checksum_valid_mutants_load_and_animate_or_are_refused(good, tmp_path):
    """Property: a checksum-valid mutant of a trained puppet (entries of any array set to, scaled by,
    or shifted by anything) is refused with a ValueError at load or animate, or animates to a
    finite animation; never another exception."""
    hypothesis = pytest.importorskip("hypothesis", reason="the property tests need hypothesis (test extra)")
    st = hypothesis.strategies

    text, arrays = _core.decode_puppet(good[0])
    names = sorted(k for k, v in arrays.items() if np.asarray(v).dtype.kind == "f" and np.asarray(v).size)
    path = tmp_path / "m.vpp"
    seen = {"refused": 0, "animated": 0}

    @hypothesis.settings(max_examples=300, deadline=None, derandomize=True, database=None,
                         suppress_health_check=list(hypothesis.HealthCheck))
    @hypothesis.given(name=st.sampled_from(names), how=st.sampled_from(["set", "scale", "shift"]),
                      value=st.sampled_from(_EXTREMES) | st.floats(-1e6, 1e6),
                      where=st.lists(st.integers(0, 10 ** 6), min_size=1, max_size=4))
    def check(name, how, value, where):
        mutant = {k: np.array(v, copy=True) for k, v in arrays.items()}
        flat = mutant[name].reshape(-1)
        idx = np.array(where) % flat.size
        with np.errstate(all="ignore"):
            if how == "set":
                flat[idx] = value
            elif how == "scale":
                flat[idx] *= value
            else:
                flat[idx] += value
        path.write_bytes(_core.encode_puppet(text, mutant))
        try:
            points = load(path).animate(features=good[1]).animation.points
        except ValueError:
            seen["refused"] += 1
            return
        assert np.isfinite(points).all() and np.abs(points).max() <= 1e6
        seen["animated"] += 1

    check()
    assert seen["refused"] > 50 and seen["animated"] > 50, seen  # both outcomes are exercised
