"""Pydantic models of the parts of a detector profile.

Every model forbids unknown keys and bounds its fields; defaults work. The
runtime (``detectors.model``) and the calibration (``calib``) both read these.
"""

from __future__ import annotations

from typing import Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, model_serializer, model_validator

from profiles.errors import DataError


class Strict(BaseModel):
    model_config = ConfigDict(extra="forbid")


class Mount(Strict):
    """Sensor pose in the vehicle frame: (x [m] forward, y [m] left, theta [rad])."""

    model_config = ConfigDict(extra="forbid", frozen=True)
    x: float = 0.0
    y: float = 0.0
    theta: float = 0.0


class Vehicle(Strict):
    """Vehicle geometry needed by some motion models (Ackermann).

    Origin of the vehicle frame: the rear-axle centre. ``encoder_offset`` is the
    lateral distance of the speed encoder (rear left wheel) from that centre.
    """

    model_config = ConfigDict(extra="forbid", frozen=True)
    wheelbase: float = Field(gt=0.0)
    encoder_offset: float = Field(default=0.0, ge=0.0)


class LidarGeometry(Strict):
    """Beam layout of a spinning multi-beam lidar (kind ``lidar3d``, e.g. a Velodyne HDL-64E).

    One ring per vertical angle, columns every ``azimuth_increment_deg`` around the
    full circle; ``height`` is the sensor's height above the vehicle frame's origin
    (the ground under the vehicle), so planes in the sensor frame can be placed in 3D.
    """

    model_config = ConfigDict(extra="forbid", frozen=True)
    vertical_angles_deg: list[float] = Field(min_length=1, description="elevation of each ring [deg], sensor frame")
    azimuth_increment_deg: float = Field(gt=0.0, le=10.0, description="azimuth step between columns [deg]")
    height: float = Field(default=0.0, description="sensor height above the vehicle frame origin [m]")


class SensorModel(Strict):
    """What the sensor is and how it is mounted.

    For a 2D laser, beam ``i`` points at ``angle_min + i * angle_increment``
    (sensor frame, radians). Detection-only sensors (a camera, a vendor's tree
    extractor) give ``fov`` instead of a beam geometry. A 3D lidar gives its
    ring and column layout in ``lidar`` (written only when present).
    """

    model_config = ConfigDict(extra="forbid", frozen=True)
    kind: Literal["laser2d", "lidar3d", "camera", "detector"] = "laser2d"
    n_beams: int | None = Field(default=None, ge=1)
    angle_min: float | None = None
    angle_increment: float | None = None
    range_min: float = Field(default=0.0, ge=0.0)
    range_max: float | None = Field(default=None, gt=0.0)
    range_sigma: float | None = Field(default=None, ge=0.0)
    fov: float | None = Field(default=None, gt=0.0, le=2 * np.pi + 1e-9)
    mount: Mount = Mount()
    lidar: LidarGeometry | None = None

    @model_serializer(mode="wrap")
    def _drop_absent_lidar(self, handler):
        data = handler(self)
        if isinstance(data, dict) and data.get("lidar", 0) is None:
            data.pop("lidar")  # absent rather than null: sensor models without it keep their bytes
        return data

    def angles(self) -> np.ndarray:
        """Beam angles in the sensor frame, (B,) float64 radians."""
        if self.n_beams is None or self.angle_min is None or self.angle_increment is None:
            raise DataError(f"sensor model of kind {self.kind!r} has no beam geometry")
        return self.angle_min + self.angle_increment * np.arange(self.n_beams, dtype=np.float64)

    @property
    def field_of_view(self) -> float | None:
        """Angular width [rad] covered by the beams (or ``fov``)."""
        if self.n_beams is not None and self.angle_increment is not None:
            return abs(self.angle_increment) * (self.n_beams - 1)
        return self.fov


class CircleDetectorParams(Strict):
    """Parameters of the circle detector (thesis sec. 5.3)."""

    jump: float = Field(default=0.5, gt=0.0, description="distance between consecutive returns that breaks a cluster [m]")
    min_points: int = Field(default=3, ge=3, description="fewest returns in a cluster (a circle needs 3)")
    max_points: int | None = Field(default=None, ge=3, description="most returns in a cluster (None: no limit)")
    max_radius: float | None = Field(default=None, gt=0.0, description="drop fitted circles larger than this [m]")
    lm_iterations: int = Field(default=30, ge=1, le=500, description="Levenberg-Marquardt iterations at most")
    line_radius: float = Field(
        default=100.0, gt=0.0, description="LM stops refining a circle whose radius exceeds this [m]: the cluster is a straight line"
    )


