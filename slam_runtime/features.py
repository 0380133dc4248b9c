"""Feature (measurement) models: how a landmark state is measured from a vehicle pose.

The feature-model protocol, vectorised over any leading axes (particles x
components x measurements):

* ``predict(poses (..., 3), x (..., dx)) -> (zhat (..., dz), H (..., dz, dx))``:
  the predicted measurement in the sensor frame and its Jacobian with respect
  to the landmark state (what the EKF map update of a Rao-Blackwellised filter
  needs, thesis eqs. 3.17-3.18);
* ``inverse(poses (..., 3), z (..., dz)) -> (x (..., dx), G (..., dx, dz))``: the
  landmark that would give z, and dx/dz (birth);
* ``innovation(z, zhat) -> nu``: z - zhat with angles wrapped to (-pi, pi];
* ``position(x) -> (..., k)``: the part of the state a map metric compares
  (OSPA between point sets).

Poses are vehicle poses (x, y, theta) in the world frame; the model holds the
sensor's mount on the vehicle. A plane in Hesse form is a second
implementation of the same protocol (the planar-feature filters).

Every feature model is found through :data:`FEATURE_MODELS` under the settings'
``features`` value ("points", "planes"); its ``Noise`` settings (the noise
floor of a measurement) become fields of the SLAM settings' ``measurement``
group, and :meth:`FeatureModel.from_settings` builds it from them and the
detection model.
"""

from __future__ import annotations

from abc import ABC, abstractmethod

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from detectors.geometry import compose
from profiles.registry import Registry


def wrap(a: np.ndarray) -> np.ndarray:
    """Angles wrapped to (-pi, pi]: one conditional shift each way, exact for |a| < 2 pi (any
    difference of two wrapped angles), and cheaper than a modulo in the update's inner arrays."""
    a = np.where(a > np.pi, a - 2 * np.pi, a)
    return np.where(a <= -np.pi, a + 2 * np.pi, a)


def mean_by_label(label: np.ndarray, x: np.ndarray, w: np.ndarray, angular: tuple[int, ...] = ()) -> tuple[np.ndarray, np.ndarray]:
    """The w-weighted mean state of each label: (labels (U,) sorted, means (U, dx)) of states x (N, dx) with labels
    (N,) and weights (N,). Taken as each label's first state plus the mean of the differences from it, the angular
    components wrapped, so that angles average across the wrap; a label of total weight 0 keeps its first state."""
    uniq, first, inv = np.unique(label, return_index=True, return_inverse=True)
    tot = np.bincount(inv, weights=w, minlength=uniq.size)
    ref = x[first]
    d = x - ref[inv]
    ang = list(angular)
    d[:, ang] = wrap(d[:, ang])
    # (float: bincount of no labels is an integer array)
    acc = np.stack([np.bincount(inv, weights=w * d[:, k], minlength=uniq.size) for k in range(x.shape[1])], axis=1).astype(np.float64)
    mean = ref + np.divide(acc, tot[:, None], out=np.zeros_like(acc), where=tot[:, None] > 0)
    mean[:, ang] = wrap(mean[:, ang])
    return uniq, mean


