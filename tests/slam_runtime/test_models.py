import itertools

import numpy as np
import pytest

from detectors.geometry import compose
from slam_runtime.measurement import innovation, inverse, predict, sensor_pose
from slam_runtime.metrics import gospa, ospa, trajectory_rmse
from slam_runtime.motion import ackermann, odometry_increment, unicycle


def test_noise_free_odometry_composes_and_noise_matches_its_model():
    p0 = np.array([[1.0, 2.0, 0.5]])
    inc = np.array([0.4, 0.02, 0.1])
    np.testing.assert_allclose(odometry_increment(p0, inc, noise=False), compose(p0, inc), atol=1e-12)
    rng = np.random.default_rng(0)
    out = odometry_increment(np.zeros((40_000, 3)), inc, rng, a_trans=0.05, a_rot=0.05, a_rot_trans=0.01, lateral=0.0)
    d = np.hypot(inc[0], inc[1])
    # starting at the origin the increment is the pose: its x std is a_trans |d|, theta std a_rot |dth| + a_rot_trans |d|
    assert out[:, 0].std() == pytest.approx(0.05 * d, rel=0.03)
    assert out[:, 2].std() == pytest.approx(0.05 * 0.1 + 0.01 * d, rel=0.03)
    assert out[:, 0].mean() == pytest.approx(inc[0], abs=3 * 0.05 * d / 200)


def test_unicycle_closes_a_full_circle_and_goes_straight():
    p = np.array([[0.0, 0.0, 0.0]])
    for _ in range(100):
        p = unicycle(p, v=np.pi, omega=2 * np.pi / 10, dt=0.1, noise=False)
    np.testing.assert_allclose(p[0], [0.0, 0.0, 0.0], atol=1e-9)  # radius 5, once around
    q = unicycle(np.array([[1.0, 1.0, np.pi / 2]]), v=2.0, omega=0.0, dt=0.5, noise=False)
    np.testing.assert_allclose(q[0], [1.0, 2.0, np.pi / 2], atol=1e-12)


def test_ackermann_moves_the_encoder_speed_to_the_axle():
    L, H = 2.83, 0.76
    p = ackermann(np.zeros((1, 3)), speed=3.0, steer=0.0, dt=1.0, wheelbase=L, encoder_offset=H, noise=False)
    np.testing.assert_allclose(p[0], [3.0, 0.0, 0.0], atol=1e-12)
    steer = 0.2
    vc = 3.0 / (1 - np.tan(steer) * H / L)
    q = ackermann(np.zeros((1, 3)), speed=3.0, steer=steer, dt=0.1, wheelbase=L, encoder_offset=H, noise=False)
    np.testing.assert_allclose(q[0], [0.1 * vc, 0.0, 0.1 * vc / L * np.tan(steer)], atol=1e-12)


def test_measurement_model_round_trip_and_jacobian():
    rng = np.random.default_rng(1)
    veh = rng.uniform(-5, 5, (20, 3))
    s = sensor_pose(veh, np.array([3.78, 0.5, 0.0]))
    lm = rng.uniform(-20, 20, (20, 2))
    z, jac = predict(s, lm)
    back, _ = inverse(s, z)
    np.testing.assert_allclose(back, lm, atol=1e-9)
    eps = 1e-6
    for k in range(2):
        dl = np.zeros(2)
        dl[k] = eps
        num = innovation(predict(s, lm + dl)[0], predict(s, lm - dl)[0]) / (2 * eps)
        np.testing.assert_allclose(jac[..., k], num, rtol=1e-5, atol=1e-8)
    # a landmark straight ahead of a mounted sensor
    z0, _ = predict(sensor_pose(np.zeros(3), np.array([1.0, 0.0, 0.0])), np.array([11.0, 0.0]))
    np.testing.assert_allclose(z0, [10.0, 0.0], atol=1e-12)


def brute_ospa(x, y, c, p):
    """Independent OSPA: every permutation of the larger set."""
    if len(x) > len(y):
        x, y = y, x
    m, n = len(x), len(y)
    if n == 0:
        return 0.0
    best = min(
        sum(min(c, np.linalg.norm(x[i] - y[perm[i]])) ** p for i in range(m)) for perm in itertools.permutations(range(n), m)
    ) if m else 0.0
    return ((best + c**p * (n - m)) / n) ** (1 / p)


def test_ospa_matches_an_exhaustive_implementation():
    rng = np.random.default_rng(2)
    for _ in range(30):
        x = rng.uniform(0, 3, (rng.integers(0, 5), 2))
        y = rng.uniform(0, 3, (rng.integers(0, 6), 2))
        for c, p in ((1.0, 1.0), (0.5, 2.0)):
            assert ospa(x, y, c, p) == pytest.approx(brute_ospa(list(x), list(y), c, p), abs=1e-12)
    assert ospa(np.zeros((0, 2)), np.zeros((0, 2))) == 0.0 and ospa(np.zeros((0, 2)), np.ones((2, 2)), c=3.0) == 3.0


def test_gospa_parts():
    truth = np.array([[0.0, 0.0], [10.0, 0.0], [20.0, 0.0]])
    est = np.array([[0.3, 0.0], [10.0, 0.4], [50.0, 0.0], [60.0, 0.0]])
    g = gospa(est, truth, c=1.0, p=1.0)
    assert g["localisation"] == pytest.approx(0.7) and g["n_missed"] == 1 and g["n_false"] == 2
    assert g["gospa"] == pytest.approx(0.7 + 0.5 * 3)


def test_trajectory_rmse_with_and_without_alignment():
    rng = np.random.default_rng(3)
    truth = np.column_stack([rng.uniform(-10, 10, (50, 2)), rng.uniform(-3, 3, 50)])
    moved = compose(np.array([5.0, -2.0, 0.7]), truth)
    assert trajectory_rmse(moved, truth) > 1.0
    assert trajectory_rmse(moved, truth, align=True) == pytest.approx(0.0, abs=1e-9)
