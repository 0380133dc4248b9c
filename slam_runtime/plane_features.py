"""The planar landmark behind the feature-model protocol: a plane in the world, measured in the sensor frame.

State x (world frame, :mod:`detectors.geometry3d`'s chart): ``(theta, phi, d)``
-- the unit normal's azimuth and elevation [rad] and the offset [m] of the plane
n . p = d. Measurement z (sensor frame): the same chart of the plane the
detector segmented, with its normal pointing away from the sensor (d > 0).

The prediction is ``beta_sensor^T = beta_world^T R_s`` with R_s the sensor's
pose matrix (eq. 28 with the mount and the sensor height; eq. 35 with R_k the
identity), written in the chart::

    z = (theta - yaw_s, phi, d - n(theta, phi) . (x_s, y_s, h))

and its Jacobian H = dz/dx has the closed form of
:func:`detectors.geometry3d.world_to_sensor`; the inverse (birth) is
:func:`detectors.geometry3d.sensor_to_world`. The innovation is taken on the
unit normal and the offset: the normal's azimuth difference wrapped to
(-pi, pi], its elevation difference, the offset difference. A plane's state
keeps the orientation it was born with (normal away from the sensor that saw
it), which holds while the vehicle stays on the plane's side, as it does on a
street.

For map metrics a plane is embedded as ``(L n, d)`` (:meth:`PlaneFeature.position`,
L = ``metric_length``), so the distance between two planes is
``sqrt(L^2 |n1 - n2|^2 + (d1 - d2)^2)``, taken over the two orientations of the
second plane (:func:`plane_distance`): with L = 10 m, 1 deg of normal counts as
about 0.17 m of offset.
"""

from __future__ import annotations

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from detectors.geometry3d import normal_angle, normal_from_chart, orient_away, sensor_to_world, world_to_sensor
from slam_runtime.features import FEATURE_MODELS, FeatureModel

#: least (azimuth [rad], elevation [rad], offset [m]) noise of a plane measurement when the settings give none
PLANE_NOISE_FLOOR = (0.005, 0.005, 0.05)


class PlaneNoiseSettings(BaseModel):
    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)
    sigma_azimuth: float | None = Field(default=None, gt=0.0, description="planes: normal azimuth [rad]")
    sigma_elevation: float | None = Field(default=None, gt=0.0, description="planes: normal elevation [rad]")
    sigma_offset: float | None = Field(default=None, gt=0.0, description="planes: offset [m]")


class PlaneFeature(FeatureModel):
    """A plane (theta, phi, d) in the world measured as (theta, phi, d) in the sensor frame.

    r (3, 3): the noise floor of a measurement's (azimuth [rad], elevation [rad], offset [m]);
    mount (3,): the sensor's planar pose on the vehicle; height: the sensor's height above the
    vehicle frame's origin [m]; metric_length: L of the map metric [m].
    """

    dim_x = 3
    dim_z = 3
    angular = (0,)
    state_angular = (0,)
    Noise = PlaneNoiseSettings
    #: a plane seen in pieces leaves a second track a few cm off its landmark's, which a low calibrated P_D does not
    #: end (docs/calibration-payoff.md); 0.5 per step in view ends it within a few steps unless the data keep it
    survival_duplicate = 0.5

    @classmethod
    def from_settings(cls, detection, noise, mount: np.ndarray, metric=None) -> PlaneFeature:
        """The noise floor: the settings' (``noise``: sigma_azimuth, sigma_elevation, sigma_offset), else the
        profile's noise of true detections but no less than :data:`PLANE_NOISE_FLOOR` (tens of particles cannot
        follow a likelihood narrower than their own spread); ``metric``: the settings' map metric (plane_length)."""
        sa, se, so = np.maximum(detection.noise_sigmas, PLANE_NOISE_FLOOR)
        sa = noise.sigma_azimuth if noise.sigma_azimuth is not None else sa
        se = noise.sigma_elevation if noise.sigma_elevation is not None else se
        so = noise.sigma_offset if noise.sigma_offset is not None else so
        length = metric.plane_length if metric is not None else 10.0
        return cls(np.diag([sa**2, se**2, so**2]), mount, height=detection.height, metric_length=length)

    def __init__(self, r: np.ndarray, mount: np.ndarray | None = None, *, height: float = 0.0, metric_length: float = 10.0) -> None:
        super().__init__(r, mount)
        self.height = float(height)
        self.metric_length = float(metric_length)

    def predict_sensor(self, sensor, x):
        return world_to_sensor(x, sensor, self.height)

    def inverse_sensor(self, sensor, z):
        return sensor_to_world(z, sensor, self.height)

    def plane_gap(self, za: np.ndarray, zb: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(normal angle [rad], |offset difference| [m]), each of the broadcast shape (...), between sensor-frame
        charts za, zb (..., 3): how far apart two planes are in the plane metric, whichever orientation each was
        born with (both oriented away from the sensor first)."""
        na, da = orient_away(*normal_from_chart(za))
        nb, db = orient_away(*normal_from_chart(zb))
        return normal_angle(na, nb, unsigned=False), np.abs(da - db)

    def position(self, x: np.ndarray) -> np.ndarray:
        """(..., 4) the embedding (L n, d), oriented so that d >= 0."""
        n, d = normal_from_chart(np.asarray(x, dtype=np.float64).reshape(-1, 3))
        n, d = orient_away(n, d)
        return np.column_stack([self.metric_length * n, d])


def embed(normal: np.ndarray, offset: np.ndarray, metric_length: float = 10.0) -> np.ndarray:
    """(L, 4) the metric embedding (L n, d) of planes n . p = d, oriented so that d >= 0."""
    n, d = orient_away(np.asarray(normal, dtype=np.float64).reshape(-1, 3), np.asarray(offset, dtype=np.float64).reshape(-1))
    return np.column_stack([metric_length * n, d])


def plane_distance(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(m, n) distances between embedded planes a (m, 4) and b (n, 4): the nearer of b and -b (the same plane)."""
    a = np.asarray(a, dtype=np.float64).reshape(-1, 4)
    b = np.asarray(b, dtype=np.float64).reshape(-1, 4)
    d1 = np.linalg.norm(a[:, None, :] - b[None, :, :], axis=-1)
    d2 = np.linalg.norm(a[:, None, :] + b[None, :, :], axis=-1)
    return np.minimum(d1, d2)



FEATURE_MODELS.add("planes", PlaneFeature)
