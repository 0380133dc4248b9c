"""The Extended Constant Turn vehicle model (Gostar et al., Sensors 2019, eq. 36), sampled over particles.

State (P, 6): ``x = (X, Xdot, Y, Ydot, phi, phidot)`` -- position [m] and velocity
[m/s] in the world frame, heading [rad] and yaw rate [rad/s]. Over a period T,

    x_{k+1} = F_k x_k + G u,   u = (u_X, u_Y, u_phi) ~ N(0, diag(sigma_ax^2, sigma_ay^2, sigma_alpha^2)),

    F_k = [[1, s/w,      0, (c-1)/w, 0, 0],
           [0, c,        0, -s,      0, 0],
           [0, (1-c)/w,  1, s/w,     0, 0],
           [0, s,        0, c,       0, 0],
           [0, 0,        0, 0,       1, T],
           [0, 0,        0, 0,       0, 1]],   s = sin(w T), c = cos(w T), w = phidot_k,

    G = [[T^2/2, 0, 0], [T, 0, 0], [0, T^2/2, 0], [0, T, 0], [0, 0, T^2/2], [0, 0, T]]

(the trigonometric arguments are the yaw *rate* times T and the divisions are
by the yaw rate, as the web version of the paper prints them; the limits at
w -> 0 are used for |w| < 1e-9). The position moves on the arc of constant
speed and turn rate; the velocity vector turns with it.

Driven by odometry (speed v and yaw rate omega, kind ``velocity``), each
particle's velocity states are set from its own noisy sample of the reading
before the step -- ``Xdot = v cos phi``, ``Ydot = v sin phi``, ``phidot = omega``
-- and ``G u`` adds the model's acceleration noise. Without a reading
(:meth:`ECT.propagate`), the model predicts from its own velocity states, as
the paper's Algorithm 1 does.
"""

from __future__ import annotations

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from detectors.sensor_log import wrap_angle
from slam_runtime.vehicle import VEHICLE_MODELS, VehicleModel

#: columns of the planar pose (X, Y, phi) in the state
POSE = (0, 2, 4)


def transition_matrix(w: np.ndarray, t: float) -> np.ndarray:
    """F_k of eq. 36, (P, 6, 6), for yaw rates w (P,) over a period t [s]."""
    w = np.asarray(w, dtype=np.float64)
    small = np.abs(w) < 1e-9
    ws = np.where(small, 1.0, w)
    s, c = np.sin(w * t), np.cos(w * t)
    sw = np.where(small, t, s / ws)
    cw = np.where(small, 0.0, (c - 1.0) / ws)  # (cos - 1) / w
    f = np.zeros(w.shape + (6, 6))
    f[..., 0, 0] = 1.0
    f[..., 0, 1] = sw
    f[..., 0, 3] = cw
    f[..., 1, 1] = c
    f[..., 1, 3] = -s
    f[..., 2, 1] = -cw
    f[..., 2, 2] = 1.0
    f[..., 2, 3] = sw
    f[..., 3, 1] = s
    f[..., 3, 3] = c
    f[..., 4, 4] = 1.0
    f[..., 4, 5] = t
    f[..., 5, 5] = 1.0
    return f


def transition_matrix_dw(w: np.ndarray, t: float) -> np.ndarray:
    """dF_k / dw (P, 6, 6): the derivative of eq. 36's F_k with respect to the yaw rate (series at w -> 0)."""
    w = np.asarray(w, dtype=np.float64)
    small = np.abs(w) < 1e-6
    ws = np.where(small, 1.0, w)
    s, c = np.sin(w * t), np.cos(w * t)
    # d(s/w)/dw = (t c w - s) / w^2 -> -w t^3 / 3 ; d((c-1)/w)/dw = (-t s w - (c - 1)) / w^2 -> -t^2 / 2
    dsw = np.where(small, -w * t**3 / 3.0, (t * c * ws - s) / ws**2)
    dcw = np.where(small, -(t**2) / 2.0 + w**2 * t**4 / 8.0, (-t * s * ws - (c - 1.0)) / ws**2)
    d = np.zeros(w.shape + (6, 6))
    d[..., 0, 1] = dsw
    d[..., 0, 3] = dcw
    d[..., 1, 1] = -t * s
    d[..., 1, 3] = -t * c
    d[..., 2, 1] = -dcw
    d[..., 2, 3] = dsw
    d[..., 3, 1] = t * c
    d[..., 3, 3] = -t * s
    return d


def noise_gain(t: float) -> np.ndarray:
    """G of eq. 36 (6, 3)."""
    g = np.zeros((6, 3))
    g[0, 0] = g[2, 1] = g[4, 2] = t * t / 2
    g[1, 0] = g[3, 1] = g[5, 2] = t
    return g


