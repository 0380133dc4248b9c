"""The Extended Constant Turn model (eq. 36): closed forms, limits, Jacobians against finite differences, noise."""

from __future__ import annotations

import numpy as np
import pytest

from slam_runtime.ect import ECT, noise_gain, transition_matrix, transition_matrix_dw
from slam_runtime.vehicle import Unicycle
from tests.detectors.test_geometry3d import fd


def test_transition_matrix_matches_the_paper_and_its_limit():
    w, t = 0.4, 0.1
    f = transition_matrix(np.array([w]), t)[0]
    s, c = np.sin(w * t), np.cos(w * t)
    expect = np.array(
        [[1, s / w, 0, (c - 1) / w, 0, 0], [0, c, 0, -s, 0, 0], [0, (1 - c) / w, 1, s / w, 0, 0], [0, s, 0, c, 0, 0], [0, 0, 0, 0, 1, t], [0, 0, 0, 0, 0, 1]]
    )
    assert np.allclose(f, expect, atol=1e-15)
    # w -> 0 is continuous: the constant-velocity model
    assert np.allclose(transition_matrix(np.array([0.0]), t), transition_matrix(np.array([1e-7]), t), atol=1e-8)
    g = noise_gain(t)
    assert np.allclose(g[:, 0], [t * t / 2, t, 0, 0, 0, 0]) and np.allclose(g[:, 2], [0, 0, 0, 0, t * t / 2, t])


def test_step_with_a_reading_is_the_exact_arc():
    """Velocity states set from (v, omega), then F_k: the position moves on the arc of constant speed and turn
    rate, which is what the unicycle model integrates."""
    ect, uni = ECT(), Unicycle()
    x = ect.initial(np.array([2.0, -1.0, 0.7]), 3)
    for u in (np.array([7.0, 0.3]), np.array([5.0, -0.05]), np.array([3.0, 0.0])):
        got = ect.pose(ect.mean(x, u, 0.1))
        assert np.allclose(got, uni.mean(ect.pose(x), u, 0.1), atol=1e-12)


def test_jacobians_against_finite_differences():
    ect = ECT()
    x = np.array([[1.0, 3.0, 2.0, 1.0, 0.3, 0.2], [0.0, 5.0, 0.0, -0.5, 1.0, -0.4]])
    assert np.allclose(ect.free_jacobian(x, 0.1), fd(lambda xx: ect.propagate(xx, 0.1), x), atol=1e-7)
    u = np.array([7.0, 0.1])
    assert np.allclose(ect.jacobian(x, u, 0.1), fd(lambda xx: ect.mean(xx, u, 0.1), x), atol=1e-7)
    w = np.array([0.3, -0.8])
    assert np.allclose(transition_matrix_dw(w, 0.1), fd(lambda ww: transition_matrix(ww[..., 0], 0.1), w[:, None])[..., 0], atol=1e-6)
    # at w -> 0 (where differences of (cos - 1) / w cancel) the series: d(s/w)/dw -> 0, d((c-1)/w)/dw -> -t^2/2
    d0 = transition_matrix_dw(np.array([1e-9]), 0.1)[0]
    assert np.isclose(d0[0, 1], 0.0, atol=1e-12) and np.isclose(d0[0, 3], -0.005) and np.isclose(d0[3, 1], 0.1)


def test_sampled_noise_matches_its_linearisation():
    """20,000 draws of one step: the sample covariance of (X, Y, phi) matches the linearised one,
    dx/d(v, omega) R dx/d(v, omega)^T + G_pose Q G_pose^T, within 5 % (sampling error about 1 %)."""
    ect = ECT(sigma_v=0.3, sigma_omega=0.05, sigma_ax=0.2, sigma_ay=0.2, sigma_alpha=0.02)
    n, dt = 20_000, 0.1
    x0 = ect.initial(np.array([0.0, 0.0, 0.4]), n)
    u = np.array([6.0, 0.2])
    draws = ect.pose(ect.step(x0, u, dt, np.random.default_rng(3)))
    x1 = ect.initial(np.array([0.0, 0.0, 0.4]), 1)
    ju = fd(lambda uu: ect.pose(ect.mean(np.repeat(x1, len(uu), 0), uu[0], dt)), u[None])[0]
    g = noise_gain(dt)[[0, 2, 4]]
    cov = ju @ np.diag(ect.sig_u**2) @ ju.T + g @ np.diag(ect.sig_acc**2) @ g.T
    sample = np.cov(draws.T)
    assert np.allclose(sample, cov, rtol=0.05, atol=1e-10)


def test_protocol_columns():
    ect = ECT()
    x = ect.initial(np.array([1.0, 2.0, 3.0]), 4)
    assert x.shape == (4, 6) and np.allclose(ect.pose(x), [1.0, 2.0, 3.0])
    with pytest.raises(IndexError):
        ect.pose(np.zeros((2, 3)))
