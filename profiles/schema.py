"""Pydantic models of the parts of a detector profile.

Every model forbids unknown keys and bounds its fields; defaults work. The
runtime (``detectors.model``) and the calibration (``calib``) both read these.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, model_serializer, model_validator

from profiles.errors import DataError
from profiles.override import updated
from profiles.registry import Registry, literal_field
from profiles.units import WRITTEN_REL_TOL


class Strict(BaseModel):
    model_config = ConfigDict(extra="forbid")


class Mount(Strict):
    """Sensor pose in the vehicle frame: (x [m] forward, y [m] left, theta [rad])."""

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)
    x: float = 0.0
    y: float = 0.0
    theta: float = 0.0


class Vehicle(Strict):
    """Vehicle geometry needed by some motion models (Ackermann).

    Origin of the vehicle frame: the rear-axle centre. ``encoder_offset`` is the
    lateral distance of the speed encoder (rear left wheel) from that centre.
    """

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)
    wheelbase: float = Field(gt=0.0)
    encoder_offset: float = Field(default=0.0, ge=0.0)


class LidarGeometry(Strict):
    """Beam layout of a spinning multi-beam lidar (kind ``lidar3d``, e.g. a Velodyne HDL-64E).

    One ring per vertical angle, columns every ``azimuth_increment_deg`` around the
    full circle; ``height`` is the sensor's height above the vehicle frame's origin
    (the ground under the vehicle), so planes in the sensor frame can be placed in 3D.
    """

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)
    vertical_angles_deg: list[float] = Field(min_length=1, description="elevation of each ring [deg], sensor frame")
    azimuth_increment_deg: float = Field(gt=0.0, le=10.0, description="azimuth step between columns [deg]")
    height: float = Field(default=0.0, description="sensor height above the vehicle frame origin [m]")


#: Most beams a 2D laser scan may have: real scanners give a few thousand at most (a SICK LMS 361, a Hokuyo UTM 1081,
#: 0.1-degree scanners 3600); a larger count is a damaged or mistyped file, and would be allocated per scan.
MAX_BEAMS = 100_000

#: Slack on a beam fan's full circle [rad] (the rounding of angle_increment over the beams).
_TURN_SLACK = 1e-6


def check_fan(n_beams: int | None, angle_min: float | None, angle_increment: float | None) -> None:
    """Refuse a beam fan no laser has: a start beyond a full turn, no step between beams, beams over more than a turn."""
    if angle_min is not None and abs(angle_min) > 2 * np.pi:
        raise ValueError(f"angle_min ({angle_min:g} rad) is beyond a full turn (|angle_min| <= 2 pi)")
    if angle_increment is None or n_beams is None or n_beams < 2:
        return
    if angle_increment == 0.0:
        raise ValueError(f"angle_increment is 0: the {n_beams} beams would all point the same way")
    span = abs(angle_increment) * (n_beams - 1)
    if span > 2 * np.pi + _TURN_SLACK:
        raise ValueError(f"{n_beams} beams every {angle_increment:g} rad span {span:.4g} rad, more than a full turn (2 pi)")


class BeamGeometry(Strict):
    """One beam layout of a 2D laser: beam ``i`` points at ``angle_min + i * angle_increment`` (sensor frame, radians)."""

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)
    n_beams: int = Field(ge=1, le=MAX_BEAMS)
    angle_min: float = Field(allow_inf_nan=False)
    angle_increment: float = Field(allow_inf_nan=False)

    @model_validator(mode="after")
    def _fan(self) -> BeamGeometry:
        check_fan(self.n_beams, self.angle_min, self.angle_increment)
        return self

    def angles(self) -> np.ndarray:
        """(n_beams,) float64 radians, sensor frame."""
        return self.angle_min + self.angle_increment * np.arange(self.n_beams, dtype=np.float64)

    def span(self) -> tuple[float, float]:
        """(lowest, highest) beam angle [rad]."""
        end = self.angle_min + self.angle_increment * (self.n_beams - 1)
        return min(self.angle_min, end), max(self.angle_min, end)


class SensorModel(Strict):
    """What the sensor is and how it is mounted.

    For a 2D laser, beam ``i`` points at ``angle_min + i * angle_increment``
    (sensor frame, radians). A laser whose scans do not all share one beam
    layout (interlaced scanners that alternate 180 and 181 beams or start
    angles; CARMEN ``ROBOTLASER1`` lines that carry their own geometry) lists
    its layouts in ``geometries`` instead; ``n_beams`` is then the widest
    count (the width of the scan arrays) and each scan says which layout it
    used (:meth:`detectors.sensor_log.SensorLog.scan_angles`). Detection-only
    sensors (a camera, a vendor's tree extractor) give ``fov`` instead of a
    beam geometry. A 3D lidar gives its ring and column layout in ``lidar``
    (written only when present).
    """

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)
    kind: Literal["laser2d", "lidar3d", "camera", "detector"] = "laser2d"
    n_beams: int | None = Field(default=None, ge=1, le=MAX_BEAMS)
    angle_min: float | None = Field(default=None, allow_inf_nan=False)
    angle_increment: float | None = Field(default=None, allow_inf_nan=False)
    range_min: float = Field(default=0.0, ge=0.0, allow_inf_nan=False)
    range_max: float | None = Field(default=None, gt=0.0, allow_inf_nan=False)
    range_sigma: float | None = Field(default=None, ge=0.0, allow_inf_nan=False)
    fov: float | None = Field(default=None, gt=0.0, le=2 * np.pi + 1e-9)
    mount: Mount = Mount()
    lidar: LidarGeometry | None = None
    geometries: tuple[BeamGeometry, ...] | None = Field(
        default=None, description="beam layouts of a laser whose scans differ (written only when there are several)"
    )

    @model_validator(mode="after")
    def _geometries(self) -> SensorModel:
        if self.range_max is not None and self.range_min >= self.range_max:
            raise ValueError(f"range_min ({self.range_min:g} m) must be below range_max ({self.range_max:g} m)")
        check_fan(self.n_beams, self.angle_min, self.angle_increment)
        if self.geometries is None:
            return self
        if len(self.geometries) < 2:
            raise ValueError("geometries lists two or more beam layouts (a single one goes in n_beams, angle_min, angle_increment)")
        if self.angle_min is not None or self.angle_increment is not None:
            raise ValueError("with geometries, the angles are per scan: leave angle_min and angle_increment unset")
        width = max(g.n_beams for g in self.geometries)
        if self.n_beams != width:
            raise ValueError(f"with geometries, n_beams is the widest layout's count ({width}), got {self.n_beams}")
        return self

    @model_serializer(mode="wrap")
    def _omit_single_geometry(self, handler):
        data = handler(self)
        if isinstance(data, dict):
            for key in ("geometries", "lidar"):  # absent rather than null: logs and profiles without them keep their bytes
                if data.get(key, 0) is None:
                    data.pop(key)
        return data

    def angles(self) -> np.ndarray:
        """Beam angles in the sensor frame, (B,) float64 radians (a laser with one beam layout)."""
        if self.geometries is not None:
            raise DataError(
                f"the scans of this laser use {len(self.geometries)} beam geometries; "
                "take each scan's angles from the log (SensorLog.scan_angles)"
            )
        if self.n_beams is None or self.angle_min is None or self.angle_increment is None:
            raise DataError(f"sensor model of kind {self.kind!r} has no beam geometry")
        return self.angle_min + self.angle_increment * np.arange(self.n_beams, dtype=np.float64)

    def layouts(self) -> tuple[BeamGeometry, ...]:
        """Every beam layout of the laser (one for most lasers; none without a beam geometry)."""
        if self.geometries is not None:
            return self.geometries
        if self.n_beams is None or self.angle_min is None or self.angle_increment is None:
            return ()
        return (BeamGeometry(n_beams=self.n_beams, angle_min=self.angle_min, angle_increment=self.angle_increment),)

    def turned(self, yaw: float) -> SensorModel:
        """This sensor with its mount turned by ``yaw`` [rad] (a mount-yaw correction, ``SlamConfig.mount_yaw``);
        itself when ``yaw`` is 0."""
        if not yaw:
            return self
        return updated(self, {"mount.theta": self.mount.theta + yaw})

    def angle_span(self) -> tuple[float, float] | None:
        """(lowest, highest) beam angle [rad] over every layout; None without a beam geometry."""
        spans = [g.span() for g in self.layouts()]
        if not spans:
            return None
        return min(a for a, _ in spans), max(b for _, b in spans)

    @property
    def field_of_view(self) -> float | None:
        """Angular width [rad] covered by the beams (or ``fov``)."""
        span = self.angle_span()
        if span is not None:
            return span[1] - span[0]
        return self.fov


class CircleDetectorParams(Strict):
    """Parameters of the circle detector (thesis sec. 5.3)."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)  # parameters a config file sets too
    jump: float = Field(default=0.5, gt=0.0, description="distance between consecutive returns that breaks a cluster [m]")
    min_points: int = Field(default=3, ge=3, description="fewest returns in a cluster (a circle needs 3)")
    max_points: int | None = Field(default=None, ge=3, description="most returns in a cluster (None: no limit)")
    max_radius: float | None = Field(default=None, gt=0.0, description="drop fitted circles larger than this [m]")
    lm_iterations: int = Field(default=30, ge=1, le=500, description="Levenberg-Marquardt iterations at most")
    line_radius: float = Field(
        default=100.0, gt=0.0, description="LM stops refining a circle whose radius exceeds this [m]: the cluster is a straight line"
    )

    @model_validator(mode="after")
    def _points(self) -> CircleDetectorParams:
        if self.max_points is not None and self.max_points < self.min_points:
            raise ValueError(f"max_points ({self.max_points}) is below min_points ({self.min_points}): no cluster could be kept")
        return self


class HotellingParams(Strict):
    """Hotelling ellipsoid of true detections' descriptors (thesis eq. 5.4).

    A detection with descriptor vector x is kept when
    (x - mean)^T covariance^-1 (x - mean) <= gamma.
    """

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)  # parameters a config file sets too
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
        w = np.linalg.eigvalsh(cov)
        if w.min() <= 0:
            raise ValueError("covariance is not positive definite")
        from profiles.plausibility import MAX_CONDITION  # (the bound and why: profiles.plausibility)

        if w.max() / w.min() > MAX_CONDITION:
            raise ValueError(
                f"covariance has condition number {w.max() / w.min():.3g}, beyond {MAX_CONDITION:g}: written to six digits, "
                "its inverse (the gate) keeps no correct digit"
            )
        return self


