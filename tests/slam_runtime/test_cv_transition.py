"""The constant-velocity feature transition and the moving point's measurement model against finite differences
and sampling."""

import numpy as np
import pytest

from slam_runtime.cv_transition import MovingPoint, jacobians, predict, process_noise, sample, transition
from slam_runtime.features import RangeBearing


def _fd(f, x, eps=1e-6):
    """Central finite differences of f (..., k) -> (..., n) at x (k,): (n, k)."""
    cols = []
    for i in range(x.size):
        d = np.zeros_like(x)
        d[i] = eps
        cols.append((f(x + d) - f(x - d)) / (2 * eps))
    return np.stack(cols, axis=-1)


@pytest.mark.parametrize("dt", [0.1, 1.0, 2.5])
def test_jacobians_match_finite_differences(dt):
    rng = np.random.default_rng(int(dt * 10))
    m, v = rng.normal(0, 10, 4), rng.normal(0, 1, 2)
    jm, jv = jacobians(m, dt)
    np.testing.assert_allclose(jm, _fd(lambda x: transition(x, v, dt), m), atol=1e-7)
    np.testing.assert_allclose(jv, _fd(lambda x: transition(m, x, dt), v), atol=1e-7)
    # the position moves by v dt plus half the acceleration's dt^2
    out = transition(m, v, dt)
    np.testing.assert_allclose(out[:2], m[:2] + dt * m[2:] + 0.5 * dt * dt * v)
    np.testing.assert_allclose(out[2:], m[2:] + dt * v)


def test_predict_matches_sampling():
    """F mu and F P F^T + Q against 200,000 seeded draws of the prior and the noise: the sample mean and
    covariance agree within 4 standard errors (each entry's standard error from the draws themselves)."""
    rng = np.random.default_rng(0)
    mu = np.array([100.0, -50.0, 3.0, -1.0])
    a = rng.normal(0, 1, (4, 4))
    cov = a @ a.T + np.eye(4)
    m1, c1 = predict(mu, cov, 1.0, 0.5)
    x = rng.multivariate_normal(mu, cov, 200_000)
    y = sample(x, 1.0, 0.5, rng)
    assert np.all(np.abs(y.mean(axis=0) - m1) < 4 * np.sqrt(np.diag(c1) / y.shape[0]))
    emp = np.cov(y.T)
    se = np.sqrt((c1**2 + np.outer(np.diag(c1), np.diag(c1))) / y.shape[0])  # of a Gaussian sample covariance
    assert np.all(np.abs(emp - c1) < 4 * se)


def test_process_noise_is_the_papers():
    """Q = sigma^2 B B^T with B = [[T^2/2 I], [T I]] (Li & Yang sec. 4: 0.5^2 B B^T, T = 1)."""
    q = process_noise(1.0, 0.5)
    b = np.array([[0.5, 0], [0, 0.5], [1, 0], [0, 1]])
    np.testing.assert_allclose(q, 0.25 * b @ b.T)


def test_moving_point_measures_its_position():
    """The moving point's predicted measurement is the static point's of its position, its Jacobian matches finite
    differences (zero for the velocity), and the inverse model returns the position with velocity 0."""
    r = np.diag([1.0, 0.01])
    mount = np.array([0.3, -0.1, 0.2])
    mp, rb = MovingPoint(r, mount, birth_speed=2.0), RangeBearing(r, mount)
    pose = np.array([1.0, 2.0, 0.4])
    x = np.array([30.0, -12.0, 4.0, 1.5])
    z, h = mp.predict(pose, x)
    z2, _ = rb.predict(pose, x[:2])
    np.testing.assert_allclose(z, z2)
    np.testing.assert_allclose(h, _fd(lambda s: mp.predict(pose, s)[0], x), atol=1e-6)
    assert not h[:, 2:].any()
    back, g = mp.inverse(pose, z)
    np.testing.assert_allclose(back, [30.0, -12.0, 0.0, 0.0], atol=1e-9)
    assert g.shape == (4, 2) and not g[2:].any()
    np.testing.assert_allclose(mp.birth_cov[2:, 2:], np.eye(2) * 4.0)
    np.testing.assert_allclose(mp.position(x), x[:2])
    np.testing.assert_allclose(mp.pose_jacobian(pose, x), rb.pose_jacobian(pose, x[:2]))


def test_moving_point_refuses_a_bad_birth_speed():
    with pytest.raises(ValueError, match="birth_speed must be above 0"):
        MovingPoint(np.eye(2), birth_speed=0.0)


def test_position_view_hands_the_detection_model_positions():
    """A filter of moving points asks the detection model through PositionView: the model sees (x, y) and the
    position block of the covariance, and answers as for static points; other attributes are the model's."""
    from detectors.model import DetectionModel
    from profiles.schema import ClutterParams, PdTable, SensorModel
    from slam_runtime.cv_transition import ConstantVelocity, PositionView

    sensor = SensorModel(kind="camera", fov=np.pi, range_max=20.0)
    det = DetectionModel(PdTable(covariate="range", edges=[0.0, 20.0], pd=[0.8]), ClutterParams(rate=2.0, volume=np.pi * 20.0), sensor)
    view = PositionView(det)
    mu = np.array([[[5.0, 1.0, 3.0, -2.0], [25.0, 0.0, 0.0, 0.0]]])
    cov = np.broadcast_to(np.diag([0.1, 0.1, 4.0, 4.0]), (1, 2, 4, 4))
    pd, buf = view.pd_features(np.zeros((1, 3)), mu, cov, None)
    pd2, buf2 = det.pd_features(np.zeros((1, 3)), mu[..., :2], cov[..., :2, :2], None)
    np.testing.assert_array_equal(pd, pd2)
    np.testing.assert_array_equal(buf, buf2)
    assert view.clutter_intensity(np.array([[5.0, 0.1]]))[0] == det.clutter_intensity(np.array([[5.0, 0.1]]))[0]
    m1, c1 = ConstantVelocity(0.5).predict(mu[0], cov[0], 2.0)
    np.testing.assert_allclose(m1[0], [11.0, -3.0, 3.0, -2.0])
    np.testing.assert_allclose(c1, predict(mu[0], cov[0], 2.0, 0.5)[1])
