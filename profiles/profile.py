"""The detector profile: everything a filter needs to know about one detector on one sensor.

A profile is a versioned YAML document (schema version ``SCHEMA_VERSION``)::

    schema_version: 1
    name: park-laser            # [a-z0-9][a-z0-9._-]*
    version: 1.0.0              # semantic version; a written version is never replaced silently
    description: ...
    detector:  {kind: circle2d, circle: {jump, min_points, ...}, k_sigma, buffer_samples, association_gate}
               or {kind: plane3d, plane: {cell_azimuth_deg, ..., msse_t, ...}, ...}
    sensor:    {kind, n_beams, angle_min, angle_increment, range_min, range_max, range_sigma, fov, mount}
    hotelling: {names, mean, covariance, confidence, gamma, auc_hotelling, auc_fisher}
    pd:        {covariate: n_p | range, edges, pd, counts, detections, wilson_low, wilson_high, clamping}
    clutter:   {rate, space, volume, chi2, dof, p_value, dispersion}
    descriptor_likelihoods: {true: truncated_gaussian, false: uniform_ellipsoid, gaussian_mass, ellipsoid_volume}
    provenance: {inputs: [{name, sha256}], detcal_version, command, parameters, created, seed}

    planes:    {pd_grid, noise, max_elevation_deg, min_points, offset_max, slab_k_sigma, slab_ratio}  (plane3d only)

Every level forbids unknown keys; a wrong value is reported with its field path.
A ``plane3d`` detector on a ``lidar3d`` sensor with a P_D table over ``points``
and a ``planes`` section is the profile kind ``lidar3d-planes`` (:attr:`DetectorProfile.kind`).
"""

from __future__ import annotations

import re
from typing import Any, Literal

from pydantic import Field, field_validator, model_validator

from profiles.planes import PlaneDetectorParams, PlaneStats
from profiles.schema import CircleDetectorParams, ClutterParams, HotellingParams, MeasurementNoise, PdTable, SensorModel, Strict

SCHEMA_VERSION = 1
NAME_RE = re.compile(r"^[a-z0-9][a-z0-9._-]*$")
SEMVER_RE = re.compile(r"^(0|[1-9]\d*)\.(0|[1-9]\d*)\.(0|[1-9]\d*)$")


def semver_key(v: str) -> tuple[int, int, int]:
    m = SEMVER_RE.match(v)
    if m is None:
        raise ValueError(f"{v!r} is not a semantic version MAJOR.MINOR.PATCH")
    return int(m.group(1)), int(m.group(2)), int(m.group(3))


class DetectorSpec(Strict):
    """Which detector and its parameters.

    ``circle2d``: the thesis's laser circle detector run by detcal (``circle`` holds
    its parameters). ``external``: detections produced elsewhere and read from the
    log (a camera's barcode detector, a vendor's tree extractor). ``plane3d``: detcal's
    plane detector on 3D lidar clouds (``plane`` holds its parameters).
    """

    kind: Literal["circle2d", "external", "plane3d"] = "circle2d"
    circle: CircleDetectorParams | None = None
    plane: PlaneDetectorParams | None = None
    k_sigma: float = Field(default=3.0, gt=0.0, description="occlusion tolerance of the n_p ray tracer, in sigma_r")
    buffer_samples: int = Field(default=5, ge=1, description="lateral samples of the buffer-zone rule (odd)")
    association_gate: float = Field(default=1.0, gt=0.0, description="detection-landmark gate used in calibration [m]")

    @model_validator(mode="after")
    def _circle(self) -> DetectorSpec:
        if self.kind == "circle2d" and self.circle is None:
            self.circle = CircleDetectorParams()
        if self.kind != "circle2d" and self.circle is not None:
            raise ValueError(f"a {self.kind} detector has no circle parameters")
        if self.kind == "plane3d" and self.plane is None:
            self.plane = PlaneDetectorParams()
        if self.kind != "plane3d" and self.plane is not None:
            raise ValueError(f"a {self.kind} detector has no plane parameters")
        if self.buffer_samples % 2 == 0:
            raise ValueError("buffer_samples must be odd")
        return self