class Selection(Strict):
    """How a model was chosen among candidates: by the mean held-out log-likelihood.

    Each candidate was fitted on all folds but one and scored on the one left
    out; ``loglik`` is the mean log-likelihood per held-out item (pair for P_D,
    false alarm for the clutter density), in the order of ``candidates``.
    """

    criterion: Literal["heldout_loglik"] = "heldout_loglik"
    folds: str = Field(description="what the folds were, e.g. 'sensors (4)' or 'time blocks (5)'")
    candidates: list[str] = Field(min_length=1)
    loglik: list[float]
    items: int = Field(ge=0, description="held-out items scored (summed over folds)")
    chosen: str

    @model_validator(mode="after")
    def _consistent(self) -> Selection:
        if len(self.loglik) != len(self.candidates):
            raise ValueError(f"loglik has {len(self.loglik)} entries for {len(self.candidates)} candidates")
        if self.chosen not in self.candidates:
            raise ValueError(f"chosen {self.chosen!r} is not one of the candidates")
        return self


def _shape(v) -> tuple[int, ...]:
    """Shape of a list or a list of lists (numpy refuses a ragged one with a ValueError)."""
    return np.asarray(v, dtype=np.float64).shape


@dataclass(frozen=True)
class Covariate:
    """What a P_D covariate is: what the profile checks and how a filter finds the covariate of a map feature.

    ``from_measurement``: the covariate of a feature predicted at measurement z (..., dz), (...) for a 1-D table or
    (..., 2) for a grid; None when it is not a function of the measurement (``ray_traced``: it needs the current
    scan, n_p). ``grid``: the table is a grid (``edges`` x ``bearing_edges``). ``integer``: one bin per count.
    ``detectors``: the detector kinds whose profiles may use it (None: any), ``refusal`` the message for others.
    ``sensor_needs``: the sensor fields it needs. ``schema``: the first profile schema that can say it.
    """

    from_measurement: Callable[[np.ndarray], np.ndarray] | None = None
    ray_traced: bool = False
    grid: bool = False
    integer: bool = False
    detectors: tuple[str, ...] | None = None
    refusal: str = ""
    sensor_needs: tuple[str, ...] = ()
    schema: int = 1


