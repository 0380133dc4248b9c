"""The constant-velocity (CV) transition of moving point features, and their range-bearing measurement.

Li & Yang (Sensors 2022, sec. 4) let the feature points of their two-stage scenario move "in uniform
linear motion in the two-dimensional plane" with process noise Q_k = 0.5^2 B B^T and T = 1 s: the
constant-velocity model of the labelled-RFS toolbox their parameters come from (Vo & Vo's Gaussian-mixture
GLMB/LMB demonstration model: the same T, F, B, H = [1 0 0 0; 0 0 1 0], P_D = 0.98 and clutter region
[-1000, 1000]^2 m, with sigma_v = 5 there). A moving point's state is

    m = (x, y, vx, vy)   world frame [m, m, m/s, m/s]

(positions first, so that a feature's position is m[..., :2] as for a static point; the paper and the toolbox
order it (x, vx, y, vy)), and it moves as

    m_{k+1} = F m_k + B v_k,   v_k ~ N(0, sigma^2 I_2)  (a white acceleration [m/s^2] held over the step)
    F = [[I, T I], [0, I]],   B = [[T^2 / 2 I], [T I]],   Q = sigma^2 B B^T        (paper sec. 4, Q_k = 0.5^2 B B^T)

The model is linear, so its Jacobians are constant: d m_{k+1} / d m_k = F and d m_{k+1} / d v_k = B
(:func:`jacobians`, checked against finite differences of :func:`transition` in the tests); the Gaussian
prediction is mu' = F mu, P' = F P F^T + Q (:func:`predict`).

:class:`MovingPoint` is the feature model of such a point for a range-bearing sensor: the predicted
measurement is the position's (:class:`slam_runtime.features.RangeBearing`), so H has zero columns for the
velocity; a feature born from a measurement takes its position by the inverse model and a velocity of mean 0
and standard deviation ``birth_speed`` per axis (:attr:`MovingPoint.birth_cov`: the velocity block a filter's
birth covariance needs, which G R G^T of the position alone cannot give).
"""

from __future__ import annotations

import numpy as np

from slam_runtime.features import RangeBearing

#: state dimension of a moving point, and of its position part
DIM, POS = 4, 2


def transition_matrix(dt: float) -> np.ndarray:
    """F (4, 4) of a step of dt [s]."""
    f = np.eye(DIM)
    f[0, 2] = f[1, 3] = dt
    return f


def noise_gain(dt: float) -> np.ndarray:
    """B (4, 2): how an acceleration held over dt [s] moves the state."""
    b = np.zeros((DIM, POS))
    b[0, 0] = b[1, 1] = 0.5 * dt * dt
    b[2, 0] = b[3, 1] = dt
    return b


def process_noise(dt: float, sigma: float) -> np.ndarray:
    """Q = sigma^2 B B^T (4, 4), sigma the acceleration noise [m/s^2] (paper sec. 4: 0.5)."""
    b = noise_gain(dt)
    return sigma * sigma * (b @ b.T)


def transition(m: np.ndarray, v: np.ndarray, dt: float) -> np.ndarray:
    """f(m, v) = F m + B v for states m (..., 4) and accelerations v (..., 2)."""
    m = np.asarray(m, dtype=np.float64)
    v = np.asarray(v, dtype=np.float64)
    out = m.copy()
    out[..., :POS] += dt * m[..., POS:] + 0.5 * dt * dt * v
    out[..., POS:] += dt * v
    return out


def jacobians(m: np.ndarray, dt: float) -> tuple[np.ndarray, np.ndarray]:
    """(d f / d m (..., 4, 4), d f / d v (..., 4, 2)) at states m (..., 4): F and B for every state."""
    shape = np.shape(m)[:-1]
    return np.broadcast_to(transition_matrix(dt), shape + (DIM, DIM)), np.broadcast_to(noise_gain(dt), shape + (DIM, POS))


