"""The shared pose proposal: the compiled range-bearing pass against the numpy batch it replaces, and the
proposal against the exact Gaussian posterior of a linear-Gaussian case."""

import numpy as np
import pytest

from profiles.errors import UsageError
from slam_runtime.features import RangeBearing
from slam_runtime.proposal import _compiled, pose_proposal, pose_proposal_numpy


def _case(seed: int, mount):
    """P particles near a true pose among J landmarks; the frame's measurements are some landmarks seen from
    the true pose plus two false alarms far from every landmark; some feature slots are padding (weight 0)."""
    rng = np.random.default_rng(seed)
    p, j = 9, 6
    fm = RangeBearing(np.diag([0.05**2, np.radians(1.0) ** 2]), np.asarray(mount, dtype=float))
    truth = np.array([1.0, -2.0, 0.4])
    lm = truth[:2] + rng.uniform(-4, 4, (j, 2))
    mu = lm[None] + rng.normal(0, 0.05, (p, j, 2))
    a = rng.normal(0, 0.03, (p, j, 2, 2))
    cov = a @ np.swapaxes(a, -1, -2) + np.eye(2) * 1e-3
    w = rng.uniform(0.3, 1.0, (p, j))
    w[rng.uniform(size=(p, j)) < 0.2] = 0.0
    xbar = truth + rng.normal(0, [0.05, 0.05, 0.02], (p, 3))
    b = rng.normal(0, 0.02, (p, 3, 3))
    q = b @ np.swapaxes(b, -1, -2) + np.diag([1e-4, 1e-4, 1e-5])
    q[0] = 0.0  # a vehicle standing still: no motion noise at all
    zt, _ = fm.predict(truth, lm[:4])
    z = np.vstack([zt + rng.normal(0, [0.05, np.radians(1.0)], zt.shape), [[30.0, 1.0], [45.0, -2.5]]])
    kappa = np.full(z.shape[0], 1e-2)
    return fm, xbar, q, z, mu, cov, w, kappa


@pytest.mark.parametrize("mount", [(0.0, 0.0, 0.0), (0.4, -0.1, 0.05)])
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_the_compiled_proposal_gives_the_numpy_batchs_numbers(seed, mount):
    fm, xbar, q, z, mu, cov, w, kappa = _case(seed, mount)
    rz = np.broadcast_to(fm.r, (z.shape[0], 2, 2))
    ref = pose_proposal_numpy(fm, xbar, q, z, rz, mu, cov, w, kappa, gate=16.0)
    got = pose_proposal(fm, xbar, q, z, rz, fm.r, mu, cov, w, kappa, gate=16.0)
    np.testing.assert_array_equal(got[2], ref[2])
    assert ref[2].min() >= 1 and ref[2].max() <= 4  # the landmarks' measurements are used, the clutter is not
    np.testing.assert_allclose(got[0], ref[0], rtol=0, atol=1e-12)
    np.testing.assert_allclose(got[1], ref[1], rtol=1e-10, atol=1e-18)


@pytest.mark.parametrize("seed", range(6))
def test_the_compiled_proposal_agrees_where_the_gate_and_the_share_decide(seed):
    """Dense maps (12 features within 3 m), headings anywhere on the circle (across +-pi), a sensor turned
    0.2 rad, clutter intensities from 1e-2 to 1e2: measurements compete for features and some are refused by
    the gate or the share test; the two implementations must use the same ones and give the same poses."""
    rng = np.random.default_rng(100 + seed)
    p, j = 40, 12
    fm = RangeBearing(np.diag([0.1**2, np.radians(2.0) ** 2]), np.array([0.3, 0.1, 0.2]))
    truth = np.array([0.0, 0.0, rng.uniform(-np.pi, np.pi)])
    lm = rng.uniform(-3, 3, (j, 2))
    mu = lm[None] + rng.normal(0, 0.1, (p, j, 2))
    cov = np.broadcast_to(np.eye(2) * 0.01, (p, j, 2, 2)).copy()
    w = rng.uniform(0.0, 1.0, (p, j))
    xbar = truth + rng.normal(0, [0.1, 0.1, 0.05], (p, 3))
    xbar[:, 2] = np.mod(xbar[:, 2] + np.pi, 2 * np.pi) - np.pi
    q = np.broadcast_to(np.diag([0.01, 0.01, 0.0025]), (p, 3, 3)).copy()
    zt, _ = fm.predict(truth, lm)
    z = zt + rng.normal(0, [0.1, np.radians(2.0)], zt.shape)
    kappa = 10.0 ** rng.uniform(-2, 2, z.shape[0])
    rz = np.broadcast_to(fm.r, (z.shape[0], 2, 2))
    ref = pose_proposal_numpy(fm, xbar, q, z, rz, mu, cov, w, kappa, gate=9.0)
    got = pose_proposal(fm, xbar, q, z, rz, fm.r, mu, cov, w, kappa, gate=9.0)
    np.testing.assert_array_equal(got[2], ref[2])
    assert 0 < ref[2].sum() < p * z.shape[0]  # some measurements used, some refused
    np.testing.assert_allclose(got[0], ref[0], rtol=0, atol=1e-12)
    np.testing.assert_allclose(got[1], ref[1], rtol=1e-9, atol=1e-18)