#: The P_D covariates a profile's table may be over (``pd.covariate``); the table's field follows it.
PD_COVARIATES: Registry[Covariate] = Registry("P_D covariate")
PD_COVARIATES.add("n_p", Covariate(
    ray_traced=True, integer=True, detectors=("circle2d",), refusal="pd.covariate n_p needs a circle2d detector (ray tracing of its scans)",
    sensor_needs=("n_beams", "range_sigma"),
))  # fmt: skip
PD_COVARIATES.add("range", Covariate(from_measurement=lambda z: z[..., 0]))
PD_COVARIATES.add("range_bearing", Covariate(
    from_measurement=lambda z: z, grid=True, schema=2, detectors=("external",),
    refusal="a range_bearing P_D table is for detection-level sensors (external detector)",
))  # fmt: skip
PD_COVARIATES.add("points", Covariate(detectors=("plane3d",)))  # (planes: the profile's plane checks say why)


class PdTable(Strict):
    """P_D against a covariate, piecewise constant (thesis eq. 6.2, Table 6.1).

    One covariate (``n_p`` or ``range``): bin i covers ``edges[i] <= v < edges[i+1]``;
    a value at or beyond the last edge uses the last bin, a value below the first
    edge has P_D = 0. For ``n_p`` the edges are integers, one bin per count.

    ``range_bearing`` (schema 2): a grid over range (``edges``, rows) and bearing
    (``bearing_edges`` [rad, sensor frame], columns); ``pd``, ``counts``, ... are
    lists of rows. Range beyond the last edge uses the last row; a bearing outside
    the bearing edges is outside the field of view (P_D = 0). ``model`` says how the
    cell values were estimated: ``binned`` (each cell its own rate),
    ``additive_logit`` (logit P_D = a(range bin) + b(bearing bin), a logistic
    regression: few parameters, no cell left empty) or ``cells_shrunk`` (each
    cell's rate shrunk toward the additive model with ``shrinkage`` pseudo-pairs)
    or ``partial_pooling`` (one sensor's table: the pooled table of several
    sensors shifted by the sensor's logit offset, its cells shrunk toward that
    with ``shrinkage`` = m pseudo-pairs; see ``sensors``).

    ``between_sensor_sd`` (pooled profiles): how far the sensors' own P_D spread
    about the pooled one in each bin, beyond binomial noise (beta-binomial).

    ``effective_counts`` (schema 2): each bin's ``counts`` divided by its design
    effect -- the outcomes of one landmark go together (its size, its surface,
    where it stands), so a bin's pairs are worth fewer independent trials. This
    is how well the profile knows each P_D, and what validation
    (:mod:`calib.drift`) allows for the profile's own sampling error.
    """

    covariate: str = "n_p"  # (one of PD_COVARIATES: set below)
    edges: list[float] = Field(min_length=2)
    bearing_edges: list[float] | None = Field(default=None, min_length=2)
    pd: list[float] | list[list[float]]
    counts: list[int] | list[list[int]] | None = None
    detections: list[int] | list[list[int]] | None = None
    wilson_low: list[float] | list[list[float]] | None = None
    wilson_high: list[float] | list[list[float]] | None = None
    clamping: str = Field(default="none", description="how the raw estimates were clamped")
    model: Literal["binned", "additive_logit", "cells_shrunk", "partial_pooling"] = "binned"
    shrinkage: float | None = Field(
        default=None, gt=0.0, description="pseudo-pairs toward the additive model (cells_shrunk) or the shifted pooled table (partial_pooling; None: cells fully pooled)"
    )
    between_sensor_sd: list[float] | list[list[float]] | None = None
    selection: Selection | None = None
    effective_counts: list[float] | list[list[float]] | None = Field(
        default=None, description="counts / design effect of the landmarks' correlated outcomes (independent trials the P_D is worth)"
    )

    @model_validator(mode="after")
    def _shapes(self) -> PdTable:
        e = np.asarray(self.edges)
        if np.any(np.diff(e) <= 0):
            raise ValueError("edges must increase strictly")
        two_d = self.two_d
        if two_d != (self.bearing_edges is not None):
            grids = " or ".join(n for n, c in PD_COVARIATES.items() if c.grid)
            raise ValueError(f"bearing_edges are given exactly when the covariate is {grids}")
        shape: tuple[int, ...] = (e.size - 1,)
        if two_d:
            be = np.asarray(self.bearing_edges)
            if np.any(np.diff(be) <= 0):
                raise ValueError("bearing_edges must increase strictly")
            shape = (e.size - 1, be.size - 1)
        for name in ("pd", "counts", "detections", "wilson_low", "wilson_high", "between_sensor_sd", "effective_counts"):
            v = getattr(self, name)
            if v is None:
                continue
            got = _shape(v)
            if got != shape:
                if len(shape) == 1 and len(got) == 1:
                    raise ValueError(f"{name} has {got[0]} entries for {shape[0]} bins")
                raise ValueError(f"{name} has shape {got} for a {'x'.join(map(str, shape))} table")
        pd = np.asarray(self.pd, dtype=np.float64)
        if not np.all((pd >= 0.0) & (pd <= 1.0)):
            raise ValueError("pd values must lie in [0, 1]")
        if self.model == "cells_shrunk" and self.shrinkage is None:
            raise ValueError("a cells_shrunk table needs its shrinkage")
        if self.model not in ("cells_shrunk", "partial_pooling") and self.shrinkage is not None:
            raise ValueError("shrinkage belongs to cells_shrunk and partial_pooling tables")
        return self

    @property
    def two_d(self) -> bool:
        return PD_COVARIATES.get(self.covariate).grid

    def lookup(self, v: np.ndarray) -> np.ndarray:
        """P_D for covariate values ``v`` (any shape) of a one-covariate table."""
        if self.two_d:
            raise ValueError(f"a {self.covariate} table needs range and bearing: use lookup_rb")
        e = np.asarray(self.edges)
        pd = np.asarray(self.pd)
        i = np.clip(np.searchsorted(e, v, side="right") - 1, 0, pd.size - 1)
        return np.where(np.asarray(v) < e[0], 0.0, pd[i])

    def lookup_rb(self, r: np.ndarray, b: np.ndarray) -> np.ndarray:
        """P_D at range ``r`` [m] and bearing ``b`` [rad, sensor frame] (broadcast shapes).

        A one-covariate range table ignores the bearing.
        """
        r = np.asarray(r, dtype=np.float64)
        if not self.two_d:
            of_z = PD_COVARIATES.get(self.covariate).from_measurement
            if of_z is None:
                raise ValueError(f"a {self.covariate} table cannot be looked up by range and bearing")
            z = np.stack(np.broadcast_arrays(r, np.asarray(b, dtype=np.float64)), axis=-1)
            return self.lookup(of_z(z))
        b = np.asarray(b, dtype=np.float64)
        e, be = np.asarray(self.edges), np.asarray(self.bearing_edges)
        pd = np.asarray(self.pd)
        i = np.clip(np.searchsorted(e, r, side="right") - 1, 0, pd.shape[0] - 1)
        j = np.clip(np.searchsorted(be, b, side="right") - 1, 0, pd.shape[1] - 1)
        inside = (r >= e[0]) & (b >= be[0]) & (b <= be[-1])
        return np.where(inside, pd[i, j], 0.0)