def predict(mu: np.ndarray, cov: np.ndarray, dt: float, sigma: float) -> tuple[np.ndarray, np.ndarray]:
    """The Gaussian prediction of states mu (..., 4), cov (..., 4, 4) over dt [s]: F mu and F P F^T + Q."""
    f = transition_matrix(dt)
    mu1 = np.asarray(mu, dtype=np.float64) @ f.T
    cov1 = f @ np.asarray(cov, dtype=np.float64) @ f.T + process_noise(dt, sigma)
    return mu1, 0.5 * (cov1 + np.swapaxes(cov1, -1, -2))


def sample(m: np.ndarray, dt: float, sigma: float, rng: np.random.Generator) -> np.ndarray:
    """One draw of m_{k+1} for states m (..., 4): the transition with an acceleration drawn from N(0, sigma^2 I)."""
    m = np.asarray(m, dtype=np.float64)
    return transition(m, rng.standard_normal(m.shape[:-1] + (POS,)) * sigma, dt)


class MovingPoint(RangeBearing):
    """A moving point (x, y, vx, vy) [m, m/s, world frame] measured as (range [m], bearing [rad]) in the sensor frame.

    r (2, 2): the measurement noise; mount (3,): the sensor on the vehicle; birth_speed [m/s]: the standard
    deviation per axis of a newborn feature's velocity (its mean is 0)."""

    dim_x = DIM

    def __init__(self, r: np.ndarray, mount: np.ndarray | None = None, birth_speed: float = 1.0) -> None:
        super().__init__(r, mount)
        if not birth_speed > 0:
            raise ValueError(f"birth_speed must be above 0, not {birth_speed}")
        self.birth_speed = float(birth_speed)

    @property
    def birth_cov(self) -> np.ndarray:
        """(4, 4) what a birth's covariance adds to G R G^T: the velocity's prior, birth_speed^2 per axis."""
        c = np.zeros((DIM, DIM))
        c[2, 2] = c[3, 3] = self.birth_speed**2
        return c

    def predict_sensor(self, sensor, x):
        zhat, h2 = super().predict_sensor(sensor, x[..., :POS])
        h = np.zeros(h2.shape[:-1] + (DIM,))
        h[..., :POS] = h2
        return zhat, h

    def pose_jacobian(self, poses, x):
        return super().pose_jacobian(poses, np.asarray(x)[..., :POS])

    def inverse_sensor(self, sensor, z):
        pos, g2 = super().inverse_sensor(sensor, z)
        x = np.zeros(pos.shape[:-1] + (DIM,))
        x[..., :POS] = pos
        g = np.zeros(g2.shape[:-2] + (DIM, g2.shape[-1]))
        g[..., :POS, :] = g2
        return x, g

    def position(self, x: np.ndarray) -> np.ndarray:
        return np.asarray(x)[..., :POS]


class ConstantVelocity:
    """The transition a map filter predicts its moving points with: acceleration noise ``sigma`` [m/s^2]."""

    def __init__(self, sigma: float) -> None:
        if not sigma >= 0:
            raise ValueError(f"sigma must be 0 or more, not {sigma}")
        self.sigma = float(sigma)

    def predict(self, mu: np.ndarray, cov: np.ndarray, dt: float) -> tuple[np.ndarray, np.ndarray]:
        """States mu (..., 4), cov (..., 4, 4) moved over dt [s] (:func:`predict`)."""
        return predict(mu, cov, max(float(dt), 0.0), self.sigma)


class PositionView:
    """A detection model as a filter of moving points sees it: P_D and the buffer zone from the position part of
    each state (x, y) and its covariance block; everything else is the model's own."""

    def __init__(self, detection) -> None:
        self.model = detection

    def pd_features(self, sensor_poses, mu, cov, meas, weights=None):
        return self.model.pd_features(sensor_poses, np.asarray(mu)[..., :POS], np.asarray(cov)[..., :POS, :POS], meas, weights)

    def __getattr__(self, name: str):
        return getattr(self.model, name)
