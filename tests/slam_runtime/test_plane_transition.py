"""The plane transition model (eq. 35), Algorithm 1 and the EKF form."""

from __future__ import annotations

import numpy as np

from detectors.geometry3d import beta_from_hesse, hesse_from_beta, pose_matrix
from slam_runtime.ect import ECT, POSE
from slam_runtime.plane_transition import algorithm1, ekf_predict, motion_matrix, predict_planes, transition_jacobians
from tests.detectors.test_geometry3d import fd


def random_betas(rng, *shape):
    n = rng.normal(size=shape + (3,))
    n /= np.linalg.norm(n, axis=-1, keepdims=True)
    return beta_from_hesse(n, rng.uniform(1, 20, shape))


def test_points_stay_on_their_planes():
    """A static world point on a plane in the vehicle frame at k is on the transformed plane in the frame at k+1."""
    rng = np.random.default_rng(0)
    pk, pk1 = np.array([1.0, 2.0, 0.3]), np.array([2.5, 2.9, 0.45])
    b = random_betas(rng, 20)
    n, d = hesse_from_beta(b)
    rk = n * d[:, None] + np.cross(n, [0, 0, 1.0]) * 2.0  # points on the planes, vehicle frame k
    world = (pose_matrix(pk) @ np.c_[rk, np.ones(20)].T).T
    rk1 = (np.linalg.inv(pose_matrix(pk1)) @ world.T).T
    b1 = predict_planes(b, motion_matrix(pk, pk1))
    assert np.allclose((b1 * rk1).sum(1), 0.0, atol=1e-12)
    assert np.allclose(b1, b @ motion_matrix(pk, pk1))  # the three-column form is the full product


def test_algorithm1_vectorised_equals_the_loop():
    """Algorithm 1 over P vehicle particles x L planes x N plane particles equals its per-particle loop (steps 1-11)."""
    rng = np.random.default_rng(1)
    ect = ECT()
    x = ect.initial(np.array([3.0, -2.0, 0.2]), 4)
    x[:, 1], x[:, 3], x[:, 5] = 6.0, 1.0, 0.1
    b = random_betas(rng, 3, 50)
    w = rng.uniform(0.1, 1.0, (3, 50))
    x1, b1, w1, eap = algorithm1(ect, x, b, w, 0.1, np.random.default_rng(2))
    u = np.random.default_rng(2).standard_normal((4, 3)) * ect.sig_acc  # the same noise sample (step 2)
    for p in range(4):
        xp1 = ect.propagate(x[p : p + 1], 0.1, u=u[p : p + 1])[0]
        assert np.allclose(xp1, x1[p])
        m = np.linalg.inv(pose_matrix(x[p, POSE])) @ pose_matrix(xp1[list(POSE)])
        for lab in range(3):
            for i in (0, 17, 49):
                assert np.allclose(b1[p, lab, i], b[lab, i] @ m)
            assert np.allclose(eap[p, lab], (w[lab, :, None] * b1[p, lab]).sum(0) / w[lab].sum())
    assert np.array_equal(w1[0], w)


def test_ekf_jacobians_against_finite_differences():
    rng = np.random.default_rng(3)
    ect = ECT()
    x = np.array([[1.0, 6.0, 2.0, 1.0, 0.3, 0.2]])
    b = random_betas(rng, 1)
    out, jb, jx, ju = transition_jacobians(b, x, ect, 0.1)
    assert np.allclose(jb, fd(lambda bb: transition_jacobians(bb, x, ect, 0.1)[0], b), atol=1e-7)
    assert np.allclose(jx, fd(lambda xx: transition_jacobians(b, xx, ect, 0.1)[0], x), atol=1e-6)

    def through_noise(uu):
        x1 = ect.propagate(x, 0.1, u=uu)
        return predict_planes(b, motion_matrix(x[:, POSE], x1[:, POSE]))

    assert np.allclose(ju, fd(through_noise, np.zeros((1, 3))), atol=1e-7)


def test_ekf_covariance_matches_the_sampled_transition():
    """EKF prediction against Monte Carlo of the same model (Gaussian plane, Gaussian vehicle state, ECT noise):
    the covariances agree within 10 % (Frobenius), the means within a tenth of a standard deviation."""
    rng = np.random.default_rng(4)
    ect = ECT(sigma_ax=0.5, sigma_ay=0.5, sigma_alpha=0.05)
    x = np.array([[0.0, 8.0, 0.0, 0.5, 0.05, 0.1]])
    xc = np.diag([0.05, 0.1, 0.05, 0.1, 0.01, 0.01]) ** 2
    b = beta_from_hesse(np.array([[0.6, 0.8, 0.0]]), np.array([12.0]))
    bc = np.diag([0.01, 0.01, 0.0, 0.05]) ** 2
    mean, cov = ekf_predict(b, bc[None], x, xc[None], ect, 0.1)
    n = 40_000
    xs = x + rng.multivariate_normal(np.zeros(6), xc, n)
    bs = b + rng.multivariate_normal(np.zeros(4), bc, n)
    x1 = ect.propagate(xs, 0.1, rng)
    samples = predict_planes(bs, motion_matrix(xs[:, POSE], x1[:, POSE]))
    sc = np.cov(samples.T)
    assert np.linalg.norm(sc - cov[0]) <= 0.1 * np.linalg.norm(sc)
    sd = np.sqrt(np.maximum(np.diag(sc), 1e-30))
    assert np.all(np.abs(samples.mean(0) - mean[0]) <= 0.1 * sd + 1e-12)