def test_a_rank_deficient_motion_prior_agrees_to_its_regularisation():
    """Ackermann odometry of one control row moves the vehicle along its heading and turns it, never sideways:
    q has rank 2. The information form inverts q + 1e-12 I, so the implementations agree to 1e-7 (module
    docstring), and neither moves the pose sideways by more than 1e-5 m."""
    fm, xbar, q, z, mu, cov, w, kappa = _case(5, (0.0, 0.0, 0.0))
    g = np.zeros((xbar.shape[0], 3, 2))
    g[:, 0, 0], g[:, 1, 0] = np.cos(xbar[:, 2]) * 0.1, np.sin(xbar[:, 2]) * 0.1
    g[:, 2, 1] = 0.05
    q = g @ np.swapaxes(g, 1, 2)
    rz = np.broadcast_to(fm.r, (z.shape[0], 2, 2))
    ref = pose_proposal_numpy(fm, xbar, q, z, rz, mu, cov, w, kappa, gate=16.0)
    got = pose_proposal(fm, xbar, q, z, rz, fm.r, mu, cov, w, kappa, gate=16.0)
    np.testing.assert_allclose(got[0], ref[0], rtol=0, atol=1e-7)
    side = -np.sin(xbar[:, 2]) * (got[0][:, 0] - xbar[:, 0]) + np.cos(xbar[:, 2]) * (got[0][:, 1] - xbar[:, 1])
    assert np.abs(side).max() < 1e-5


def test_no_iteration_is_refused():
    fm, xbar, q, z, mu, cov, w, kappa = _case(0, (0.0, 0.0, 0.0))
    with pytest.raises(UsageError, match="pose proposal: iterations must be at least 1, not 0"):
        pose_proposal(fm, xbar, q, z, np.broadcast_to(fm.r, (z.shape[0], 2, 2)), fm.r, mu, cov, w, kappa, gate=16.0, iterations=0)


def test_a_particle_whose_map_explains_nothing_keeps_its_motion_prior():
    fm, xbar, q, z, mu, cov, w, kappa = _case(3, (0.0, 0.0, 0.0))
    w[4] = 0.0  # particle 4 sees no feature
    rz = np.broadcast_to(fm.r, (z.shape[0], 2, 2))
    for impl in (
        lambda: pose_proposal(fm, xbar, q, z, rz, fm.r, mu, cov, w, kappa, gate=16.0),
        lambda: pose_proposal_numpy(fm, xbar, q, z, rz, mu, cov, w, kappa, gate=16.0),
    ):
        x, c, n = impl()
        assert n[4] == 0
        np.testing.assert_array_equal(x[4], xbar[4])
        np.testing.assert_array_equal(c[4], q[4])


def test_the_proposal_is_the_exact_posterior_of_a_near_linear_case():
    """A landmark 1,000 m ahead measured from the true pose: over a 1 cm / 1 mrad prior the range-bearing
    model is linear to 1e-8, so the iterated EKF must give the information-form posterior
    (Q^-1 + H^T S^-1 H)^-1 and its mean to that precision."""
    fm = RangeBearing(np.diag([0.02**2, 1e-3**2]))
    lm = np.array([[[1000.0, 0.0]]])
    cov_l = np.array([[[[1e-4, 0.0], [0.0, 1e-4]]]])
    truth = np.zeros(3)
    z, _ = fm.predict(truth, lm[0])
    xbar = np.array([[0.01, -0.01, 0.001]])
    q = np.diag([1e-4, 1e-4, 1e-6])[None]
    x, c, n = pose_proposal(
        fm, xbar, q, z, np.broadcast_to(fm.r, (1, 2, 2)), fm.r, lm, cov_l, np.ones((1, 1)), np.array([1e-6]), gate=16.0
    )
    assert n[0] == 1
    zh, hl = fm.predict(xbar[0], lm[0, 0])
    hx = fm.pose_jacobian(xbar[0], lm[0, 0])
    s = fm.r + hl @ cov_l[0, 0] @ hl.T
    info = np.linalg.inv(q[0]) + hx.T @ np.linalg.inv(s) @ hx
    want_c = np.linalg.inv(info)
    nu = z[0] - zh
    want_x = xbar[0] + want_c @ hx.T @ np.linalg.inv(s) @ nu
    np.testing.assert_allclose(c[0], want_c, rtol=1e-6, atol=1e-11)
    np.testing.assert_allclose(x[0], want_x, atol=1e-8)


def test_the_compiled_kernel_refuses_nothing_it_is_given_empty():
    """No feature in view of any particle: every particle keeps its prior."""
    fm, xbar, q, z, mu, cov, w, kappa = _case(4, (0.0, 0.0, 0.0))
    x, c, n = _compiled(xbar, q, z, fm.r, fm.mount, mu, cov, np.zeros_like(w), kappa, 16.0, 0.5, 3)
    assert not n.any()
    np.testing.assert_array_equal(x, xbar)
    np.testing.assert_array_equal(c, q)