def lookup(keys: np.ndarray, query: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(index into the sorted keys, whether keys hold it) of each query."""
    n = keys.size
    if n == 0:
        return np.zeros(query.shape, np.int64), np.zeros(query.shape, bool)
    j = np.minimum(np.searchsorted(keys, query), n - 1)
    return j, keys[j] == query


class FeatureModel(ABC):
    dim_x: int
    dim_z: int
    #: the noise floor of a measurement, settable in the SLAM settings' ``measurement`` group (None: the profile's)
    Noise: type[BaseModel]
    #: which measurement components are angles (wrapped in innovations)
    angular: tuple[int, ...] = ()
    #: which state components are angles (wrapped when states of one feature are averaged)
    state_angular: tuple[int, ...] = ()
    #: the labelled filters' survival_duplicate when the settings give none (1: off)
    survival_duplicate: float = 1.0

    def __init__(self, r: np.ndarray, mount: np.ndarray | None = None) -> None:
        """r (dz, dz): the measurement noise covariance (a floor, when each measurement brings its own);
        mount (3,): the sensor's pose on the vehicle (x, y, theta)."""
        self.r = np.asarray(r, dtype=np.float64).reshape(self.dim_z, self.dim_z)
        self.mount = np.zeros(3) if mount is None else np.asarray(mount, dtype=np.float64)

    def sensor_pose(self, poses: np.ndarray) -> np.ndarray:
        """(..., 3) sensor poses of vehicle poses (..., 3)."""
        return compose(poses, self.mount) if np.any(self.mount) else np.asarray(poses, dtype=np.float64)

    @abstractmethod
    def predict_sensor(self, sensor: np.ndarray, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """As :meth:`predict`, from sensor poses (the mount already applied)."""

    @abstractmethod
    def inverse_sensor(self, sensor: np.ndarray, z: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """As :meth:`inverse`, from sensor poses."""

    def predict(self, poses: np.ndarray, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return self.predict_sensor(self.sensor_pose(poses), x)

    def inverse(self, poses: np.ndarray, z: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return self.inverse_sensor(self.sensor_pose(poses), z)

    def pose_jacobian(self, poses: np.ndarray, x: np.ndarray) -> np.ndarray:
        """(..., dz, 3) d(predicted z)/d(vehicle pose (x, y, theta)), the mount included (the pose proposal needs it)."""
        raise NotImplementedError(f"{type(self).__name__} has no pose Jacobian")

    def innovation(self, z: np.ndarray, zhat: np.ndarray) -> np.ndarray:
        d = z - zhat
        for i in self.angular:
            d[..., i] = wrap(d[..., i])
        return d

    def position(self, x: np.ndarray) -> np.ndarray:
        return x

    def plane_gap(self, za: np.ndarray, zb: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
        """(normal angle [rad], offset difference [m]), each of the broadcast shape (...), between measurements za, zb
        (..., dz) of planar features (the plane metric of the labelled filters' duplicate test); None: the feature is not a plane
        (the filters' Mahalanobis gate decides)."""
        return None


class RangeBearingNoise(BaseModel):
    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)
    sigma_range: float | None = Field(default=None, gt=0.0, description="[m]")
    sigma_bearing: float | None = Field(default=None, gt=0.0, description="[rad]")


class RangeBearing(FeatureModel):
    """A point landmark (x, y) [m, world frame] measured as (range [m], bearing [rad]) in the sensor frame.

    A circular landmark (a trunk) is represented by its centre; the circle
    detector reports the centre's range and bearing, so no radius term enters.
    """

    dim_x = 2
    dim_z = 2
    angular = (1,)
    Noise = RangeBearingNoise

    @classmethod
    def from_settings(cls, detection, noise, mount: np.ndarray, metric=None) -> RangeBearing:
        """The noise floor: the settings' (``noise``: sigma_range, sigma_bearing), else the profile's measured noise,
        else 0.1 m / 0.01 rad."""
        sr, sb = detection.noise_sigmas if detection.noise is not None else (0.1, 0.01)
        sr = noise.sigma_range if noise.sigma_range is not None else sr
        sb = noise.sigma_bearing if noise.sigma_bearing is not None else sb
        return cls(np.diag([sr**2, sb**2]), mount)

    def predict_sensor(self, sensor, x):
        dx = x[..., 0] - sensor[..., 0]
        dy = x[..., 1] - sensor[..., 1]
        q = np.maximum(dx * dx + dy * dy, 1e-12)
        r = np.sqrt(q)
        b = wrap(np.arctan2(dy, dx) - sensor[..., 2])
        zhat = np.stack([r, b], axis=-1)
        h = np.empty(zhat.shape + (2,))
        h[..., 0, 0] = dx / r
        h[..., 0, 1] = dy / r
        h[..., 1, 0] = -dy / q
        h[..., 1, 1] = dx / q
        return zhat, h

    def pose_jacobian(self, poses, x):
        poses = np.asarray(poses, dtype=np.float64)
        sp = self.sensor_pose(poses)
        _, h = self.predict_sensor(sp, x)  # d z / d landmark = - d z / d sensor position
        th = poses[..., 2]
        mx, my = self.mount[0], self.mount[1]
        dsx = -np.sin(th) * mx - np.cos(th) * my  # d(sensor position)/d(theta)
        dsy = np.cos(th) * mx - np.sin(th) * my
        out = np.empty(h.shape[:-1] + (3,))
        out[..., 0] = -h[..., 0]
        out[..., 1] = -h[..., 1]
        out[..., 2] = -(h[..., 0] * dsx[..., None] + h[..., 1] * dsy[..., None])
        out[..., 1, 2] -= 1.0  # the bearing turns with the sensor
        return out

    def inverse_sensor(self, sensor, z):
        a = sensor[..., 2] + z[..., 1]
        c, s = np.cos(a), np.sin(a)
        pos = np.stack([sensor[..., 0] + z[..., 0] * c, sensor[..., 1] + z[..., 0] * s], axis=-1)
        g = np.empty(pos.shape + (2,))
        g[..., 0, 0] = c
        g[..., 0, 1] = -z[..., 0] * s
        g[..., 1, 0] = s
        g[..., 1, 1] = z[..., 0] * c
        return pos, g



#: The feature models by the settings' ``features`` value, in the settings' order.
FEATURE_MODELS: Registry[type[FeatureModel]] = Registry("feature model", builtins=("slam_runtime.features", "slam_runtime.plane_features"))
FEATURE_MODELS.add("points", RangeBearing)