class HotellingModel(HotellingParams):
    """Hotelling ellipsoid (eq. 5.4) with the ROC areas measured in calibration (fig. 5.5)."""

    auc_hotelling: float | None = Field(default=None, ge=0.0, le=1.0)
    auc_fisher: float | None = Field(default=None, ge=0.0, le=1.0)
    samples: int | None = Field(default=None, ge=0, description="true detections the ellipsoid was fitted to")


class DescriptorLikelihoods(Strict):
    """Eq. 5.6: true detections' descriptors ~ Gaussian truncated to the ellipsoid, false ones uniform over it."""

    true: Literal["truncated_gaussian"] = "truncated_gaussian"
    false: Literal["uniform_ellipsoid"] = "uniform_ellipsoid"
    gaussian_mass: float = Field(gt=0.0, le=1.0, description="chi2 CDF of gamma: the Gaussian's mass inside the ellipsoid")
    ellipsoid_volume: float = Field(gt=0.0, description="volume of the ellipsoid in descriptor space (g_FA = 1 / volume)")


class InputRef(Strict):
    name: str
    sha256: str = Field(pattern=r"^[0-9a-f]{64}$")


class Provenance(Strict):
    inputs: list[InputRef] = Field(default_factory=list)
    detcal_version: str
    command: str = ""
    parameters: dict[str, Any] = Field(default_factory=dict)
    created: str = Field(description="ISO 8601 UTC time (SOURCE_DATE_EPOCH when set, for reproducible bytes)")
    seed: int | None = None


class DetectorProfile(Strict):
    schema_version: Literal[1] = SCHEMA_VERSION
    name: str
    version: str
    description: str = ""
    detector: DetectorSpec
    sensor: SensorModel
    hotelling: HotellingModel | None = None
    pd: PdTable
    clutter: ClutterParams
    descriptor_likelihoods: DescriptorLikelihoods | None = None
    noise: MeasurementNoise | None = Field(default=None, description="measurement noise of true detections (written only when measured)")
    planes: PlaneStats | None = Field(default=None, description="plane3d detectors: P_D grid, noise, landmark planes (written only for them)")
    provenance: Provenance

    @field_validator("name")
    @classmethod
    def _name(cls, v: str) -> str:
        if not NAME_RE.match(v):
            raise ValueError("name must match [a-z0-9][a-z0-9._-]* (lower case, no '@' or '/')")
        return v

    @field_validator("version")
    @classmethod
    def _version(cls, v: str) -> str:
        semver_key(v)
        return v

    @model_validator(mode="after")
    def _consistent(self) -> DetectorProfile:
        if self.pd.covariate == "n_p":
            if self.detector.kind != "circle2d":
                raise ValueError("pd.covariate n_p needs a circle2d detector (ray tracing of its scans)")
            if self.sensor.n_beams is None or self.sensor.range_sigma is None:
                raise ValueError("pd.covariate n_p needs sensor.n_beams and sensor.range_sigma")
        if (self.descriptor_likelihoods is not None) and self.hotelling is None:
            raise ValueError("descriptor_likelihoods need a hotelling model")
        planar = self.detector.kind == "plane3d"
        if planar and (self.sensor.kind != "lidar3d" or self.sensor.lidar is None):
            raise ValueError("a plane3d detector needs a lidar3d sensor with its lidar geometry")
        if planar and (self.pd.covariate != "points" or self.planes is None or self.clutter.space != "plane"):
            raise ValueError("a plane3d profile needs pd.covariate points, a planes section and clutter.space plane")
        if not planar and (self.planes is not None or self.pd.covariate == "points"):
            raise ValueError("planes and a P_D table over points belong to plane3d detectors")
        return self

    @property
    def kind(self) -> str:
        """What the profile is for: ``laser2d-circles``, ``lidar3d-planes`` or ``<sensor kind>-external``."""
        if self.detector.kind == "plane3d":
            return "lidar3d-planes"
        if self.detector.kind == "circle2d":
            return f"{self.sensor.kind}-circles"
        return f"{self.sensor.kind}-external"

    @property
    def ref(self) -> str:
        return f"{self.name}@{self.version}"
