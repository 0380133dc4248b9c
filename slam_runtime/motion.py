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

from detectors.geometry import compose
from detectors.logs import wrap_angle


def _noisy(n: int, values: tuple[float, ...], sigmas: tuple[float, ...], rng: np.random.Generator | None, noise: bool) -> np.ndarray:
    """(n, k) copies of a control with independent Gaussian noise of the given std per column."""
    out = np.tile(np.asarray(values, dtype=np.float64), (n, 1))
    if noise:
        if rng is None:
            raise ValueError("noise=True needs a numpy.random.Generator")
        out += rng.standard_normal((n, len(values))) * np.asarray(sigmas, dtype=np.float64)
    return out


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
    d = float(np.hypot(inc[0], inc[1]))
    u = _noisy(p.shape[0], tuple(inc), (a_trans * d, lateral * d, a_rot * abs(inc[2]) + a_rot_trans * d), rng, noise)
    return compose(p, u)


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
    vv, ww = _noisy(p.shape[0], (v, omega), (sigma_v, sigma_omega), rng, noise).T
    th = p[:, 2]
    small = np.abs(ww) < 1e-9
    w_safe = np.where(small, 1.0, ww)
    dx = np.where(small, vv * dt * np.cos(th), vv / w_safe * (np.sin(th + ww * dt) - np.sin(th)))
    dy = np.where(small, vv * dt * np.sin(th), -vv / w_safe * (np.cos(th + ww * dt) - np.cos(th)))
    return np.column_stack([p[:, 0] + dx, p[:, 1] + dy, wrap_angle(th + ww * dt)])


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
    v, g = _noisy(p.shape[0], (speed, steer), (sigma_speed, sigma_steer), rng, noise).T
    vc = v / (1.0 - np.tan(g) * encoder_offset / wheelbase)  # encoder speed -> rear-axle centre
    th = p[:, 2]
    return np.column_stack(
        [p[:, 0] + dt * vc * np.cos(th), p[:, 1] + dt * vc * np.sin(th), wrap_angle(th + dt * vc / wheelbase * np.tan(g))]
    )
