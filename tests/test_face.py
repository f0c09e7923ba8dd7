import numpy as np
import pytest

from voicepuppet import face, layout
from voicepuppet.evaluation import metrics


def _planted(rng, T=50, P=68):
    base = rng.normal(size=(P, 2)) * 40
    motion = rng.normal(size=(T, 1, 1)) * rng.normal(size=(1, P, 2)) * 2.0   # one mode of shape motion
    motion[:, list(layout.RIGID)] = 0                                   # the rigid points stay put
    pose = np.stack([rng.normal(0, 0.1, T), rng.normal(0, 0.2, T), rng.normal(160, 5, T),
                     rng.normal(150, 5, T)], axis=1)
    shapes = base + motion
    m = np.exp(pose[:, 0] + 1j * pose[:, 1])[:, None]
    z = m * (shapes[..., 0] + 1j * shapes[..., 1]) + (pose[:, 2] + 1j * pose[:, 3])[:, None]
    return np.stack([z.real, z.imag], axis=2), shapes, pose


def test_pose_removed_and_round_trip(rng):
    pts, shapes, pose = _planted(rng)
    w = np.zeros(68)
    w[list(layout.RIGID)] = 1
    fs = face.FaceSpace.fit(pts, weights=w)
    Y, est_pose = fs.encode(pts)
    # Planted: the rigid points do not move, so with the fit on them alone the normalised rigid
    # points are identical across frames.
    norm, _ = fs.normalize(pts)
    rigid = list(layout.RIGID)
    assert np.max(np.std(norm[:, rigid], axis=0)) < 1e-9
    # Pose differences between frames are recovered exactly (the reference's own pose is arbitrary).
    d_est = est_pose - est_pose[0]
    d_true = pose - pose[0]
    np.testing.assert_allclose(d_est[:, :2], d_true[:, :2], atol=1e-9)
    # Exact round trip with the full basis, at the frames' own pose.
    np.testing.assert_allclose(fs.decode(Y, est_pose), pts, atol=1e-8)
    # The planted single mode of motion needs one component.
    fs1 = face.FaceSpace.fit(pts, n_components=0.999999, weights=w)
    assert fs1.n_dims == 1
    Y1, p1 = fs1.encode(pts)
    np.testing.assert_allclose(fs1.decode(Y1, p1), pts, atol=1e-6)
    # The default weights (mouth and jaw weighted 0.05) leave a small pose leak, well under a pixel.
    fsd = face.FaceSpace.fit(pts)
    assert np.max(np.std(fsd.normalize(pts)[0][:, rigid], axis=0)) < 0.2


def test_pca_truncation_error_is_discarded_variance(rng):
    pts = rng.normal(size=(200, 10, 2)) + np.arange(10)[None, :, None] * 10
    fs_all = face.FaceSpace.fit(pts)
    fs3 = face.FaceSpace.fit(pts, n_components=3)
    Y, pose = fs3.encode(pts)
    shapes, _ = fs3.normalize(pts)
    resid = np.sum((fs3.shapes(Y) - shapes) ** 2) / (len(pts) - 1)
    np.testing.assert_allclose(resid, fs_all.variances[0][3:].sum(), rtol=1e-9)
    assert fs3.n_dims == 3 and face.FaceSpace.fit(pts, max_components=5).n_dims == 5


def test_parts_partition_and_storage(rng):
    pts, _, _ = _planted(rng, T=30)
    fs = face.FaceSpace.fit(pts, n_components=4, parts="upper_lower")
    assert fs.part_names == ["upper", "lower"] and fs.n_dims == 8
    Y, pose = fs.encode(pts)
    again = face.FaceSpace.from_arrays(fs.to_arrays(), fs.part_names)
    np.testing.assert_array_equal(again.encode(pts)[0], Y)
    with pytest.raises(ValueError, match="partition"):
        face.FaceSpace.fit(pts, parts={"a": range(0, 40), "b": range(30, 68)})
    with pytest.raises(ValueError, match="68-point"):
        face.FaceSpace.fit(pts[:, :10], parts="upper_lower")


