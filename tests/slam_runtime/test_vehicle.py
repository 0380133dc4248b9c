"""Vehicle models: closed-form motions, their noise against its stated model, Jacobians against finite differences."""

import numpy as np
import pytest

from detectors.geometry import compose
from slam_runtime.vehicle import Ackermann, AckermannNoise, OdometryIncrement, Unicycle, VehicleModel


def test_noise_free_increment_composes_and_its_noise_matches_the_model():
    veh = OdometryIncrement(a_trans=0.05, a_rot=0.05, a_rot_trans=0.01, lateral=0.0)
    p0 = np.array([[1.0, 2.0, 0.5]])
    inc = np.array([0.4, 0.02, 0.1])
    np.testing.assert_allclose(veh.mean(p0, inc, 0.1), compose(p0, inc), atol=1e-12)
    out = veh.sample(np.zeros((40_000, 3)), inc, 0.1, np.random.default_rng(0))
    d = np.hypot(inc[0], inc[1])
    # from the origin the increment is the pose: x std a_trans |d|, theta std a_rot |dth| + a_rot_trans |d|
    # (40,000 draws: a sample std within 3 % of the truth is > 4 standard errors)
    assert out[:, 0].std() == pytest.approx(0.05 * d, rel=0.03)
    assert out[:, 2].std() == pytest.approx(0.05 * 0.1 + 0.01 * d, rel=0.03)
    assert out[:, 0].mean() == pytest.approx(inc[0], abs=3 * 0.05 * d / 200)


def test_the_constant_noise_term_moves_a_robot_that_stands_still():
    """A random walk of s^2 per second: after 100 steps of 0.1 s standing still, variance 10 s^2 per axis."""
    veh = OdometryIncrement(a_trans=0.0, a_rot=0.0, a_rot_trans=0.0, lateral=0.0, s_x=0.02, s_y=0.01, s_theta=0.005)
    rng = np.random.default_rng(1)
    x = np.zeros((20_000, 3))
    for _ in range(100):
        x = veh.sample(x, np.zeros(3), 0.1, rng)
    assert x[:, 2].std() == pytest.approx(0.005 * np.sqrt(10.0), rel=0.03)
    # the position spreads at least by the along/across walks (the heading walk rotates them, so >=)
    assert np.hypot(x[:, 0], x[:, 1]).std() > 0.3 * 0.02 * np.sqrt(10.0)
    assert OdometryIncrement().mean(np.zeros((1, 3)), np.zeros(3), 1.0)[0] == pytest.approx(np.zeros(3))


def test_unicycle_closes_a_full_circle_and_goes_straight():
    veh = Unicycle()
    p = np.array([[0.0, 0.0, 0.0]])
    for _ in range(100):
        p = veh.mean(p, np.array([np.pi, 2 * np.pi / 10]), 0.1)
    np.testing.assert_allclose(p[0], [0.0, 0.0, 0.0], atol=1e-9)  # radius 5, once around
    q = veh.mean(np.array([[1.0, 1.0, np.pi / 2]]), np.array([2.0, 0.0]), 0.5)
    np.testing.assert_allclose(q[0], [1.0, 2.0, np.pi / 2], atol=1e-12)


def test_unicycle_turn_rate_scale_and_offset():
    """A command omega turns by omega_scale * omega - omega_offset: a quarter circle commanded at pi/2 rad/s for 1 s
    turns by 0.9 * pi/2 - 0.05 with the scale 0.9 and the offset 0.05; the Jacobian's heading terms use the same rate."""
    veh = Unicycle(omega_scale=0.9, omega_offset=0.05)
    q = veh.mean(np.zeros((1, 3)), np.array([1.0, np.pi / 2]), 1.0)[0]
    w = 0.9 * np.pi / 2 - 0.05
    np.testing.assert_allclose(q, [np.sin(w) / w, (1 - np.cos(w)) / w, w], atol=1e-12)
    x = np.array([[0.3, -0.2, 0.4]])
    f, h = veh.jacobian(x, np.array([1.0, np.pi / 2]), 0.5), 1e-6
    xp, xm = x.copy(), x.copy()
    xp[0, 2] += h
    xm[0, 2] -= h
    fd = (veh.mean(xp, np.array([1.0, np.pi / 2]), 0.5) - veh.mean(xm, np.array([1.0, np.pi / 2]), 0.5))[0] / (2 * h)
    np.testing.assert_allclose(f[0, :, 2], fd, atol=1e-6)


