"""Vehicle motion models, sampled vectorised over particles.

Every model maps particle poses (P, 3) (x, y, theta, world frame) and one
control to new poses (P, 3), drawing its noise from a ``numpy.random.Generator``
(same seed, same draws). ``noise=False`` gives the noise-free prediction.

* :func:`odometry_increment` -- pose increments (dx, dy, dtheta) in the
  previous vehicle frame; noise grows with the motion (translation std
  ``a_trans * |d|``, rotation std ``a_rot * |dtheta| + a_rot_trans * |d|``);
* :func:`unicycle` -- velocity commands (v, omega) held for dt (UTIAS), exact
  arc integration, Gaussian noise on v and omega;
* :func:`ackermann` -- encoder speed and steering (Victoria Park): the speed is
  moved from the encoder to the rear-axle centre, v_c = v / (1 - tan(steer) H / L),
  and the rear-axle centre moves as a bicycle with wheelbase L.
"""

from __future__ import annotations

import numpy as np


def _wrap(a: np.ndarray) -> np.ndarray:
    return np.mod(a + np.pi, 2 * np.pi) - np.pi


def compose_increments(poses: np.ndarray, inc: np.ndarray) -> np.ndarray:
    """poses (P, 3) (+) increments (P, 3) expressed in each pose's frame."""
    c, s = np.cos(poses[:, 2]), np.sin(poses[:, 2])
    return np.column_stack(
        [poses[:, 0] + c * inc[:, 0] - s * inc[:, 1], poses[:, 1] + s * inc[:, 0] + c * inc[:, 1], _wrap(poses[:, 2] + inc[:, 2])]
    )


def odometry_increment(
    poses: np.ndarray,
    inc: np.ndarray,
    rng: np.random.Generator | None = None,
    *,
    a_trans: float = 0.05,
    a_rot: float = 0.05,
    a_rot_trans: float = 0.01,
    lateral: float = 0.02,
    noise: bool = True,
) -> np.ndarray:
    """Propagate (P, 3) poses by the increment (3,) with motion-proportional noise."""
    p = np.atleast_2d(np.asarray(poses, dtype=np.float64))
    n = p.shape[0]
    d = float(np.hypot(inc[0], inc[1]))
    u = np.broadcast_to(np.asarray(inc, dtype=np.float64), (n, 3)).copy()
    if noise:
        if rng is None:
            raise ValueError("noise=True needs a numpy.random.Generator")
        z = rng.standard_normal((n, 3))
        u[:, 0] += a_trans * d * z[:, 0]
        u[:, 1] += lateral * d * z[:, 1]
        u[:, 2] += (a_rot * abs(inc[2]) + a_rot_trans * d) * z[:, 2]
    return compose_increments(p, u)


def unicycle(
    poses: np.ndarray,
    v: float,
    omega: float,
    dt: float,
    rng: np.random.Generator | None = None,
    *,
    sigma_v: float = 0.05,
    sigma_omega: float = 0.05,
    noise: bool = True,
) -> np.ndarray:
    """Propagate (P, 3) poses along the arc of (v, omega) held for dt seconds."""
    p = np.atleast_2d(np.asarray(poses, dtype=np.float64))
    n = p.shape[0]
    vv = np.full(n, float(v))
    ww = np.full(n, float(omega))
    if noise:
        if rng is None:
            raise ValueError("noise=True needs a numpy.random.Generator")
        z = rng.standard_normal((n, 2))
        vv += sigma_v * z[:, 0]
        ww += sigma_omega * z[:, 1]
    th = p[:, 2]
    small = np.abs(ww) < 1e-9
    w_safe = np.where(small, 1.0, ww)
    dx = np.where(small, vv * dt * np.cos(th), vv / w_safe * (np.sin(th + ww * dt) - np.sin(th)))
    dy = np.where(small, vv * dt * np.sin(th), -vv / w_safe * (np.cos(th + ww * dt) - np.cos(th)))
    return np.column_stack([p[:, 0] + dx, p[:, 1] + dy, _wrap(th + ww * dt)])


def ackermann(
    poses: np.ndarray,
    speed: float,
    steer: float,
    dt: float,
    wheelbase: float,
    encoder_offset: float,
    rng: np.random.Generator | None = None,
    *,
    sigma_speed: float = 0.1,
    sigma_steer: float = 0.02,
    noise: bool = True,
) -> np.ndarray:
    """Propagate (P, 3) rear-axle poses with encoder speed and front-wheel steering (Victoria Park)."""
    p = np.atleast_2d(np.asarray(poses, dtype=np.float64))
    n = p.shape[0]
    v = np.full(n, float(speed))
    g = np.full(n, float(steer))
    if noise:
        if rng is None:
            raise ValueError("noise=True needs a numpy.random.Generator")
        z = rng.standard_normal((n, 2))
        v += sigma_speed * z[:, 0]
        g += sigma_steer * z[:, 1]
    vc = v / (1.0 - np.tan(g) * encoder_offset / wheelbase)  # encoder speed -> rear-axle centre
    th = p[:, 2]
    return np.column_stack(
        [p[:, 0] + dt * vc * np.cos(th), p[:, 1] + dt * vc * np.sin(th), _wrap(th + dt * vc / wheelbase * np.tan(g))]
    )