def test_bad_landmarks():
    with pytest.raises(ValueError, match="shape"):
        face.FaceSpace.fit(np.zeros((5, 68)))
    bad = np.ones((4, 5, 2)) + np.arange(5)[None, :, None]
    bad[2, 3, 0] = np.nan
    with pytest.raises(ValueError, match="frame 2, point 3"):
        face.FaceSpace.fit(bad)
    with pytest.raises(ValueError, match="coincide"):
        face.FaceSpace.fit(np.ones((4, 5, 2)))


def test_shape_distance_ignores_pose_and_measures_shape(rng):
    """0 for a scaled, turned, moved copy of the rest; for a shape with one point moved by d, the
    least-squares residual over a similarity fit by lstsq (the closed form's peer)."""
    rest = rng.normal(0, 30, (12, 2)) + 100
    th = 0.3
    R = np.array([[np.cos(th), np.sin(th)], [-np.sin(th), np.cos(th)]])
    moved = 1.7 * rest @ R + [40.0, -7.0]
    bent = rest.copy()
    bent[3] += [0.0, 9.0]
    bent = 0.8 * bent @ R.T - [5.0, 12.0]
    d = face.shape_distance(np.stack([moved, bent]), rest)
    assert d[0] < 1e-12
    # peer: x' = a x - b y + tx, y' = b x + a y + ty fitted by least squares
    A = np.zeros((24, 4))
    A[0::2] = np.column_stack([bent[:, 0], -bent[:, 1], np.ones(12), np.zeros(12)])
    A[1::2] = np.column_stack([bent[:, 1], bent[:, 0], np.zeros(12), np.ones(12)])
    coef, *_ = np.linalg.lstsq(A, rest.reshape(-1), rcond=None)
    resid = rest.reshape(-1) - A @ coef
    radius = np.sqrt(((rest - rest.mean(axis=0)) ** 2).sum())
    assert d[1] == pytest.approx(np.sqrt((resid ** 2).sum()) / radius, rel=1e-10)


def test_observations():
    Y = np.arange(12, dtype=float).reshape(6, 2) ** 2
    O = face.observations(Y, lengths=[4, 2])
    np.testing.assert_array_equal(O[:, :2], Y)
    np.testing.assert_array_equal(O[1:4, 2:], np.diff(Y[:4], axis=0))
    np.testing.assert_array_equal(O[0, 2:], O[1, 2:])
    np.testing.assert_array_equal(O[4, 2:], Y[5] - Y[4])
    with pytest.raises(ValueError, match="sum"):
        face.observations(Y, lengths=[3, 2])


def test_err_closed_forms(rng):
    y = rng.normal(size=(40, 6))
    motion = y - y.mean(axis=0)
    assert metrics.err(y, y) == 0
    assert metrics.err(np.broadcast_to(y.mean(axis=0), y.shape), y) == pytest.approx(1.0)
    assert metrics.err(y.mean(axis=0) + 0.5 * motion, y) == pytest.approx(0.25 / 2.25)
    assert metrics.err(y.mean(axis=0) + 2 * motion, y) == pytest.approx(1 / 9)
    with pytest.raises(ValueError, match="same shape"):
        metrics.err(y[:-1], y)


def test_landmark_measures_by_hand():
    truth = np.zeros((2, 68, 2))
    truth[:, 45, 0] = 10.0                  # inter-ocular distance 10
    pred = truth.copy()
    pred[0, 50] += [3.0, 4.0]               # frame 0: one mouth point off by 5 px
    pred[1, 10] += [0.0, 2.0]               # frame 1: a jaw point off by 2 px
    assert metrics.lip_vertex_error(pred, truth) == pytest.approx((25 + 0) / 2)
    expected = (np.sqrt(25 / 68) / 10 + np.sqrt(4 / 68) / 10) / 2
    assert metrics.landmark_rmse_iod(pred, truth) == pytest.approx(expected)
    s = metrics.summary(pred, truth)
    assert set(s) >= {"err", "l1", "rms", "linf", "rmse_iod", "lve"} and s["linf"] == 4.0