def test_ackermann_moves_the_encoder_speed_to_the_axle_and_removes_the_steering_offset():
    L, H = 2.83, 0.76
    veh = Ackermann(L, H)
    np.testing.assert_allclose(veh.mean(np.zeros((1, 3)), np.array([3.0, 0.0]), 1.0)[0], [3.0, 0.0, 0.0], atol=1e-12)
    steer = 0.2
    vc = 3.0 / (1 - np.tan(steer) * H / L)
    q = veh.mean(np.zeros((1, 3)), np.array([3.0, steer]), 0.1)
    np.testing.assert_allclose(q[0], [0.1 * vc, 0.0, 0.1 * vc / L * np.tan(steer)], atol=1e-12)
    biased = Ackermann(L, H, steer_offset=0.01)
    np.testing.assert_allclose(biased.mean(np.zeros((1, 3)), np.array([3.0, steer + 0.01]), 0.1), q, atol=1e-12)


@pytest.mark.parametrize(
    "veh,u",
    [
        (OdometryIncrement(), np.array([0.4, -0.1, 0.2])),
        (Unicycle(), np.array([1.5, 0.7])),
        (Unicycle(), np.array([1.5, 0.0])),
        (Ackermann(2.83, 0.76), np.array([3.0, 0.15])),
    ],
)
def test_state_jacobians_agree_with_finite_differences(veh, u):
    rng = np.random.default_rng(2)
    x = np.column_stack([rng.uniform(-5, 5, (8, 2)), rng.uniform(-3, 3, 8)])
    f = veh.jacobian(x, u, 0.3)
    eps = 1e-6
    for k in range(3):
        dx = np.zeros(3)
        dx[k] = eps
        num = (veh.mean(x + dx, u, 0.3) - veh.mean(x - dx, u, 0.3)) / (2 * eps)
        np.testing.assert_allclose(f[:, :, k], num, atol=1e-7)


@pytest.mark.parametrize(
    "veh,u,dt",
    [
        (OdometryIncrement(a_trans=0.1, a_rot=0.1, lateral=0.05, s_theta=0.01), np.array([0.3, 0.01, 0.05]), 0.2),
        (Unicycle(sigma_v=0.1, sigma_omega=0.2), np.array([1.0, 0.4]), 0.1),
        (Ackermann(2.83, 0.76, sigma_speed=0.3, sigma_steer=0.03), np.array([4.0, 0.1]), 0.05),
    ],
)
def test_the_gaussian_of_the_motion_matches_its_samples(veh, u, dt):
    """Five control rows from one pose: the linearised mean and covariance (what the pose proposal starts
    from) against 40,000 sampled motions; the noise is small, so linearisation holds to a few per cent."""
    x0 = np.array([[1.0, -2.0, 0.3]])
    controls, dts = np.tile(u, (5, 1)), np.full(5, dt)
    mean, cov = veh.predict_gaussian(x0, controls, dts)
    rng = np.random.default_rng(5)
    x = np.repeat(x0, 40_000, axis=0)
    for uu, d in zip(controls, dts, strict=True):
        x = veh.sample(x, uu, d, rng)
    # the mean to 4 standard errors plus 5 % of the spread (the second-order terms the linearisation drops)
    sd = np.sqrt(np.diag(cov[0]))
    assert (np.abs(mean[0] - x.mean(axis=0)) <= 4 * sd / 200 + 0.05 * sd).all()
    emp = np.cov(x.T)
    np.testing.assert_allclose(np.sqrt(np.diag(cov[0])), np.sqrt(np.diag(emp)), rtol=0.05)


def test_ackermann_closed_form_gaussian_equals_the_generic_linearisation():
    """Ackermann's compiled predict_gaussian (control Jacobian written out) against the generic form
    (central differences of the model), with a steering offset and a speed scale, over a frame's rows."""
    rng = np.random.default_rng(4)
    veh = Ackermann(2.83, 0.76, sigma_speed=0.5, sigma_steer=0.05, steer_offset=-0.0055, speed_scale=1.012)
    x = np.column_stack([rng.normal(0, 5, (12, 2)), rng.uniform(-np.pi, np.pi, 12)])
    x[0, 2] = np.pi - 1e-4  # crosses the wrap point
    controls = np.column_stack([rng.uniform(0.0, 4.0, 7), rng.uniform(-0.5, 0.5, 7)])
    dts = rng.uniform(0.01, 0.05, 7)
    mean, cov = veh.predict_gaussian(x, controls, dts)
    ref_mean, ref_cov = VehicleModel.predict_gaussian(veh, x, controls, dts)
    np.testing.assert_allclose(mean, ref_mean, rtol=0, atol=1e-12)
    np.testing.assert_allclose(cov, ref_cov, rtol=1e-6, atol=1e-12)  # central differences are good to ~1e-9 here
    assert mean[0, 2] < 0  # wrapped
    # one offset per state (the bias search): the generic form
    search = Ackermann(2.83, 0.76, steer_offset=np.linspace(-0.01, 0.01, 12))
    m2, _ = search.predict_gaussian(x, controls, dts)
    np.testing.assert_allclose(m2, VehicleModel.predict_gaussian(search, x, controls, dts)[0])


