"""Vehicle (motion) models, sampled vectorised over particles.

Every model holds its noise settings and maps particle states (P, d) and one
control row u (k,) held for dt seconds to new states (P, d), drawing its noise
from a ``numpy.random.Generator`` (same seed, same draws). The state dimension
d varies by model (3 for the planar pose models here; 6 for the Extended
Constant Turn model of the planar-feature filters); :meth:`VehicleModel.pose`
gives the planar pose (x, y, theta) (P, 3) in the world frame that the feature
and detection models need.

* :class:`OdometryIncrement` -- pose increments (dx, dy, dtheta) in the previous
  vehicle frame (u = the increment, dt = its duration). Noise std per axis:
  a constant term per second (so a robot that stands still or creeps still
  drifts) plus terms that grow with the motion;
* :class:`Unicycle` -- velocity commands u = (v, omega), exact arc integration;
* :class:`Ackermann` -- encoder speed and steering u = (v, steer) (Victoria
  Park): the speed is moved from the encoder to the rear-axle centre,
  v_c = v / (1 - tan(steer) H / L), and the rear-axle centre moves as a
  bicycle of wheelbase L; an optional steering offset is removed first.
"""

from __future__ import annotations

from abc import ABC, abstractmethod

import numpy as np

from detectors.geometry import compose
from detectors.logs import wrap_angle


class VehicleModel(ABC):
    """The vehicle-model protocol of the RB filter loop."""

    dim: int = 3
    #: columns of a control row
    control_dim: int = 3

    def initial(self, pose: np.ndarray, n: int) -> np.ndarray:
        """(n, dim) states at a planar pose (3,) (at rest)."""
        x = np.zeros((n, self.dim))
        x[:, :3] = np.asarray(pose, dtype=np.float64)[:3]
        return x

    def pose(self, x: np.ndarray) -> np.ndarray:
        """(P, 3) planar poses (x, y, theta) of states (P, dim)."""
        return x[:, :3]

    @abstractmethod
    def step(self, x: np.ndarray, u: np.ndarray, dt: float, rng: np.random.Generator | None) -> np.ndarray:
        """States (P, dim) after control u (control_dim,) held for dt [s]; ``rng=None``: no noise (the mean motion)."""

    def mean(self, x: np.ndarray, u: np.ndarray, dt: float) -> np.ndarray:
        """The noise-free motion (dead reckoning)."""
        return self.step(x, u, dt, None)

    def jacobian(self, x: np.ndarray, u: np.ndarray, dt: float) -> np.ndarray:
        """(P, dim, dim) d(mean motion)/d(state) at states x (P, dim): the EKF form of the model."""
        raise NotImplementedError(f"{type(self).__name__} has no state Jacobian")

    def sample(self, x: np.ndarray, u: np.ndarray, dt: float, rng: np.random.Generator) -> np.ndarray:
        return self.step(x, u, dt, rng)


def _noisy(n: int, values: np.ndarray, sigmas: np.ndarray, rng: np.random.Generator | None) -> np.ndarray:
    """(n, k) copies of a control with independent Gaussian noise of std ``sigmas`` per column."""
    out = np.tile(np.asarray(values, dtype=np.float64), (n, 1))
    if rng is not None:
        out += rng.standard_normal((n, out.shape[1])) * sigmas
    return out


