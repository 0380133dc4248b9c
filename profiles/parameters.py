"""The parameters a calibration records in a profile's provenance, as pydantic models (``extra="forbid"``).

A profile records the config it was made with (``provenance.parameters``); these
are those configs: the laser calibration's (:class:`CalibrateConfig`), the
detection-level calibration's (:class:`DetectionCalibConfig`), the
self-calibration's (:class:`SelfCalConfig`) and the scenarios of the simulators
whose truth is a profile (:class:`RfsSimConfig`, :class:`GlmbPaperConfig`).
They live here, below every other package, so that a profile validates the same
whichever packages a program imports (:mod:`profiles.provenance` adds the
choices the data made); ``calib`` uses them as its configs.
"""

from __future__ import annotations

from typing import Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, field_validator, model_validator

from profiles.schema import CircleDetectorParams


def check_order(model: BaseModel, low: str, high: str, *, strict: bool = False) -> None:
    """A model's own check that setting ``low`` does not exceed ``high`` (``strict``: is below it), for a model
    validator; the message names both with their values."""
    a, b = getattr(model, low), getattr(model, high)
    if a > b or (strict and a == b):
        raise ValueError(f"{low} ({a}) must {'be below' if strict else 'not exceed'} {high} ({b})")


class PdFitConfig(BaseModel):
    """How the P_D table is binned and clamped.

    ``min_count``: a bin is well populated with at least this many (landmark,
    scan) pairs. ``tail``: above the last well-populated bin, ``last`` uses that
    bin's own estimate (the thesis: n_p > 6 uses n_p = 6), ``pool`` pools every
    pair at or above it into that bin (more data for the same rule; the default,
    because the tail is where counts are thin). ``zero_below``: estimates under
    this become 0 (thesis: 0.1), so a filter does not keep expecting features
    that are out of view.
    """

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)
    min_count: int = Field(default=200, ge=1)
    tail: str = Field(default="pool", pattern="^(pool|last)$")
    zero_below: float = Field(default=0.1, ge=0.0, lt=1.0)
    range_bin: float = Field(default=0.5, gt=0.0, description="bin width for a range covariate [m]")


class ClutterModelConfig(BaseModel):
    """How clutter counts and the clutter density are modelled."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)
    dispersion_level: float = Field(default=0.05, gt=0.0, lt=1.0, description="negative binomial when the dispersion test rejects the Poisson at this level")
    density: Literal["auto", "always", "never"] = Field(
        default="auto",
        description="a density over (range, bearing): auto = chosen against the uniform one by leave-one-log-out likelihood "
        "when there are several logs (one log: uniform); always = also over time blocks of a single log; never = uniform",
    )
    range_bins: int = Field(default=8, ge=1, le=200)
    bearing_bins: int = Field(default=8, ge=1, le=200)
    smoothing: list[float] = Field(
        default=[0.25, 1.0, 4.0, 16.0], min_length=1, description="Dirichlet pseudo-counts per cell tried against the uniform density"
    )
    folds: int = Field(default=5, ge=2, le=50, description="time blocks for the held-out choice when there is one sensor")

    def use_density(self, n_logs: int) -> bool:
        return self.density == "always" or (self.density == "auto" and n_logs > 1)


class RangeNoiseConfig(BaseModel):
    """How sigma_r is estimated from registered scans (defaults suit indoor and park lasers)."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)
    bands: list[float] = Field(default=[0.0, 1.0, 2.0, 4.0, 8.0, 16.0, 32.0], min_length=1, description="lower edges of the range bands [m]")
    query_scans: int = Field(default=1500, ge=1, description="scans (evenly spread) whose returns are scored")
    map_move: float = Field(default=0.3, ge=0.0, description="a scan joins the map after the sensor moved this far [m] ...")
    map_turn: float = Field(default=0.1, ge=0.0, description="... or turned this much [rad] since the last map scan")
    neighbours: int = Field(default=32, ge=3, le=64, description="nearest map returns of other scans that make a local surface")
    min_neighbours: int = Field(default=8, ge=3, description="fewest of them within radius for a residual")
    radius: float = Field(default=0.5, gt=0.0, description="neighbour search radius [m]")
    thinness: float = Field(default=0.3, gt=0.0, le=1.0, description="largest ratio of the scatter's eigenvalues (small: a line)")
    min_incidence: float = Field(default=0.4, gt=0.0, le=1.0, description="smallest |cos| of the angle between beam and surface normal")
    min_samples: int = Field(default=100, ge=1, description="residuals a band needs for its own figure")