def test_ackermann_offset_per_particle_gaussian_and_its_sensitivity():
    """The joint prediction of a pose and its particle's steering offset (steer_offset_sd > 0): with every particle at
    the same offset the pose's mean and control covariance are the fixed-offset model's; the sensitivity of the
    pose to the offset matches central differences of that model; the pose's covariance takes var S S^T and its
    covariance with the offset var S; conditioning on the predicted mean keeps the offset and lowers its variance
    by S^T q^-1 S var^2 (the Gaussian regression of the offset on the pose)."""
    rng = np.random.default_rng(5)
    L, H, off, sd = 2.83, 0.76, -0.0055, 0.01
    veh = Ackermann(L, H, sigma_speed=0.5, sigma_steer=0.05, steer_offset=off, speed_scale=1.012, steer_offset_sd=sd)
    assert veh.adaptive and veh.dim == 5
    x = veh.initial(np.array([1.0, 2.0, 3.1]), 6)
    x[:, :3] += np.column_stack([rng.normal(0, 5, (6, 2)), rng.normal(0, 0.1, 6)])
    np.testing.assert_array_equal(x[:, 3:], np.tile([off, sd**2], (6, 1)))
    controls = np.column_stack([rng.uniform(0.5, 4.0, 7), rng.uniform(-0.5, 0.5, 7)])
    dts = rng.uniform(0.01, 0.05, 7)
    xbar, q, cross = veh.predict_joint(x, controls, dts)
    fixed = Ackermann(L, H, sigma_speed=0.5, sigma_steer=0.05, steer_offset=off, speed_scale=1.012)
    m0, c0 = fixed.predict_gaussian(x[:, :3], controls, dts)
    np.testing.assert_allclose(xbar[:, :3], m0, rtol=0, atol=1e-12)
    np.testing.assert_array_equal(xbar[:, 3:], x[:, 3:])  # no walk: the offset's Gaussian is carried as it is
    eps = 1e-6
    up = Ackermann(L, H, steer_offset=off + eps, speed_scale=1.012).predict_gaussian(x[:, :3], controls, dts)[0]
    down = Ackermann(L, H, steer_offset=off - eps, speed_scale=1.012).predict_gaussian(x[:, :3], controls, dts)[0]
    sens = (up - down) / (2 * eps)
    np.testing.assert_allclose(cross, sd**2 * sens, rtol=1e-5, atol=1e-12)
    np.testing.assert_allclose(q, c0 + sd**2 * sens[:, :, None] * sens[:, None, :], rtol=1e-5, atol=1e-14)
    post = veh.condition(xbar, q, cross, xbar[:, :3])
    np.testing.assert_allclose(post[:, 3], off, atol=1e-15)
    drop = np.einsum("pi,pi->p", np.linalg.solve(q, cross[:, :, None])[..., 0], cross)
    np.testing.assert_allclose(post[:, 4], sd**2 - drop, rtol=1e-6)  # (condition regularises q by 1e-12 I)
    assert (post[:, 4] < sd**2).all() and (post[:, 4] > 0).all()
    # a pose turned further than predicted says the offset is lower (more turn to the left: a smaller offset)
    turned = xbar[:, :3].copy()
    turned[:, 2] += 0.01
    assert (veh.condition(xbar, q, cross, turned)[:, 3] < off).all()  # (every speed is forward here)
    # the walk widens the offset's variance by walk^2 times the frame's duration
    walk = Ackermann(L, H, sigma_speed=0.5, sigma_steer=0.05, steer_offset=off, steer_offset_sd=sd, steer_offset_walk=0.01)
    np.testing.assert_allclose(walk.predict_joint(x, controls, dts)[0][:, 4], sd**2 + 1e-4 * dts.sum())
    with pytest.raises(ValueError, match="needs steer_offset_sd"):
        AckermannNoise(steer_offset_walk=0.01)
