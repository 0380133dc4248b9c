"""The compiled helpers of the particle loop against their numpy or scipy references: the increment model's motion
Gaussian, the optimal proposal's pose log-density and the point features' line-of-sight geometry of P_D."""

import numpy as np

from slam_runtime.vehicle import OdometryIncrement, VehicleModel


def test_the_closed_form_motion_gaussian_is_the_generic_linearisations():
    """Several rows per frame, turning and sliding, every noise term on: mean and covariance as the generic form's
    (its control Jacobian by central differences of a function linear in the increment: exact to rounding, so 1e-7
    relative)."""
    rng = np.random.default_rng(5)
    veh = OdometryIncrement(a_trans=0.05, a_rot=0.1, a_rot_trans=0.02, lateral=0.03, s_x=0.01, s_y=0.02, s_theta=0.03)
    x = np.column_stack([rng.normal(size=(7, 2)), rng.uniform(-np.pi, np.pi, 7)])
    u = np.column_stack([rng.uniform(-0.3, 0.5, 4), rng.uniform(-0.1, 0.1, 4), rng.uniform(-0.4, 0.4, 4)])
    dts = rng.uniform(0.05, 0.2, 4)
    mean, cov = veh.predict_gaussian(x, u, dts)
    ref_mean, ref_cov = VehicleModel.predict_gaussian(veh, x, u, dts)
    np.testing.assert_allclose(mean, ref_mean, rtol=0, atol=1e-12)
    np.testing.assert_allclose(cov, ref_cov, rtol=1e-7, atol=1e-15)
    assert (np.linalg.eigvalsh(cov) > 0).all()


def test_the_compiled_pose_log_density_is_scipys():
    """The optimal proposal's weight correction: log N(x; mean, cov) of planar poses, the heading difference wrapped,
    against scipy's multivariate normal (1e-9: a Cholesky factor against LAPACK's, rounding only)."""
    from scipy.stats import multivariate_normal

    from slam_runtime.slam import _log_normal

    rng = np.random.default_rng(2)
    a = rng.normal(size=(6, 3, 3))
    cov = a @ np.swapaxes(a, 1, 2) * 1e-3 + np.eye(3) * 1e-4
    mean = rng.normal(size=(6, 3))
    x = mean + rng.normal(size=(6, 3)) * 0.05
    x[0, 2], mean[0, 2] = np.pi - 0.01, -np.pi + 0.01  # headings 0.02 rad apart across the wrap
    got = _log_normal(x, mean, cov)
    d = x - mean
    d[:, 2] = np.mod(d[:, 2] + np.pi, 2 * np.pi) - np.pi
    ref = [multivariate_normal(np.zeros(3), cov[i] + np.eye(3) * 1e-12).logpdf(d[i]) for i in range(6)]
    np.testing.assert_allclose(got, ref, rtol=1e-9)


def test_the_compiled_line_of_sight_is_the_numpy_geometrys():
    """P_D's geometry of point features (detectors.occlusion.line_of_sight): range, wrapped bearing and the position's
    spread along and across the line of sight, as written out in numpy (rounding only: 1e-12)."""
    from detectors.occlusion import line_of_sight

    rng = np.random.default_rng(3)
    sp = np.column_stack([rng.normal(size=(4, 2)), rng.uniform(-np.pi, np.pi, 4)])
    mu = rng.normal(size=(4, 5, 2)) * 3
    a = rng.normal(size=(4, 5, 2, 2))
    cov = a @ np.swapaxes(a, -1, -2) * 0.01
    z, s_rad, s_lat = line_of_sight(sp, mu, cov)
    los = mu - sp[:, None, :2]
    r = np.hypot(los[..., 0], los[..., 1])
    b = np.mod(np.arctan2(los[..., 1], los[..., 0]) - sp[:, None, 2] + np.pi, 2 * np.pi) - np.pi
    u = los / r[..., None]
    np.testing.assert_allclose(z[..., 0], r, rtol=1e-12)
    np.testing.assert_allclose(z[..., 1], b, rtol=0, atol=1e-12)
    np.testing.assert_allclose(s_rad**2, np.einsum("pji,pjik,pjk->pj", u, cov, u), rtol=1e-9)
    n = np.stack([-u[..., 1], u[..., 0]], axis=-1)
    np.testing.assert_allclose(s_lat**2, np.einsum("pji,pjik,pjk->pj", n, cov, n), rtol=1e-9)