def _covariates() -> None:
    literal_field(PdTable, "covariate", PD_COVARIATES.names())


_covariates()
PD_COVARIATES.on_change(_covariates)


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


class CountTest(Strict):
    """A test on per-frame counts: statistic, degrees of freedom (None where not chi-square) and p-value."""

    test: str
    statistic: float
    dof: int | None = None
    p_value: float = Field(ge=0.0, le=1.0)


class ClutterDensity(Strict):
    """Where false alarms fall in the measurement space: a density over (range, bearing).

    Piecewise constant over the grid ``range_edges`` [m] x ``bearing_edges`` [rad,
    sensor frame]; ``density`` [1 / (m rad)] integrates to 1 over the grid and is 0
    outside it. Estimated from the calibration's false alarms with ``smoothing``
    pseudo-counts spread uniformly (a Dirichlet prior): 0 is the raw histogram, a
    large value approaches the uniform density of the thesis (sec. 4.2).
    """

    range_edges: list[float] = Field(min_length=2)
    bearing_edges: list[float] = Field(min_length=2)
    density: list[list[float]]
    counts: list[list[int]] | None = None
    smoothing: float = Field(ge=0.0)
    selection: Selection | None = None

    @model_validator(mode="after")
    def _shape(self) -> ClutterDensity:
        re_, be = np.asarray(self.range_edges), np.asarray(self.bearing_edges)
        if np.any(np.diff(re_) <= 0) or np.any(np.diff(be) <= 0):
            raise ValueError("range_edges and bearing_edges must increase strictly")
        want = (re_.size - 1, be.size - 1)
        for name in ("density", "counts"):
            v = getattr(self, name)
            if v is not None and _shape(v) != want:
                raise ValueError(f"{name} has shape {_shape(v)} for a {want[0]}x{want[1]} grid")
        d = np.asarray(self.density, dtype=np.float64)
        if np.any(d < 0):
            raise ValueError("density values must be >= 0")
        mass = float((d * np.diff(re_)[:, None] * np.diff(be)[None, :]).sum())
        if not np.isclose(mass, 1.0, rtol=WRITTEN_REL_TOL):  # a written density is rounded (profiles.units)
            raise ValueError(f"density integrates to {mass:.9g} over the grid, not 1")
        return self

    def at(self, r: np.ndarray, b: np.ndarray) -> np.ndarray:
        """Density [1 / (m rad)] at range ``r`` and bearing ``b`` (broadcast shapes); 0 outside the grid."""
        r, b = np.asarray(r, dtype=np.float64), np.asarray(b, dtype=np.float64)
        re_, be = np.asarray(self.range_edges), np.asarray(self.bearing_edges)
        d = np.asarray(self.density)
        i = np.clip(np.searchsorted(re_, r, side="right") - 1, 0, d.shape[0] - 1)
        j = np.clip(np.searchsorted(be, b, side="right") - 1, 0, d.shape[1] - 1)
        inside = (r >= re_[0]) & (r <= re_[-1]) & (b >= be[0]) & (b <= be[-1])
        return np.where(inside, d[i, j], 0.0)


