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
* :class:`Unicycle` -- velocity commands u = (v, omega), exact arc integration
  (an optional speed scale and turn-rate offset applied first);
* :class:`Ackermann` -- encoder speed and steering u = (v, steer) (Victoria
  Park): the speed is moved from the encoder to the rear-axle centre,
  v_c = v / (1 - tan(steer) H / L), and the rear-axle centre moves as a
  bicycle of wheelbase L; an optional steering offset is removed and a speed
  scale applied first (:func:`fit_ackermann_bias` measures both against a
  trajectory).

Every model is found through :data:`VEHICLE_MODELS` under the name of its noise
settings' group (``motion.increment``, ``motion.velocity``, ...): its class
declares the odometry kinds that drive it, the feature kinds it is the model
of by default, and its noise settings (``Noise``), which become that group of
the SLAM settings. A new model is a module with a :class:`VehicleModel`
subclass and one registration line.
"""

from __future__ import annotations

from abc import ABC, abstractmethod

import numba
import numpy as np
from pydantic import BaseModel, ConfigDict, Field, model_validator

from detectors.geometry import compose
from detectors.sensor_log import wrap_angle
from profiles.errors import DataError
from profiles.registry import Registry


class VehicleModel(ABC):
    """The vehicle-model protocol of the RB filter loop."""

    dim: int = 3
    #: columns of a control row
    control_dim: int = 3
    #: the model's name in messages
    label: str = "vehicle"
    #: the odometry kinds (``Odometry.kind``) that drive it, and what they are in words (messages)
    odometry: tuple[str, ...] = ()
    takes: str = ""
    #: the feature kinds whose filters it drives when the settings leave the choice to the odometry (``motion.model: auto``)
    features: tuple[str, ...] = ("points", "planes")
    #: its noise settings: a pydantic model refusing unknown keys, the group of ``motion`` it is registered under
    Noise: type[BaseModel]
    #: the settings of its group a self-calibration measures against a trajectory (:meth:`fit_biases`), with their
    #: labels, and how little their change must be for the iteration to have settled
    biases: dict[str, str] = {}
    settled: dict[str, float] = {}
    #: True when each state carries a Gaussian of a bias (its mean and variance after the planar pose) that the
    #: optimal proposal updates with the pose (:meth:`predict_joint`, :meth:`condition`); the state is then the pose
    #: and those two columns
    adaptive: bool = False
    #: how late the motion follows the odometry rows [s] (a command acts this long after its stamp): the run hands
    #: each frame interval the rows that act in it (:func:`slam_runtime.sources.delayed`)
    delay: float = 0.0

    @property
    def planar(self) -> bool:
        """The state is a planar pose (with an adaptive model's bias beside it): what the optimal proposal and the
        islands' mean path take."""
        return self.dim == 3 or self.adaptive

    def predict_joint(self, x: np.ndarray, controls: np.ndarray, dts: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Adaptive models: the mean motion (P, dim), the pose's covariance (P, 3, 3) with the bias's uncertainty in
        it, and the pose's covariance with the bias (P, 3), through control rows (R, k) held for dts (R,)."""
        raise NotImplementedError(f"{type(self).__name__} estimates no bias during a run")

    def condition(self, xbar: np.ndarray, q: np.ndarray, cross: np.ndarray, pose: np.ndarray) -> np.ndarray:
        """Adaptive models: the states (P, dim) at the drawn poses (P, 3), each bias conditioned on its pose under the
        joint Gaussian of :meth:`predict_joint` (the measurements depend on the bias only through the pose)."""
        raise NotImplementedError(f"{type(self).__name__} estimates no bias during a run")

    def fit_biases(self, controls: list[tuple[np.ndarray, np.ndarray]], trajectory: np.ndarray) -> dict:
        """The :attr:`biases` measured against a trajectory (T, 3), given each frame's control rows and durations."""
        raise NotImplementedError(f"{type(self).__name__} has no biases to measure")

    @classmethod
    def from_settings(cls, noise: BaseModel, vehicle=None) -> VehicleModel:
        """The model with its noise settings; ``vehicle``: the log's vehicle geometry (models that need it)."""
        return cls(**noise.model_dump())

    def initial(self, pose: np.ndarray, n: int) -> np.ndarray:
        """(n, dim) states at a planar pose (3,) (at rest)."""
        x = np.zeros((n, self.dim))
        x[:, :3] = np.asarray(pose, dtype=np.float64)[:3]
        return x

    def pose(self, x: np.ndarray) -> np.ndarray:
        """(P, 3) planar poses (x, y, theta) of states (P, dim)."""
        return x[:, :3]

    def placed(self, x: np.ndarray, pose: np.ndarray) -> np.ndarray:
        """States (P, dim) with their planar pose set to ``pose`` (3,) and the other states (velocities) kept:
        mapping with the path given (``poses: ground_truth``)."""
        out = np.array(x, dtype=np.float64)
        out[:, :3] = np.asarray(pose, dtype=np.float64)[:3]
        return out

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

    def control_sigmas(self, u: np.ndarray, dt: float) -> np.ndarray:
        """(control_dim,) standard deviations of the noise on control u."""
        raise NotImplementedError(f"{type(self).__name__} has no control noise model")

    def predict_gaussian(self, x: np.ndarray, controls: np.ndarray, dts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The mean motion (P, dim) through control rows (R, k) held for dts (R,), and its covariance
        (P, dim, dim) from the control noise linearised row by row: C <- F C F^T + G S G^T, with F
        the state Jacobian, G = d(motion)/d(control) (central differences) and S the control noise.
        The Gaussian a pose proposal starts from."""
        p, d = x.shape
        cov = np.zeros((p, d, d))
        for u, dt in zip(controls, dts, strict=True):
            u = np.asarray(u, dtype=np.float64)
            dt = float(dt)
            f = self.jacobian(x, u, dt)
            sig = self.control_sigmas(u, dt)
            g = np.empty((p, d, u.size))
            for c in range(u.size):
                h = 1e-6 * max(1.0, abs(u[c]))
                up, um = u.copy(), u.copy()
                up[c] += h
                um[c] -= h
                diff = self.mean(x, up, dt) - self.mean(x, um, dt)
                diff[:, 2] = np.mod(diff[:, 2] + np.pi, 2 * np.pi) - np.pi
                g[:, :, c] = diff / (2 * h)
            gs = g * sig[None, None, :]
            cov = f @ cov @ np.swapaxes(f, 1, 2) + gs @ np.swapaxes(gs, 1, 2)
            x = self.mean(x, u, dt)
        return x, cov


def _noisy(n: int, values: np.ndarray, sigmas: np.ndarray, rng: np.random.Generator | None) -> np.ndarray:
    """(n, k) copies of a control with independent Gaussian noise of std ``sigmas`` per column."""
    out = np.tile(np.asarray(values, dtype=np.float64), (n, 1))
    if rng is not None:
        out += rng.standard_normal((n, out.shape[1])) * sigmas
    return out


class IncrementNoise(BaseModel):
    """Pose-increment odometry (see :class:`slam_runtime.vehicle.OdometryIncrement`)."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)
    a_trans: float = Field(default=0.05, ge=0.0, description="std along per metre travelled")
    a_rot: float = Field(default=0.05, ge=0.0, description="heading std per radian turned")
    a_rot_trans: float = Field(default=0.01, ge=0.0, description="heading std per metre travelled [rad/m]")
    lateral: float = Field(default=0.02, ge=0.0, description="std across per metre travelled")
    s_x: float = Field(default=0.0, ge=0.0, description="constant std along [m / sqrt(s)]")
    s_y: float = Field(default=0.0, ge=0.0, description="constant std across [m / sqrt(s)]")
    s_theta: float = Field(default=0.0, ge=0.0, description="constant heading std [rad / sqrt(s)]")


class OdometryIncrement(VehicleModel):
    """Pose increments u = (dx, dy, dtheta) in the previous vehicle frame.

    Standard deviations of the increment actually travelled, per axis:
    along = sqrt(dt) s_x + a_trans |d|, across = sqrt(dt) s_y + lateral |d|,
    heading = sqrt(dt) s_theta + a_rot |dtheta| + a_rot_trans |d|, with
    |d| = hypot(dx, dy). The sqrt(dt) terms are a random walk of variance
    s^2 per second: noise that does not vanish when the robot stands still.
    """

    control_dim = 3
    label = "increment"
    odometry = ("pose", "increment")
    takes = "pose or increment odometry"
    Noise = IncrementNoise

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

    def control_sigmas(self, u, dt):
        return self.sigmas(np.asarray(u, dtype=np.float64), dt)

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

    def predict_gaussian(self, x, controls, dts):
        """As :meth:`VehicleModel.predict_gaussian`, with the control Jacobian in closed form (the rotation into the
        particle's heading) and the rows of a frame integrated in one compiled loop."""
        u = np.asarray(controls, dtype=np.float64).reshape(-1, 3)
        dt = np.asarray(dts, dtype=np.float64).reshape(-1)
        d = np.hypot(u[:, 0], u[:, 1])
        sig = self.const[None, :] * np.sqrt(np.maximum(dt, 0.0))[:, None] + np.column_stack(
            [self.a_trans * d, self.lateral * d, self.a_rot * np.abs(u[:, 2]) + self.a_rot_trans * d]
        )  # (R, 3) as sigmas() row by row
        return _increment_gaussian(np.ascontiguousarray(x, dtype=np.float64), u, sig)


@numba.njit(cache=True, nogil=True)
def _left_product(f, c, out):  # pragma: no cover - compiled
    """out = F C for 3 x 3 matrices, the first half of a covariance's linearised propagation F C F^T + ..."""
    for m in range(3):
        for n in range(3):
            acc = 0.0
            for k in range(3):
                acc += f[m, k] * c[k, n]
            out[m, n] = acc


@numba.njit(cache=True, nogil=True)
def _increment_gaussian(x, controls, sig):  # pragma: no cover - compiled
    """Mean motion and linearised covariance of pose increments through control rows (R, 3) of noise sigmas (R, 3).

    Per row, at heading th (c, s = cos th, sin th): x += c dx - s dy, y += s dx + c dy, th += dth;
    C <- F C F^T + G diag(sig^2) G^T with F the identity but F[0, 2] = -s dx - c dy, F[1, 2] = c dx - s dy, and
    G = d(motion)/d(increment) the rotation by th (the heading's row and column: 1)."""
    p = x.shape[0]
    out = x.copy()
    cov = np.zeros((p, 3, 3))
    f = np.eye(3)
    g = np.zeros((3, 3))
    tmp = np.zeros((3, 3))
    for r in range(controls.shape[0]):
        ux, uy, ut = controls[r, 0], controls[r, 1], controls[r, 2]
        for i in range(p):
            th = out[i, 2]
            c, s = np.cos(th), np.sin(th)
            f[0, 2] = -s * ux - c * uy
            f[1, 2] = c * ux - s * uy
            g[0, 0], g[0, 1] = c * sig[r, 0], -s * sig[r, 1]
            g[1, 0], g[1, 1] = s * sig[r, 0], c * sig[r, 1]
            g[2, 2] = sig[r, 2]
            _left_product(f, cov[i], tmp)
            for m in range(3):
                for n in range(3):
                    acc = 0.0
                    for k in range(3):
                        acc += tmp[m, k] * f[n, k] + g[m, k] * g[n, k]
                    cov[i, m, n] = acc
            out[i, 0] += c * ux - s * uy
            out[i, 1] += s * ux + c * uy
            out[i, 2] = np.mod(th + ut + np.pi, 2.0 * np.pi) - np.pi  # as detectors.geometry.compose
    return out, cov


class VelocityNoise(BaseModel):
    """Unicycle (v, omega) commands."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)
    sigma_v: float = Field(default=0.05, ge=0.0, description="m/s")
    sigma_omega: float = Field(default=0.05, ge=0.0, description="rad/s")
    speed_scale: float = Field(default=1.0, gt=0.5, lt=2.0, description="factor on every speed command")
    omega_offset: float = Field(default=0.0, ge=-0.5, le=0.5, description="turn-rate bias removed from every command [rad/s]")
    omega_scale: float = Field(default=1.0, gt=0.5, lt=2.0, description="factor on every turn-rate command (before the offset)")
    delay: float = Field(default=0.0, ge=0.0, le=1.0, description="how late the motion follows each command [s]")


class Unicycle(VehicleModel):
    """Velocity commands u = (v [m/s], omega [rad/s]) held for dt, Gaussian noise on each."""

    control_dim = 2
    label = "unicycle"
    odometry = ("velocity",)
    takes = "speed and yaw-rate odometry"
    features = ("points",)
    Noise = VelocityNoise

    def __init__(
        self,
        *,
        sigma_v: float = 0.05,
        sigma_omega: float = 0.05,
        speed_scale: float = 1.0,
        omega_offset: float = 0.0,
        omega_scale: float = 1.0,
        delay: float = 0.0,
    ) -> None:
        self.sig = np.array([sigma_v, sigma_omega], dtype=np.float64)
        self.speed_scale, self.omega_offset, self.omega_scale, self.delay = speed_scale, omega_offset, omega_scale, delay

    def control_sigmas(self, u, dt):
        return self.sig

    def step(self, x, u, dt, rng):
        vv, ww = _noisy(x.shape[0], u, self.sig, rng).T
        vv, ww = vv * self.speed_scale, ww * self.omega_scale - self.omega_offset
        th = x[:, 2]
        small = np.abs(ww) < 1e-9
        w_safe = np.where(small, 1.0, ww)
        dx = np.where(small, vv * dt * np.cos(th), vv / w_safe * (np.sin(th + ww * dt) - np.sin(th)))
        dy = np.where(small, vv * dt * np.sin(th), -vv / w_safe * (np.cos(th + ww * dt) - np.cos(th)))
        return np.column_stack([x[:, 0] + dx, x[:, 1] + dy, wrap_angle(th + ww * dt)])

    def jacobian(self, x, u, dt):
        v, w = float(u[0]) * self.speed_scale, float(u[1]) * self.omega_scale - self.omega_offset
        th = x[:, 2]
        f = np.tile(np.eye(3), (x.shape[0], 1, 1))
        if abs(w) < 1e-9:
            f[:, 0, 2], f[:, 1, 2] = -v * dt * np.sin(th), v * dt * np.cos(th)
        else:
            f[:, 0, 2] = v / w * (np.cos(th + w * dt) - np.cos(th))
            f[:, 1, 2] = v / w * (np.sin(th + w * dt) - np.sin(th))
        return f


class AckermannNoise(BaseModel):
    """Encoder speed and steering angle."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)
    sigma_speed: float = Field(default=0.1, ge=0.0, description="m/s")
    sigma_steer: float = Field(default=0.02, ge=0.0, description="rad")
    steer_offset: float = Field(default=0.0, ge=-0.2, le=0.2, description="steering bias removed from every reading [rad]")
    speed_scale: float = Field(default=1.0, gt=0.5, lt=2.0, description="factor on every speed reading")
    steer_offset_sd: float = Field(default=0.0, ge=0.0, le=0.1, description="rad: > 0 estimates the offset in every particle, from steer_offset with this sd (optimal proposal)")
    steer_offset_walk: float = Field(default=0.0, ge=0.0, le=0.01, description="rad/sqrt(s): how fast the estimated steering offset may drift")

    @model_validator(mode="after")
    def _walk_needs_the_estimate(self) -> AckermannNoise:
        if self.steer_offset_walk > 0 and self.steer_offset_sd == 0:
            raise ValueError("steer_offset_walk is the drift of the estimated offset: it needs steer_offset_sd > 0 (the estimate)")
        return self


class Ackermann(VehicleModel):
    """Encoder speed and steering u = (v [m/s], steer [rad]) of a car-like vehicle (rear-axle frame)."""

    control_dim = 2
    label = "Ackermann"
    odometry = ("ackermann",)
    takes = "encoder speed and steering odometry"
    Noise = AckermannNoise
    biases = {"steer_offset": "steering offset [rad]", "speed_scale": "speed scale"}
    settled = {"steer_offset": 5e-4}

    def fit_biases(self, controls, trajectory) -> dict:
        return fit_ackermann_bias(self, controls, trajectory)

    @classmethod
    def from_settings(cls, noise: BaseModel, vehicle=None) -> Ackermann:
        if vehicle is None:
            raise DataError("Ackermann odometry needs the vehicle geometry (wheelbase)")
        return cls(vehicle.wheelbase, vehicle.encoder_offset, **noise.model_dump())

    def __init__(
        self,
        wheelbase: float,
        encoder_offset: float = 0.0,
        *,
        sigma_speed: float = 0.1,
        sigma_steer: float = 0.02,
        steer_offset: float | np.ndarray = 0.0,
        speed_scale: float | np.ndarray = 1.0,
        steer_offset_sd: float = 0.0,
        steer_offset_walk: float = 0.0,
    ) -> None:
        self.L, self.H = float(wheelbase), float(encoder_offset)
        self.sig = np.array([sigma_speed, sigma_steer], dtype=np.float64)
        self.steer_offset = steer_offset
        self.speed_scale = speed_scale
        # the steering offset estimated in every particle (a Gaussian: mean and variance in the state's columns 3-4)
        self.adaptive = steer_offset_sd > 0.0
        self.dim = 5 if self.adaptive else 3
        self.offset_sd, self.offset_walk = float(steer_offset_sd), float(steer_offset_walk)

    def initial(self, pose, n):
        x = super().initial(pose, n)
        if self.adaptive:
            x[:, 3], x[:, 4] = float(self.steer_offset), self.offset_sd**2
        return x

    def predict_joint(self, x, controls, dts):
        """Each particle's offset o ~ N(x[3], x[4]) (after the random walk's variance for the frame) enters the motion
        as a steering noise shared by every row: with S = d(pose)/d(o) through the rows, the pose's covariance is
        the control noise's plus x[4] S S^T and its covariance with o is x[4] S."""
        xp = np.array(x, dtype=np.float64)
        xp[:, 4] += self.offset_walk**2 * float(np.sum(dts))
        c = np.asarray(controls, dtype=np.float64).reshape(-1, 2)
        pose, cov, sens = _ackermann_gaussian(
            np.ascontiguousarray(xp[:, :3]), np.ascontiguousarray(xp[:, 3]), c, np.asarray(dts, dtype=np.float64).reshape(-1),
            self.L, self.H, self.sig[0], self.sig[1], float(self.speed_scale),
        )  # fmt: skip
        var = xp[:, 4]
        xp[:, :3] = pose
        return xp, cov + var[:, None, None] * sens[:, :, None] * sens[:, None, :], var[:, None] * sens

    def condition(self, xbar, q, cross, pose):
        d = np.asarray(pose, dtype=np.float64) - xbar[:, :3]
        d[:, 2] = wrap_angle(d[:, 2])
        k = np.linalg.solve(q + np.eye(3) * 1e-12, cross[:, :, None])[..., 0]  # q^-1 Cov(pose, o): o regressed on the pose
        out = np.array(xbar, dtype=np.float64)
        out[:, :3] = pose
        out[:, 3] += np.einsum("pi,pi->p", k, d)
        out[:, 4] = np.maximum(out[:, 4] - np.einsum("pi,pi->p", k, cross), 1e-14)
        return out

    def control_sigmas(self, u, dt):
        return self.sig

    def step(self, x, u, dt, rng):
        v, g = _noisy(x.shape[0], u, self.sig, rng).T
        g = g - self.steer_offset  # a float, or one offset per state (a search over offsets)
        v = v * self.speed_scale
        vc = v / (1.0 - np.tan(g) * self.H / self.L)  # encoder speed -> rear-axle centre
        th = x[:, 2]
        return np.column_stack([x[:, 0] + dt * vc * np.cos(th), x[:, 1] + dt * vc * np.sin(th), wrap_angle(th + dt * vc / self.L * np.tan(g))])

    def jacobian(self, x, u, dt):
        v, g = float(u[0]) * self.speed_scale, float(u[1]) - self.steer_offset
        vc = v / (1.0 - np.tan(g) * self.H / self.L)
        th = x[:, 2]
        f = np.tile(np.eye(3), (x.shape[0], 1, 1))
        f[:, 0, 2], f[:, 1, 2] = -dt * vc * np.sin(th), dt * vc * np.cos(th)
        return f

    def predict_gaussian(self, x, controls, dts):
        """As :meth:`VehicleModel.predict_gaussian`, with the control Jacobian in closed form and the rows of a
        frame integrated in one compiled loop (a frame holds several odometry rows; the generic
        form costs six vectorised model evaluations per row)."""
        if np.ndim(self.steer_offset) or np.ndim(self.speed_scale):  # one bias per state: the generic form
            return super().predict_gaussian(x, controls, dts)
        c = np.asarray(controls, dtype=np.float64).reshape(-1, 2)
        x = np.ascontiguousarray(x, dtype=np.float64)
        mean, cov, _ = _ackermann_gaussian(
            x, np.full(x.shape[0], float(self.steer_offset)), c, np.asarray(dts, dtype=np.float64).reshape(-1),
            self.L, self.H, self.sig[0], self.sig[1], float(self.speed_scale),
        )  # fmt: skip
        return mean, cov


@numba.njit(cache=True, nogil=True)
def _ackermann_gaussian(x, offsets, controls, dts, wheelbase, h, s_v, s_g, scale):  # pragma: no cover - compiled
    """Mean motion and linearised covariance of the Ackermann model through control rows (R, 2).

    Per row: v_c = s v / (1 - tan(g) H / L), g = steer - offset; x += dt v_c cos th, y += dt v_c sin th,
    th += dt v_c tan(g) / L; C <- F C F^T + G diag(s_v^2, s_g^2) G^T with F = d(motion)/d(state) and
    G = d(motion)/d(v, steer) written out.

    One steering offset per pose (P,); also returns the sensitivity of each pose to its offset through the rows
    (P, 3): S <- F S - d(motion)/d(steer) per row (g = steer - offset)."""
    p = x.shape[0]
    out = x.copy()
    cov = np.zeros((p, 3, 3))
    sens = np.zeros((p, 3))
    f = np.eye(3)  # d(motion)/d(state): the identity but for the heading column's position terms
    g_ = np.zeros((3, 2))
    tmp = np.zeros((3, 3))
    for r in range(controls.shape[0]):
        dt = dts[r]
        for i in range(p):
            g = controls[r, 1] - offsets[i]
            t = np.tan(g)
            sec2 = 1.0 + t * t
            den = 1.0 - t * h / wheelbase
            a = scale / den  # d v_c / d v
            vc = a * controls[r, 0]
            dvc = scale * controls[r, 0] * (h / wheelbase) * sec2 / (den * den)  # d v_c / d steer
            dth = dt * vc * t / wheelbase
            th = out[i, 2]
            ct, st = np.cos(th), np.sin(th)
            f[0, 2] = -dt * vc * st
            f[1, 2] = dt * vc * ct
            gx, gy, gt = dt * dvc * ct, dt * dvc * st, dt / wheelbase * (dvc * t + vc * sec2)  # d(motion)/d(steer)
            g_[0, 0] = dt * a * ct * s_v
            g_[1, 0] = dt * a * st * s_v
            g_[2, 0] = dt * a * t / wheelbase * s_v
            g_[0, 1] = gx * s_g
            g_[1, 1] = gy * s_g
            g_[2, 1] = gt * s_g
            _left_product(f, cov[i], tmp)
            for m in range(3):
                for n in range(3):
                    acc = 0.0
                    for k in range(3):
                        acc += tmp[m, k] * f[n, k]
                    acc += g_[m, 0] * g_[n, 0] + g_[m, 1] * g_[n, 1]
                    cov[i, m, n] = acc
            sens[i, 0] += f[0, 2] * sens[i, 2] - gx
            sens[i, 1] += f[1, 2] * sens[i, 2] - gy
            sens[i, 2] -= gt
            out[i, 0] += dt * vc * ct
            out[i, 1] += dt * vc * st
            w = np.mod(th + dth + np.pi, 2.0 * np.pi) - np.pi
            out[i, 2] = np.pi if w == -np.pi else w  # wrap_angle: (-pi, pi]
    return out, cov, sens


def fit_ackermann_bias(
    model: Ackermann,
    controls: list[tuple[np.ndarray, np.ndarray]],
    trajectory: np.ndarray,
    *,
    window: int = 25,
    offsets: np.ndarray | None = None,
) -> dict:
    """Steering offset and speed scale of Ackermann odometry, measured against a trajectory.

    controls: per frame, its control rows (R, 2) and their durations (R,) (the rows since
    the previous frame); trajectory (T, 3): the vehicle poses at the same frames (e.g. a
    SLAM run's). Over windows of ``window`` frames, the odometry is integrated from the
    trajectory's pose at the window's start for every candidate offset at once; the
    offset whose heading changes best match the trajectory's (least squares) wins, then
    the speed scale is the ratio of the trajectory's path length to the odometry's.
    """
    offsets = np.linspace(-0.03, 0.03, 241) if offsets is None else np.asarray(offsets, dtype=np.float64)
    t = trajectory.shape[0]
    if len(controls) != t:
        raise ValueError("one list of control rows per trajectory pose")
    c = offsets.size
    starts = np.arange(0, t - window, window)
    err = np.zeros(c)
    dist_dr = np.zeros(c)
    dist_tr = 0.0
    probe = Ackermann(model.L, model.H, steer_offset=offsets)
    for s0 in starts:
        x = np.tile(trajectory[s0], (c, 1))
        for f in range(s0 + 1, s0 + window + 1):
            u, dt = controls[f]
            for uu, d in zip(u, dt, strict=True):
                prev = x
                x = probe.mean(x, uu, float(d))
                dist_dr += np.hypot(x[:, 0] - prev[:, 0], x[:, 1] - prev[:, 1])
        dth = np.mod(x[:, 2] - trajectory[s0 + window, 2] + np.pi, 2 * np.pi) - np.pi
        err += dth * dth
        dist_tr += float(np.sum(np.hypot(*np.diff(trajectory[s0 : s0 + window + 1, :2], axis=0).T)))
    best = int(np.argmin(err))
    return {
        "steer_offset": float(offsets[best]),
        "speed_scale": float(dist_tr / dist_dr[best]) if dist_dr[best] > 0 else 1.0,
        "heading_rms_rad": float(np.sqrt(err[best] / max(len(starts), 1))),
        "heading_rms_without_rad": float(np.sqrt(err[np.argmin(np.abs(offsets))] / max(len(starts), 1))),
        "windows": int(len(starts)),
    }


#: The vehicle models by the name of their noise settings' group (``motion.<name>``), in the settings' order.
VEHICLE_MODELS: Registry[type[VehicleModel]] = Registry("vehicle model", builtins=("slam_runtime.vehicle", "slam_runtime.ect"))
VEHICLE_MODELS.add("increment", OdometryIncrement)
VEHICLE_MODELS.add("velocity", Unicycle)
VEHICLE_MODELS.add("ackermann", Ackermann)
