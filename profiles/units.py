"""The unit of every quantity a detector profile holds, and how precisely it is written.

One table, :data:`UNITS`, keyed ``"<model class>.<field>"``: the profile writer
(:func:`profiles.store.dump_profile`) puts the unit in a comment after each
value, and the schema reference of the documentation prints it beside each
field. ``1`` is a dimensionless ratio, ``count`` a number of things, and a unit
that depends on another field (the clutter space) is a function of the
section's data. A test walks every model of a profile and requires an entry
for each numeric field.

Precision: the fitted quantities (P_D, Wilson bounds, Hotelling mean and
covariance, clutter rate and tests, noise, ...) are written with
:data:`SIGNIFICANT` significant digits. A calibration's estimates rest on at
most about 10^6 samples, so their relative standard errors are at least
1/sqrt(10^6) = 1e-3; six digits (a relative rounding error of at most 5e-6)
keep every written figure 200 times finer than the noise of the fit, so
rounding never changes what a filter does, while the derived relations
(``kappa = rate / volume``, a density integrating to 1, a positive-definite
covariance) still hold within the :data:`WRITTEN_REL_TOL` the validators
allow. Fewer digits would be nearer the standard error of the best-measured
bins but would make those relations depend on the rounding. What a person or a
log header gave -- the sensor's geometry, the bin edges, the recorded
parameters -- is written exactly as given.
"""

from __future__ import annotations

import math
import typing
from collections.abc import Callable

from pydantic import BaseModel

#: significant digits of a fitted float in a written profile (see the module text for why six)
SIGNIFICANT = 6
#: relative tolerance of relations between written (rounded) figures: three roundings of 5e-6 each, with margin
WRITTEN_REL_TOL = 5e-5

_CLUTTER_VOLUME = {"range_bearing": "m rad", "xy": "m^2", "plane": "rad^2 m"}


def _volume(section: dict) -> str:
    return _CLUTTER_VOLUME.get(section.get("space"), "of the clutter space")


def _kappa(section: dict) -> str:
    return f"false alarms / scan / ({_volume(section)})"


def _pd_bins(section: dict) -> str:
    return {"n_p": "points", "range": "m", "range_bearing": "m", "points": "points"}.get(section.get("covariate"), "of the covariate")


Unit = str | Callable[[dict], str]