class CloudLandmarkConfig(BaseModel):
    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)
    min_scans: int = Field(default=10, ge=1, description="scans a landmark must be detected in")
    merge: float = Field(default=0.3, gt=0.0, description="detections closer than this are the same landmark [m]")
    min_radius: float = Field(default=0.03, gt=0.0)
    max_radius: float = Field(default=1.0, gt=0.0)
    min_points: int = Field(default=4, ge=3, description="returns a detection needs to vote")
    max_spread: float = Field(
        default=0.05, gt=0.0, description="median distance of a cluster's centres from their median [m]: a circle fits the same from every side, a bush does not"
    )


DescriptorName = Literal["fit_error", "radius", "convexity", "points", "mse", "log_mse", "log_radius", "rel_convexity"]


class CalibrateConfig(BaseModel):
    """Everything ``detcal calibrate --config`` accepts; the defaults follow the thesis."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)
    detector: CircleDetectorParams = CircleDetectorParams()
    # log mean-square residual, log radius, convexity / radius: the thesis's three descriptors
    # in coordinates where a Gaussian fits (see detectors.circle.DESCRIPTOR_NAMES); the raw
    # ["fit_error", "radius", "convexity"] remain available
    descriptors: list[DescriptorName] = Field(default=["log_mse", "log_radius", "rel_convexity"], min_length=1)
    confidence: float = Field(default=0.999, gt=0.0, lt=1.0, description="Hotelling ellipsoid confidence (eq. 5.4)")
    gamma: Literal["chi2", "empirical"] = Field(
        default="chi2",
        description="Hotelling threshold: the chi-square quantile (eq. 5.4; exact for Gaussian descriptors) or the empirical "
        "quantile of the true detections' Mahalanobis distances (the stated confidence holds whatever their distribution)",
    )
    gate: float = Field(default=1.0, gt=0.0, description="detection-landmark association gate [m]")
    k_sigma: float = Field(default=3.0, gt=0.0, description="occlusion tolerance of the ray tracer, in sigma_r")
    buffer_samples: int = Field(default=5, ge=1)
    pd: PdFitConfig = PdFitConfig()
    clutter_space: Literal["range_bearing", "xy"] = "range_bearing"
    clutter: ClutterModelConfig = ClutterModelConfig()
    poses: Literal["auto", "reference", "icp"] = Field(default="auto", description="where scan poses come from")
    cloud_landmarks: CloudLandmarkConfig = CloudLandmarkConfig()
    range_noise: RangeNoiseConfig = Field(
        default=RangeNoiseConfig(), description="how sigma_r is estimated when the log does not state it and --range-sigma is not given"
    )

    @field_validator("descriptors")
    @classmethod
    def _distinct(cls, names: list[str]) -> list[str]:
        seen = [n for i, n in enumerate(names) if n in names[:i]]
        if seen:
            raise ValueError(f"{seen[0]} is named twice (a descriptor twice makes the Hotelling covariance singular)")
        return names


Candidate = Literal["range", "additive_logit", "cells_shrunk"]


class PdModelConfig(BaseModel):
    """Candidates and their resolution for a detection-level P_D model."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)
    candidates: list[Candidate] = Field(default=["range", "additive_logit", "cells_shrunk"], min_length=1)
    # no zero clamp: inside the field of view a low P_D is real, not a sign of being out of view (docs/results.md)
    table: PdFitConfig = PdFitConfig(min_count=50, range_bin=0.25, zero_below=0.0)
    grid_range_bin: float = Field(default=0.5, gt=0.0, description="range bin of the range x bearing grids [m]")
    bearing_bins: int = Field(default=8, ge=1, le=90, description="bearing bins across the field of view")
    shrinkage: float = Field(default=20.0, gt=0.0, description="cells_shrunk: pseudo-pairs toward the additive model")
    ridge: float = Field(default=1.0, ge=0.0, description="additive_logit: ridge penalty on the bearing terms (logit units^-2)")
    folds: int = Field(default=5, ge=2, le=50, description="contiguous time blocks for the held-out choice when there is one sensor")