class HotellingParams(Strict):
    """Hotelling ellipsoid of true detections' descriptors (thesis eq. 5.4).

    A detection with descriptor vector x is kept when
    (x - mean)^T covariance^-1 (x - mean) <= gamma.
    """

    names: list[str] = Field(min_length=1)
    mean: list[float]
    covariance: list[list[float]]
    confidence: float = Field(default=0.999, gt=0.0, lt=1.0)
    gamma: float = Field(gt=0.0, description="threshold on the squared Mahalanobis distance")

    @model_validator(mode="after")
    def _shapes(self) -> HotellingParams:
        d = len(self.names)
        if len(self.mean) != d:
            raise ValueError(f"mean has {len(self.mean)} entries for {d} descriptor names")
        cov = np.asarray(self.covariance, dtype=np.float64)
        if cov.shape != (d, d):
            raise ValueError(f"covariance must be {d}x{d}, got {cov.shape}")
        if not np.allclose(cov, cov.T, rtol=1e-9, atol=1e-15):
            raise ValueError("covariance is not symmetric")
        if np.linalg.eigvalsh(cov).min() <= 0:
            raise ValueError("covariance is not positive definite")
        return self


class PdTable(Strict):
    """P_D against a covariate, piecewise constant (thesis eq. 6.2, Table 6.1).

    Bin i covers ``edges[i] <= v < edges[i+1]``; a value at or beyond the last
    edge uses the last bin, a value below the first edge has P_D = 0. For
    ``n_p`` the edges are integers, one bin per count.
    """

    covariate: Literal["n_p", "range", "points"] = "n_p"
    edges: list[float] = Field(min_length=2)
    pd: list[float]
    counts: list[int] | None = None
    detections: list[int] | None = None
    wilson_low: list[float] | None = None
    wilson_high: list[float] | None = None
    clamping: str = Field(default="none", description="how the raw estimates were clamped")

    @model_validator(mode="after")
    def _shapes(self) -> PdTable:
        e = np.asarray(self.edges)
        if np.any(np.diff(e) <= 0):
            raise ValueError("edges must increase strictly")
        n = e.size - 1
        for name in ("pd", "counts", "detections", "wilson_low", "wilson_high"):
            v = getattr(self, name)
            if v is not None and len(v) != n:
                raise ValueError(f"{name} has {len(v)} entries for {n} bins")
        if any(not 0.0 <= p <= 1.0 for p in self.pd):
            raise ValueError("pd values must lie in [0, 1]")
        return self

    def lookup(self, v: np.ndarray) -> np.ndarray:
        """P_D for covariate values ``v`` (any shape)."""
        e = np.asarray(self.edges)
        pd = np.asarray(self.pd)
        i = np.clip(np.searchsorted(e, v, side="right") - 1, 0, pd.size - 1)
        return np.where(np.asarray(v) < e[0], 0.0, pd[i])


class MeasurementNoise(Strict):
    """Spread of true detections' (range, bearing) about the truth, measured in calibration.

    Robust standard deviations (1.4826 x median absolute deviation) and median
    biases of the residuals measured - predicted; a filter takes the sigmas as
    its measurement noise.
    """

    range_sigma: float = Field(gt=0.0, description="[m]")
    bearing_sigma: float = Field(gt=0.0, description="[rad]")
    range_bias: float = Field(default=0.0, description="[m]")
    bearing_bias: float = Field(default=0.0, description="[rad]")
    samples: int = Field(default=0, ge=0, description="true detections the figures come from")


class ClutterParams(Strict):
    """Poisson clutter: ``rate`` false alarms per scan spread uniformly over ``volume``.

    space: ``range_bearing`` (volume in m*rad), ``xy`` (area in m^2) or ``plane``
    (the chart of landmark planes: azimuth x elevation x offset, in rad^2 m).
    """

    rate: float = Field(ge=0.0, description="lambda: mean false alarms per scan")
    space: Literal["range_bearing", "xy", "plane"] = "range_bearing"
    volume: float = Field(gt=0.0, description="size of the field of view in the measurement space")
    kappa: float | None = Field(default=None, ge=0.0, description="clutter intensity rate / volume (filled in when omitted)")
    chi2: float | None = None
    dof: int | None = None
    p_value: float | None = Field(default=None, ge=0.0, le=1.0)
    dispersion: float | None = Field(default=None, ge=0.0, description="variance / mean of the per-scan counts")

    @model_validator(mode="after")
    def _kappa(self) -> ClutterParams:
        k = self.rate / self.volume
        if self.kappa is None:
            self.kappa = k
        elif not np.isclose(self.kappa, k, rtol=1e-9, atol=0.0):
            raise ValueError(f"kappa {self.kappa} is not rate / volume = {k}")
        return self