class ECTNoise(BaseModel):
    """Extended Constant Turn model (eq. 36 of Gostar et al.) driven by speed and yaw-rate odometry."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)
    sigma_v: float = Field(default=0.15, ge=0.0, description="speed reading [m/s]")
    sigma_omega: float = Field(default=0.03, ge=0.0, description="yaw-rate reading [rad/s]")
    sigma_ax: float = Field(default=0.05, ge=0.0, description="model acceleration noise along X [m/s^2]")
    sigma_ay: float = Field(default=0.05, ge=0.0, description="model acceleration noise along Y [m/s^2]")
    sigma_alpha: float = Field(default=0.005, ge=0.0, description="model yaw acceleration noise [rad/s^2]")


class ECT(VehicleModel):
    """Extended Constant Turn model (eq. 36) driven by speed and yaw-rate odometry u = (v [m/s], omega [rad/s]).

    sigma_v, sigma_omega: noise of the odometry readings (each particle draws its own);
    sigma_ax, sigma_ay [m/s^2], sigma_alpha [rad/s^2]: the model's acceleration noise u of eq. 36.
    """

    dim = 6
    control_dim = 2
    label = "ECT"
    odometry = ("velocity",)
    takes = "speed and yaw-rate odometry"
    features = ("planes",)
    Noise = ECTNoise

    def __init__(
        self, *, sigma_v: float = 0.15, sigma_omega: float = 0.03, sigma_ax: float = 0.05, sigma_ay: float = 0.05, sigma_alpha: float = 0.005
    ) -> None:
        self.sig_u = np.array([sigma_v, sigma_omega], dtype=np.float64)
        self.sig_acc = np.array([sigma_ax, sigma_ay, sigma_alpha], dtype=np.float64)

    def initial(self, pose: np.ndarray, n: int) -> np.ndarray:
        x = np.zeros((n, 6))
        p = np.asarray(pose, dtype=np.float64)
        x[:, 0], x[:, 2], x[:, 4] = p[0], p[1], p[2]
        return x

    def pose(self, x: np.ndarray) -> np.ndarray:
        return x[..., POSE]

    def control_sigmas(self, u: np.ndarray, dt: float) -> np.ndarray:
        """(2,) noise of a (speed, yaw-rate) reading."""
        return self.sig_u

    def with_velocity(self, x: np.ndarray, u: np.ndarray, rng: np.random.Generator | None) -> np.ndarray:
        """States whose velocity states are set from a (noisy, per particle) speed and yaw-rate reading."""
        x = np.array(x, dtype=np.float64)
        v = np.full(x.shape[0], float(u[0]))
        w = np.full(x.shape[0], float(u[1]))
        if rng is not None:
            e = rng.standard_normal((x.shape[0], 2)) * self.sig_u
            v, w = v + e[:, 0], w + e[:, 1]
        x[:, 1] = v * np.cos(x[:, 4])
        x[:, 3] = v * np.sin(x[:, 4])
        x[:, 5] = w
        return x

    def propagate(self, x: np.ndarray, dt: float, rng: np.random.Generator | None = None, u: np.ndarray | None = None) -> np.ndarray:
        """Eq. 36: F_k x + G u for states (P, 6); ``u`` (P, 3) given noise, else drawn from ``rng``, else none."""
        f = transition_matrix(x[:, 5], dt)
        out = np.einsum("pij,pj->pi", f, x)
        if u is None and rng is not None:
            u = rng.standard_normal((x.shape[0], 3)) * self.sig_acc
        if u is not None:
            out += np.asarray(u) @ noise_gain(dt).T
        out[:, 4] = wrap_angle(out[:, 4])
        return out

    def step(self, x, u, dt, rng):
        return self.propagate(self.with_velocity(x, u, rng), dt, rng)

    def jacobian(self, x, u, dt):
        """d(mean motion)/d(state) (P, 6, 6) with the velocity states set from the reading u: the new state
        depends on the old one through X, Y and phi (the velocity direction follows phi)."""
        xv = self.with_velocity(x, u, None)
        f = transition_matrix(xv[:, 5], dt)
        jv = np.tile(np.eye(6), (x.shape[0], 1, 1))
        jv[:, 1, 1] = jv[:, 3, 3] = jv[:, 5, 5] = 0.0
        jv[:, 1, 4] = -float(u[0]) * np.sin(x[:, 4])
        jv[:, 3, 4] = float(u[0]) * np.cos(x[:, 4])
        return f @ jv

    def free_jacobian(self, x: np.ndarray, dt: float) -> np.ndarray:
        """d(F_k x)/dx (P, 6, 6) of the free model (no reading): F_k plus the yaw rate's effect through F_k itself."""
        f = transition_matrix(x[:, 5], dt)
        df = transition_matrix_dw(x[:, 5], dt)
        f[:, :, 5] += np.einsum("pij,pj->pi", df, x)
        return f


VEHICLE_MODELS.add("ect", ECT)