class OdometryIncrement(VehicleModel):
    """Pose increments u = (dx, dy, dtheta) in the previous vehicle frame.

    Standard deviations of the increment actually travelled, per axis:
    along = sqrt(dt) s_x + a_trans |d|, across = sqrt(dt) s_y + lateral |d|,
    heading = sqrt(dt) s_theta + a_rot |dtheta| + a_rot_trans |d|, with
    |d| = hypot(dx, dy). The sqrt(dt) terms are a random walk of variance
    s^2 per second: noise that does not vanish when the robot stands still.
    """

    control_dim = 3

    def __init__(
        self,
        *,
        a_trans: float = 0.05,
        a_rot: float = 0.05,
        a_rot_trans: float = 0.01,
        lateral: float = 0.02,
        s_x: float = 0.0,
        s_y: float = 0.0,
        s_theta: float = 0.0,
    ) -> None:
        self.a_trans, self.a_rot, self.a_rot_trans, self.lateral = a_trans, a_rot, a_rot_trans, lateral
        self.const = np.array([s_x, s_y, s_theta], dtype=np.float64)

    def sigmas(self, u: np.ndarray, dt: float) -> np.ndarray:
        d = float(np.hypot(u[0], u[1]))
        return self.const * np.sqrt(max(dt, 0.0)) + np.array([self.a_trans * d, self.lateral * d, self.a_rot * abs(u[2]) + self.a_rot_trans * d])

    def step(self, x, u, dt, rng):
        u = np.asarray(u, dtype=np.float64)
        inc = _noisy(x.shape[0], u, self.sigmas(u, dt), rng)
        return compose(x, inc)

    def jacobian(self, x, u, dt):
        c, s = np.cos(x[:, 2]), np.sin(x[:, 2])
        f = np.tile(np.eye(3), (x.shape[0], 1, 1))
        f[:, 0, 2] = -s * u[0] - c * u[1]
        f[:, 1, 2] = c * u[0] - s * u[1]
        return f


class Unicycle(VehicleModel):
    """Velocity commands u = (v [m/s], omega [rad/s]) held for dt, Gaussian noise on each."""

    control_dim = 2

    def __init__(self, *, sigma_v: float = 0.05, sigma_omega: float = 0.05) -> None:
        self.sig = np.array([sigma_v, sigma_omega], dtype=np.float64)

    def step(self, x, u, dt, rng):
        vv, ww = _noisy(x.shape[0], u, self.sig, rng).T
        th = x[:, 2]
        small = np.abs(ww) < 1e-9
        w_safe = np.where(small, 1.0, ww)
        dx = np.where(small, vv * dt * np.cos(th), vv / w_safe * (np.sin(th + ww * dt) - np.sin(th)))
        dy = np.where(small, vv * dt * np.sin(th), -vv / w_safe * (np.cos(th + ww * dt) - np.cos(th)))
        return np.column_stack([x[:, 0] + dx, x[:, 1] + dy, wrap_angle(th + ww * dt)])

    def jacobian(self, x, u, dt):
        v, w = float(u[0]), float(u[1])
        th = x[:, 2]
        f = np.tile(np.eye(3), (x.shape[0], 1, 1))
        if abs(w) < 1e-9:
            f[:, 0, 2], f[:, 1, 2] = -v * dt * np.sin(th), v * dt * np.cos(th)
        else:
            f[:, 0, 2] = v / w * (np.cos(th + w * dt) - np.cos(th))
            f[:, 1, 2] = v / w * (np.sin(th + w * dt) - np.sin(th))
        return f


class Ackermann(VehicleModel):
    """Encoder speed and steering u = (v [m/s], steer [rad]) of a car-like vehicle (rear-axle frame)."""

    control_dim = 2

    def __init__(
        self, wheelbase: float, encoder_offset: float = 0.0, *, sigma_speed: float = 0.1, sigma_steer: float = 0.02, steer_offset: float = 0.0
    ) -> None:
        self.L, self.H = float(wheelbase), float(encoder_offset)
        self.sig = np.array([sigma_speed, sigma_steer], dtype=np.float64)
        self.steer_offset = float(steer_offset)

    def step(self, x, u, dt, rng):
        u = np.asarray(u, dtype=np.float64) - np.array([0.0, self.steer_offset])
        v, g = _noisy(x.shape[0], u, self.sig, rng).T
        vc = v / (1.0 - np.tan(g) * self.H / self.L)  # encoder speed -> rear-axle centre
        th = x[:, 2]
        return np.column_stack([x[:, 0] + dt * vc * np.cos(th), x[:, 1] + dt * vc * np.sin(th), wrap_angle(th + dt * vc / self.L * np.tan(g))])

    def jacobian(self, x, u, dt):
        v, g = float(u[0]), float(u[1]) - self.steer_offset
        vc = v / (1.0 - np.tan(g) * self.H / self.L)
        th = x[:, 2]
        f = np.tile(np.eye(3), (x.shape[0], 1, 1))
        f[:, 0, 2], f[:, 1, 2] = -dt * vc * np.sin(th), dt * vc * np.cos(th)
        return f