class ClutterParams(Strict):
    """Clutter: ``rate`` false alarms per frame, spread over the measurement space.

    space: ``range_bearing`` (volume in m*rad), ``xy`` (area in m^2) or ``plane``
    (the chart of landmark planes: azimuth x elevation x offset, in rad^2 m). ``kappa`` is
    the mean intensity rate / volume (uniform, thesis sec. 4.2); with a ``density``
    (schema 2) the intensity is rate x density(range, bearing) instead.

    Counts per frame (schema 2): ``count_model`` ``poisson`` (the thesis; its
    Pearson test is ``chi2``/``dof``/``p_value``) or ``negative_binomial`` (a
    Poisson-gamma mixture with mean ``rate`` and variance rate + rate^2 / ``size``),
    chosen when ``dispersion_test`` (likelihood ratio of the negative binomial
    against the Poisson) rejects the Poisson at 0.05; ``nb_gof`` is the negative
    binomial's Pearson test. A PHD filter uses only the intensity (the mean); the
    count model is what a cardinality-aware filter (CPHD) and the validation use.

    ``frames`` and ``rate_se`` (schema 2): how many frames the rate was measured
    on and its standard error from batch means (false alarms of one clutter
    source come in runs of frames, so the naive sqrt(variance / frames) is far
    too small); validation (:mod:`calib.drift`) allows for it.
    """

    rate: float = Field(ge=0.0, description="lambda: mean false alarms per scan")
    space: Literal["range_bearing", "xy", "plane"] = "range_bearing"
    volume: float = Field(gt=0.0, description="size of the field of view in the measurement space")
    kappa: float | None = Field(default=None, ge=0.0, description="clutter intensity rate / volume (filled in when omitted)")
    chi2: float | None = None
    dof: int | None = None
    p_value: float | None = Field(default=None, ge=0.0, le=1.0)
    dispersion: float | None = Field(default=None, ge=0.0, description="variance / mean of the per-scan counts")
    count_model: Literal["poisson", "negative_binomial"] = "poisson"
    size: float | None = Field(default=None, gt=0.0, description="negative binomial shape r (variance = rate + rate^2 / r)")
    dispersion_test: CountTest | None = None
    nb_gof: CountTest | None = None
    density: ClutterDensity | None = None
    frames: int | None = Field(default=None, ge=0, description="frames the rate was measured on")
    rate_se: float | None = Field(default=None, ge=0.0, description="standard error of the rate (batch means) [false alarms per frame]")

    @model_validator(mode="after")
    def _kappa(self) -> ClutterParams:
        k = self.rate / self.volume
        if self.kappa is None:
            self.kappa = k
        elif not np.isclose(self.kappa, k, rtol=WRITTEN_REL_TOL, atol=0.0):  # written rate and kappa are rounded (profiles.units)
            raise ValueError(f"kappa {self.kappa} is not rate / volume = {k}")
        if (self.count_model == "negative_binomial") != (self.size is not None):
            raise ValueError("size is given exactly when the count model is negative_binomial")
        if self.density is not None and self.space != "range_bearing":
            raise ValueError("a clutter density is over range and bearing: space must be range_bearing")
        return self

    def count_pmf(self, k: np.ndarray) -> np.ndarray:
        """P(k false alarms in a frame) under the count model, k (...) non-negative integers."""
        from scipy.stats import nbinom, poisson

        k = np.asarray(k)
        if self.count_model == "poisson":
            return poisson.pmf(k, self.rate)
        r = float(self.size)
        return nbinom.pmf(k, r, r / (r + self.rate))

    def count_sf(self, k: np.ndarray) -> np.ndarray:
        """P(more than k false alarms in a frame)."""
        from scipy.stats import nbinom, poisson

        if self.count_model == "poisson":
            return poisson.sf(k, self.rate)
        r = float(self.size)
        return nbinom.sf(k, r, r / (r + self.rate))

    @property
    def count_variance(self) -> float:
        """Variance of the count per frame under the count model."""
        if self.count_model == "poisson":
            return self.rate
        return self.rate + self.rate**2 / float(self.size)