UNITS: dict[str, Unit] = {
    # sensor and its mount (sensor frame, vehicle frame)
    "Mount.x": "m", "Mount.y": "m", "Mount.theta": "rad",
    "Vehicle.wheelbase": "m", "Vehicle.encoder_offset": "m",
    "LidarGeometry.vertical_angles_deg": "deg", "LidarGeometry.azimuth_increment_deg": "deg", "LidarGeometry.height": "m",
    "BeamGeometry.n_beams": "count", "BeamGeometry.angle_min": "rad", "BeamGeometry.angle_increment": "rad",
    "SensorModel.n_beams": "count", "SensorModel.angle_min": "rad", "SensorModel.angle_increment": "rad",
    "SensorModel.range_min": "m", "SensorModel.range_max": "m", "SensorModel.range_sigma": "m", "SensorModel.fov": "rad",
    # detectors
    "CircleDetectorParams.jump": "m", "CircleDetectorParams.min_points": "count", "CircleDetectorParams.max_points": "count",
    "CircleDetectorParams.max_radius": "m", "CircleDetectorParams.lm_iterations": "count", "CircleDetectorParams.line_radius": "m",
    "PlaneDetectorParams.cell_azimuth_deg": "deg", "PlaneDetectorParams.cell_elevation_deg": "deg", "PlaneDetectorParams.cell_range_ratio": "1",
    "PlaneDetectorParams.range_min": "m", "PlaneDetectorParams.min_cell_size": "m", "PlaneDetectorParams.min_cell_points": "count",
    "PlaneDetectorParams.range_sigma": "m", "PlaneDetectorParams.merge_angle_deg": "deg", "PlaneDetectorParams.merge_offset": "m",
    "PlaneDetectorParams.grow_steps": "count", "PlaneDetectorParams.grow_share": "1", "PlaneDetectorParams.coplanar_angle_deg": "deg",
    "PlaneDetectorParams.coplanar_offset": "m", "PlaneDetectorParams.msse_t": "scale units", "PlaneDetectorParams.msse_min_fraction": "1",
    "PlaneDetectorParams.refits": "count", "PlaneDetectorParams.min_points": "count", "PlaneDetectorParams.max_sigma": "m",
    "DetectorSpec.k_sigma": "sigma_r", "DetectorSpec.buffer_samples": "count", "DetectorSpec.association_gate": "m",
    "DetectorSpec.occluder_radius": "m",
    # Hotelling gate (eq. 5.4) and descriptor likelihoods (eq. 5.6)
    "HotellingModel.mean": "descriptor units (names)", "HotellingModel.covariance": "descriptor units squared",
    "HotellingModel.confidence": "probability", "HotellingModel.gamma": "squared Mahalanobis distance",
    "HotellingModel.auc_hotelling": "1", "HotellingModel.auc_fisher": "1", "HotellingModel.samples": "true detections",
    "HotellingModel.coverage": "1",
    "DescriptorLikelihoods.gaussian_mass": "probability", "DescriptorLikelihoods.ellipsoid_volume": "descriptor units ^ dimension",
    # P_D table (eq. 6.2)
    "PdTable.edges": _pd_bins, "PdTable.bearing_edges": "rad", "PdTable.pd": "probability", "PdTable.counts": "feature-scan pairs",
    "PdTable.detections": "feature-scan pairs detected", "PdTable.wilson_low": "probability", "PdTable.wilson_high": "probability",
    "PdTable.shrinkage": "pseudo-pairs", "PdTable.between_sensor_sd": "probability",
    "PdTable.effective_counts": "independent trials (pairs / design effect)",
    "Selection.loglik": "nats / held-out item", "Selection.items": "count",
    "PdGrid.points_edges": "points", "PdGrid.angle_edges_deg": "deg", "PdGrid.pd": "probability", "PdGrid.counts": "feature-scan pairs",
    "PdGrid.detections": "feature-scan pairs detected",
    # clutter (sec. 4.2)
    "ClutterParams.rate": "false alarms / scan", "ClutterParams.volume": _volume, "ClutterParams.kappa": _kappa,
    "ClutterParams.chi2": "1", "ClutterParams.dof": "count", "ClutterParams.p_value": "probability", "ClutterParams.dispersion": "1",
    "ClutterParams.size": "1", "ClutterParams.frames": "count", "ClutterParams.rate_se": "false alarms / scan",
    "CountTest.statistic": "1", "CountTest.dof": "count", "CountTest.p_value": "probability",
    "ClutterDensity.range_edges": "m", "ClutterDensity.bearing_edges": "rad", "ClutterDensity.density": "1 / (m rad)",
    "ClutterDensity.counts": "false alarms", "ClutterDensity.smoothing": "pseudo-counts",
    # measurement noise
    "MeasurementNoise.range_sigma": "m", "MeasurementNoise.bearing_sigma": "rad", "MeasurementNoise.range_bias": "m",
    "MeasurementNoise.bearing_bias": "rad", "MeasurementNoise.samples": "true detections",
    "PlaneNoise.azimuth_sigma": "rad", "PlaneNoise.elevation_sigma": "rad", "PlaneNoise.offset_sigma": "m",
    "PlaneNoise.normal_angle_median": "rad", "PlaneNoise.offset_bias": "m", "PlaneNoise.samples": "true detections",
    "PlaneStats.max_elevation_deg": "deg", "PlaneStats.min_points": "count", "PlaneStats.min_width": "m", "PlaneStats.offset_max": "m",
    "PlaneStats.slab_k_sigma": "sigma", "PlaneStats.slab_ratio": "1",
    # the sensors behind a pooled profile
    "SensorSpread.pairs": "feature-scan pairs", "SensorSpread.pd_observed": "probability", "SensorSpread.pd_predicted": "probability",
    "SensorSpread.frames": "count", "SensorSpread.clutter_rate": "false alarms / scan", "SensorSpread.pd_logit_offset": "logit",
    "SensorSpread.pd_logit_sd": "logit", "SensorSpread.pd_concentration": "pseudo-pairs", "SensorSpread.pd_between_sd": "probability",
    "SensorSpread.clutter_between_sd": "false alarms / scan", "SensorSpread.clutter_weight": "1",
    # provenance
    "Provenance.seed": "integer",
}  # fmt: skip


def unit(model: str, field: str, section: dict) -> str | None:
    """The unit of ``field`` of the model class named ``model`` (``section``: that model's data); None if it has none."""
    u = UNITS.get(f"{model}.{field}")
    return u(section) if callable(u) else u


def rounded(x: float, digits: int = SIGNIFICANT) -> float:
    """``x`` to ``digits`` significant digits (0, inf and nan as they are)."""
    if x == 0.0 or not math.isfinite(x):
        return x
    return float(f"{x:.{digits}g}")


def models_of(root: type[BaseModel]) -> list[type[BaseModel]]:
    """Every pydantic model reachable from ``root`` through its fields' annotations, ``root`` first (the models a
    profile is made of, for the unit check and the schema reference)."""
    found: list[type[BaseModel]] = []
    todo = [root]
    while todo:
        cls = todo.pop(0)
        if cls in found:
            continue
        found.append(cls)
        for f in cls.model_fields.values():
            stack = [f.annotation]
            while stack:
                t = stack.pop()
                if isinstance(t, type) and issubclass(t, BaseModel):
                    todo.append(t)
                else:
                    stack.extend(typing.get_args(t))
    return found