class IdentityAudit(BaseModel):
    """When a landmark identity's detections are taken to belong to another landmark."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)
    enabled: bool = True
    share: float = Field(default=0.9, gt=0.5, le=1.0, description="share of its detections on one other landmark (and at most 1 - share on its own)")
    min_detections: int = Field(default=20, ge=1)


class DetectionCalibConfig(BaseModel):
    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)
    gate: float = Field(default=1.0, gt=0.0, description="true detection: within this of the landmark [m]")
    frame_period: float | None = Field(default=None, gt=0.0, description="camera frame period [s] (default: estimated)")
    fov: float | None = Field(default=None, gt=0.0, description="field of view [rad] (default: from the true detections)")
    range_max: float | None = Field(default=None, gt=0.0, description="[m] (default: from the true detections)")
    quantile: float = Field(default=0.995, gt=0.5, lt=1.0)
    occlusion: bool = Field(
        default=True, description="estimate the landmarks' occluder radius from where a nearer landmark hides them (false: no occlusion)"
    )
    audit: IdentityAudit = IdentityAudit()
    pd: PdModelConfig = PdModelConfig()
    clutter: ClutterModelConfig = ClutterModelConfig()


class SelfCalConfig(BaseModel):
    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)
    gate: float = Field(default=1.5, gt=0.0, description="a detection matches a map feature within this [m]")
    map_weight: float = Field(
        default=0.2, gt=0.0, description="map components of this weight or more are features (a feature missed twice at P_D 0.6 keeps 0.16 of its weight)"
    )
    radius: float | None = Field(
        default=None, gt=0.0, description="trunk radius for the occlusion test when the log has no diameters [m] (None: point landmarks, no occlusion)"
    )
    pd: PdFitConfig = PdFitConfig(min_count=100, range_bin=5.0, zero_below=0.0)


class RfsSimConfig(BaseModel):
    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)
    steps: int = Field(default=1000, ge=60, le=1_000_000)
    dt: float = Field(default=0.1, gt=0.0)
    segments: int = Field(default=20, ge=1)
    still_steps: int = Field(default=50, ge=0, description="steps the vehicle stands still at the start")
    max_dx: float = Field(default=0.30, gt=0.0, description="largest forward speed [m/s]")
    min_dx: float = Field(default=0.10, ge=0.0, description="smallest forward speed [m/s]")
    max_dy: float = Field(default=0.0, ge=0.0, description="largest sideways speed [m/s]")
    max_dtheta: float = Field(default=0.50, ge=0.0, description="largest turn rate [rad/s]")
    var_odometry: float = Field(default=2e-3, ge=0.0, description="odometry noise: variance x dt^2 per step and axis")
    landmarks: int = Field(default=50, ge=1)
    range_min: float = Field(default=0.5, ge=0.0)
    range_max: float = Field(default=2.5, gt=0.0)
    pd: float = Field(default=0.99, gt=0.0, le=1.0)
    clutter_intensity: float = Field(default=1e-4, ge=0.0, description="false alarms per m rad per step")
    var_range: float = Field(default=5e-4, gt=0.0, description="[m^2]")
    var_bearing: float = Field(default=5e-5, gt=0.0, description="[rad^2]")

    @model_validator(mode="after")
    def _order(self) -> RfsSimConfig:
        check_order(self, "min_dx", "max_dx")
        check_order(self, "range_min", "range_max", strict=True)
        lam = self.clutter_intensity * (self.range_max - self.range_min) * 2 * np.pi
        if lam > 10_000:
            raise ValueError(f"clutter_intensity ({self.clutter_intensity}) gives {lam:.3g} false alarms per step; at most 10,000 are simulated")
        return self


#: the 23 landmarks [m], world frame, 1-2 m beside the default circuit
LANDMARKS = [
    [1.6, 1.1], [5.6, -1.8], [9.1, 1.1], [12.6, -1.5], [16.2, 1.7], [20.5, -1.2], [22.5, 2.9], [27.2, 4.7],
    [24.6, 8.6], [27.1, 12.5], [22.5, 14.6], [20.6, 18.0], [16.3, 15.5], [12.6, 18.8], [9.1, 16.1], [5.7, 18.2],
    [2.7, 14.0], [-1.4, 13.3], [0.0, 8.9], [-3.0, 5.7], [1.4, 3.0], [-1.8, 1.0], [8.0, -3.0],
]  # fmt: skip

#: the pre-planned path: from the origin heading east round the circuit, then along its first side again
WAYPOINTS = [[24.0, 0.0], [24.0, 16.0], [0.0, 16.0], [0.0, 0.0], [14.0, 0.0]]


class GlmbPaperConfig(BaseModel):
    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)
    landmarks: list[tuple[float, float]] = Field(default_factory=lambda: [tuple(x) for x in LANDMARKS], min_length=1)
    waypoints: list[tuple[float, float]] = Field(default_factory=lambda: [tuple(x) for x in WAYPOINTS], min_length=1)
    speed: float = Field(default=1.0, gt=0.0, description="[m/s]")
    dt: float = Field(default=0.025, gt=0.0, description="control period [s]")
    observe_every: int = Field(default=8, ge=1, description="control steps per scan")
    wheelbase: float = Field(default=4.0, gt=0.0, description="[m]")
    max_steer: float = Field(default=float(np.radians(30.0)), gt=0.0, lt=np.pi / 2, description="[rad]")
    steer_rate: float = Field(default=float(np.radians(20.0)), gt=0.0, description="[rad/s]")
    switch: float = Field(default=6.0, gt=0.0, description="distance at which the next waypoint is taken [m]")
    arrive: float = Field(default=1.0, gt=0.0, description="the run ends this close to the last waypoint [m]")
    max_steps: int = Field(default=20000, ge=10, le=1_000_000, description="control steps at most")
    sigma_v: float = Field(default=0.1, ge=0.0, description="control noise on the speed [m/s]")
    sigma_steer: float = Field(default=float(np.radians(2.0)), ge=0.0, description="control noise on the steering angle [rad]")
    range_min: float = Field(default=0.0, ge=0.0)
    range_max: float = Field(default=3.0, gt=0.0)
    pd: float = Field(default=0.7, gt=0.0, le=1.0)
    clutter: float = Field(default=5.0, ge=0.0, le=10_000.0, description="false alarms per scan (Poisson mean)")
    sigma_range: float = Field(default=0.3, gt=0.0, description="[m]")
    sigma_bearing: float = Field(default=float(np.radians(2.0)), gt=0.0, description="[rad]")

    @model_validator(mode="after")
    def _ranges(self) -> GlmbPaperConfig:
        if self.range_min >= self.range_max:
            raise ValueError("range_min must be below range_max")
        if len(self.waypoints) == 1 and float(np.hypot(*self.waypoints[0])) < self.arrive:
            raise ValueError(
                f"waypoints: the only waypoint is within arrive ({self.arrive} m) of the start (0, 0): the path would have no step"
            )
        return self


class TwoStageConfig(BaseModel):
    """The two-stage scenario of Li & Yang (Sensors 2022): its settings (``calib.sim.two_stage`` says what each does)."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)
    path: Literal["serpentine", "spiral"] = Field(default="serpentine", description="the initial path (Fig. 4a / 4b)")
    start: tuple[float, float] = Field(default=(-800.0, -800.0), description="the path's start [m] (sec. 4)")
    end: tuple[float, float] = Field(default=(800.0, 800.0), description="the scene's far corner [m] (sec. 4); the serpentine ends there")
    lanes: int = Field(
        default=7, ge=2, le=100, description="straight lanes of the serpentine (odd: it ends at end); the spiral's rings lie the scene / lanes apart"
    )
    detection_radius: float = Field(default=150.0, gt=0.0, description="[m] (Table 1: 50, 100, 150; 150 with ten features in Figs. 6a, 7a)")
    safety_distance: float = Field(default=50.0, gt=0.0, description="sigma_min [m]: the event trigger and the avoidance radius (eqs. 28-30)")
    spline_spacing: float = Field(default=25.0, gt=0.0, description="[m] between the B-spline's control points")
    steps: int = Field(default=100, ge=2, le=100_000, description="time steps (sec. 4: 100)")
    dt: float = Field(default=1.0, gt=0.0, description="T [s] (sec. 4)")
    speed: float | None = Field(default=None, gt=0.0, description="[m/s] on straight parts (Table 1: 2); null: the whole path in the steps")
    arc_speed_ratio: float = Field(default=0.5, gt=0.0, le=1.0, description="speed on arcs / speed on straight parts (Table 1: 1 / 2)")
    features: int = Field(default=10, ge=1, le=10_000, description="feature points (sec. 4)")
    on_path: int = Field(default=3, ge=0, description="of them placed on the initial path (obstacles)")
    moving: bool = Field(default=False, description="the feature points move (constant velocity with process noise)")
    feature_speed: float = Field(default=1.0, ge=0.0, description="[m/s] each moving feature's initial speed, random direction")
    process_noise: float = Field(default=0.5, ge=0.0, description="[m/s^2] sigma of Q = sigma^2 B B^T (sec. 4: 0.5)")
    pd: float = Field(default=0.98, gt=0.0, le=1.0, description="P_D inside the detection radius (sec. 4)")
    clutter: float = Field(default=20.0, ge=0.0, le=10_000.0, description="false alarms per scan (sec. 4: 20)")
    clutter_area: Literal["square", "disc"] = Field(default="square", description="clutter uniform over S (the reports inside the disc), or over the disc")
    clutter_half_width: float = Field(default=1000.0, gt=0.0, description="[m] S = [-w, w]^2 (sec. 4: 1000)")
    sigma_range: float = Field(default=10.0, gt=0.0, description="[m]")
    sigma_bearing: float = Field(default=float(np.radians(2.0)), gt=0.0, description="[rad]")
    odometry_sigma: float = Field(default=1.0, ge=0.0, description="[m] noise of each step's odometry along each axis")
    odometry_heading_sigma: float = Field(default=float(np.radians(0.5)), ge=0.0, description="[rad] noise of each step's heading change")

    @model_validator(mode="after")
    def _check(self) -> TwoStageConfig:
        check_order(self, "on_path", "features")
        lo, hi = np.asarray(self.start), np.asarray(self.end)
        if not np.all(hi - lo > 0):
            raise ValueError(f"end {self.end} must lie above and to the right of start {self.start}")
        spacing = (hi[1] - lo[1]) / (self.lanes - 1)
        if self.path == "serpentine" and self.safety_distance >= spacing / 2:
            raise ValueError(f"safety_distance ({self.safety_distance}) must be below half the lane spacing ({spacing / 2:g} m)")
        return self
