"""The range-bearing feature model: closed-form cases, round trip, Jacobians against finite differences."""

import numpy as np

from slam_runtime.features import RangeBearing, wrap

R = np.diag([0.01, 0.001])


def test_a_landmark_straight_ahead_of_a_mounted_sensor():
    fm = RangeBearing(R, np.array([1.0, 0.0, 0.0]))
    z, _ = fm.predict(np.zeros(3), np.array([11.0, 0.0]))
    np.testing.assert_allclose(z, [10.0, 0.0], atol=1e-12)
    z, _ = fm.predict(np.array([0.0, 0.0, np.pi / 2]), np.array([0.0, 6.0]))  # sensor at (0, 1) facing +y
    np.testing.assert_allclose(z, [5.0, 0.0], atol=1e-12)


def test_round_trip_and_jacobians():
    rng = np.random.default_rng(1)
    fm = RangeBearing(R, np.array([3.78, 0.5, 0.0]))
    veh = rng.uniform(-5, 5, (20, 3))
    lm = rng.uniform(-20, 20, (20, 2))
    z, h = fm.predict(veh, lm)
    back, g = fm.inverse(veh, z)
    np.testing.assert_allclose(back, lm, atol=1e-9)
    eps = 1e-6
    for k in range(2):
        d = np.zeros(2)
        d[k] = eps
        num = fm.innovation(fm.predict(veh, lm + d)[0], fm.predict(veh, lm - d)[0]) / (2 * eps)
        np.testing.assert_allclose(h[..., k], num, rtol=1e-5, atol=1e-8)
        num = (fm.inverse(veh, z + d)[0] - fm.inverse(veh, z - d)[0]) / (2 * eps)
        np.testing.assert_allclose(g[..., k], num, rtol=1e-5, atol=1e-7)


def test_innovation_wraps_the_bearing():
    fm = RangeBearing(R)
    nu = fm.innovation(np.array([[2.0, 3.1]]), np.array([[1.5, -3.1]]))
    np.testing.assert_allclose(nu, [[0.5, 6.2 - 2 * np.pi]], atol=1e-12)
    a = np.linspace(-2 * np.pi + 1e-9, 2 * np.pi, 1001)  # any difference of two wrapped angles
    w = wrap(a)
    assert (w > -np.pi).all() and (w <= np.pi).all()
    np.testing.assert_allclose(np.cos(w), np.cos(a), atol=1e-12)


def test_pose_jacobian_agrees_with_finite_differences():
    rng = np.random.default_rng(4)
    fm = RangeBearing(R, np.array([3.78, 0.5, 0.2]))
    veh = np.column_stack([rng.uniform(-5, 5, (12, 2)), rng.uniform(-3, 3, 12)])
    lm = rng.uniform(-20, 20, (12, 2))
    hx = fm.pose_jacobian(veh, lm)
    eps = 1e-6
    for k in range(3):
        d = np.zeros(3)
        d[k] = eps
        num = fm.innovation(fm.predict(veh + d, lm)[0], fm.predict(veh - d, lm)[0]) / (2 * eps)
        np.testing.assert_allclose(hx[..., k], num, rtol=1e-5, atol=1e-7)
