"""The plane transition model of Gostar et al. (Sensors 2019): eq. 35 driven by the ECT model, SMC and EKF forms.

A plane in the vehicle frame, ``beta^T r = 0`` with ``beta = (a, b, c, d')``
(eqs. 23-24; ``beta = (n, -d)`` for the Hesse form n . p = d), moves with the
vehicle: with the pose matrix R_k of eq. 28,

    beta_{k+1}^T = beta_k^T M_k^{-1},   M_k^{-1} = R_k^{-1} R_{k+1}      (eq. 35)

where R_{k+1} comes from the vehicle state the ECT model (eq. 36) predicts.

* :func:`motion_matrix` -- M_k^{-1} (..., 4, 4) from two planar poses;
* :func:`predict_planes` -- eq. 35 for planes (..., 4), broadcasting over
  vehicle particles x planes x plane particles;
* :func:`algorithm1` -- the SMC implementation (Algorithm 1): one ECT noise
  sample per vehicle particle, the plane particles of every label moved by that
  particle's M_k^{-1}, weights kept, the EAP estimate per label;
* :func:`transition_jacobians` / :func:`ekf_predict` -- the EKF form for a
  Gaussian plane: d beta_{k+1} / d beta_k = (M_k^{-1})^T, and the derivatives with
  respect to the vehicle state x_k (through R_k and through x_{k+1} = f(x_k)) and
  the ECT noise u, so Sigma_{k+1} = J_b Sigma_b J_b^T + J_x Sigma_x J_x^T + J_u Q J_u^T.

Rao-Blackwellised filters (``slam_runtime.rbphd``) keep their planes in the
world frame, where they do not move; there the same relation with R_k the
identity and R_{k+1} the sensor's pose matrix is the measurement model
(``slam_runtime.plane_features``).
"""

from __future__ import annotations

import numpy as np

from detectors.geometry3d import beta_from_hesse, hesse_from_beta, pose_matrix, pose_matrix_inverse
from slam_runtime.ect import ECT, POSE, noise_gain, transition_matrix


def motion_matrix(pose_k: np.ndarray, pose_k1: np.ndarray) -> np.ndarray:
    """M_k^{-1} = R_k^{-1} R_{k+1} (eq. 35) for planar poses (..., 3) at k and k+1, (..., 4, 4)."""
    return pose_matrix_inverse(pose_k) @ pose_matrix(pose_k1)


def predict_planes(beta: np.ndarray, m: np.ndarray) -> np.ndarray:
    """beta_{k+1}^T = beta_k^T M (eq. 35): planes (..., 4) and matrices broadcasting against them (..., 4, 4).

    For planes (L, N, 4) and one matrix per vehicle particle (P, 4, 4), pass ``m[:, None, None]``.
    Only the three non-trivial columns are formed (the motion is planar, so
    c' = c) -- this is the hot loop of Algorithm 1.
    """
    b = np.asarray(beta, dtype=np.float64)
    m = np.asarray(m, dtype=np.float64)
    out = np.empty(np.broadcast_shapes(b.shape, m.shape[:-1]))
    b0, b1, b2, b3 = b[..., 0], b[..., 1], b[..., 2], b[..., 3]
    out[..., 0] = b0 * m[..., 0, 0] + b1 * m[..., 1, 0]
    out[..., 1] = b0 * m[..., 0, 1] + b1 * m[..., 1, 1]
    out[..., 2] = b2
    out[..., 3] = b0 * m[..., 0, 3] + b1 * m[..., 1, 3] + b2 * m[..., 2, 3] + b3
    return out


def algorithm1(
    ect: ECT,
    x_k: np.ndarray,
    beta: np.ndarray,
    weights: np.ndarray,
    dt: float,
    rng: np.random.Generator,
    *,
    reading: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Algorithm 1 (the SMC implementation of the transition model), vectorised.

    x_k (P, 6) ECT states (P vehicle hypotheses; P = 1 is the paper's case);
    beta (L, N, 4) N weighted particles of each of L planes in the vehicle frame at k
    (or (P, L, N, 4): each vehicle hypothesis its own); weights (L, N) (or (P, L, N)).
    reading: an optional odometry reading (v, omega) that sets the velocity states first.
    Steps: (1) R_k (eq. 28); (2) a noise sample u ~ N(0, Sigma) per vehicle particle;
    (3) x_{k+1} by eq. 36; (4) R_{k+1}; (5) M_k^{-1} = R_k^{-1} R_{k+1}; (6-10) every plane
    particle beta^T M_k^{-1}, weights unchanged; (11) the EAP estimate per plane.
    Returns x_{k+1} (P, 6), beta_{k+1} (P, L, N, 4), weights (P, L, N), EAP (P, L, 4).
    """
    x = np.asarray(x_k, dtype=np.float64)
    if reading is not None:
        x = ect.with_velocity(x, reading, rng)
    u = rng.standard_normal((x.shape[0], 3)) * ect.sig_acc
    x1 = ect.propagate(x, dt, u=u)
    m = motion_matrix(x[:, POSE], x1[:, POSE])  # (P, 4, 4)
    b = np.asarray(beta, dtype=np.float64)
    if b.ndim == 3:
        b = b[None]
    b1 = predict_planes(b, m[:, None, None])
    w = np.broadcast_to(np.asarray(weights, dtype=np.float64), b1.shape[:-1])
    wsum = w.sum(axis=-1, keepdims=True)
    eap = np.einsum("pln,plnk->plk", w / np.where(wsum > 0, wsum, 1.0), b1)
    return x1, b1, np.array(w), eap


# ---------------------------------------------------------------------------- EKF form


def _dpose_matrix(pose: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """dR/dX, dR/dY, dR/dphi of eq. 28 (..., 4, 4)."""
    p = np.asarray(pose, dtype=np.float64)
    z = np.zeros(p.shape[:-1] + (4, 4))
    dx, dy, dp = z.copy(), z.copy(), z.copy()
    dx[..., 0, 3] = 1.0
    dy[..., 1, 3] = 1.0
    c, s = np.cos(p[..., 2]), np.sin(p[..., 2])
    dp[..., 0, 0], dp[..., 0, 1], dp[..., 1, 0], dp[..., 1, 1] = -s, -c, c, -s
    return dx, dy, dp


def transition_jacobians(beta: np.ndarray, x_k: np.ndarray, ect: ECT, dt: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The mean transition of planes beta (P, 4) from ECT states x_k (P, 6) and its Jacobians.

    Returns beta_{k+1} (P, 4) with the noise-free ECT step, J_b (P, 4, 4) = d/d beta_k,
    J_x (P, 4, 6) = d/d x_k (through R_k^{-1} and through x_{k+1} = F_k x_k), and
    J_u (P, 4, 3) = d/d u (the ECT noise, through x_{k+1} = F_k x_k + G u).
    """
    b = np.asarray(beta, dtype=np.float64)
    x = np.asarray(x_k, dtype=np.float64)
    x1 = ect.propagate(x, dt)
    pk, pk1 = x[:, POSE], x1[:, POSE]
    rinv, r1 = pose_matrix_inverse(pk), pose_matrix(pk1)
    m = rinv @ r1
    out = np.einsum("pi,pij->pj", b, m)
    jb = np.swapaxes(m, -1, -2)
    # through R_{k+1}: d beta'/d pose_{k+1} (P, 4, 3)
    d1 = _dpose_matrix(pk1)
    dbeta_dp1 = np.stack([np.einsum("pi,pij->pj", b, rinv @ d) for d in d1], axis=-1)
    # through R_k^{-1}: d(R^-1) = -R^-1 dR R^-1
    d0 = _dpose_matrix(pk)
    dbeta_dp0 = np.stack([np.einsum("pi,pij->pj", b, -(rinv @ d @ rinv) @ r1) for d in d0], axis=-1)
    f = ect.free_jacobian(x, dt)  # (P, 6, 6)
    jx = dbeta_dp1 @ f[:, POSE, :]
    jx[:, :, POSE] += dbeta_dp0
    ju = dbeta_dp1 @ noise_gain(dt)[POSE, :]
    return out, jb, jx, ju


def ekf_predict(
    beta: np.ndarray, beta_cov: np.ndarray, x_k: np.ndarray, x_cov: np.ndarray, ect: ECT, dt: float
) -> tuple[np.ndarray, np.ndarray]:
    """EKF prediction of Gaussian planes (P, 4) with covariances (P, 4, 4) through eq. 35 and the ECT model,
    given the vehicle state x_k (P, 6) and its covariance (P, 6, 6) (taken independent of the plane)."""
    out, jb, jx, ju = transition_jacobians(beta, x_k, ect, dt)
    q = np.diag(ect.sig_acc**2)
    cov = jb @ beta_cov @ np.swapaxes(jb, -1, -2) + jx @ x_cov @ np.swapaxes(jx, -1, -2) + ju @ q @ np.swapaxes(ju, -1, -2)
    return out, 0.5 * (cov + np.swapaxes(cov, -1, -2))


def hesse(beta: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(n, d) of planes beta (eq. 24), the normal at unit length."""
    return hesse_from_beta(beta)


def beta(n: np.ndarray, d: np.ndarray) -> np.ndarray:
    """beta (eq. 24) of planes n . p = d."""
    return beta_from_hesse(n, d)


__all__ = ["algorithm1", "beta", "ekf_predict", "hesse", "motion_matrix", "predict_planes", "transition_jacobians", "transition_matrix"]
