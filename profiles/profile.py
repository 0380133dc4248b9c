"""The detector profile: everything a filter needs to know about one detector on one sensor.

A profile is a versioned YAML document (schema version ``SCHEMA_VERSION``)::

    schema_version: 3
    name: park-laser            # [a-z0-9][a-z0-9._-]*
    version: 1.0.0              # semantic version; a written version is never replaced silently
    description: ...
    detector:  {kind: circle2d, circle: {jump, min_points, ...}, k_sigma, buffer_samples, association_gate}
               or {kind: plane3d, plane: {cell_azimuth_deg, ..., msse_t, ...}, ...}
    sensor:    {kind, n_beams, angle_min, angle_increment, range_min, range_max, range_sigma, fov, mount}
    hotelling: {names, mean, covariance, confidence, gamma, auc_hotelling, auc_fisher}
    pd:        {covariate: n_p | range | range_bearing, edges, bearing_edges, pd, counts, detections, wilson_low,
                wilson_high, clamping, model, shrinkage, between_sensor_sd, selection}
               (written as bins: one row {from, to, pd, counts, ...} per bin)
    clutter:   {rate, space, volume, kappa, chi2, dof, p_value, dispersion, count_model, size, dispersion_test,
                nb_gof, density}
    sensors:   {names, member, pairs, pd_observed, pd_predicted, frames, clutter_rate, ...}   (optional)
    descriptor_likelihoods: {true: truncated_gaussian, false: uniform_ellipsoid, gaussian_mass, ellipsoid_volume}
    planes:    {pd_grid, noise, max_elevation_deg, min_points, min_width, offset_max, slab_k_sigma, slab_ratio}  (plane3d only)
    provenance: {inputs: [{name, sha256}], detcal_version, commit, packages, command, parameters, created, seed}

Every level forbids unknown keys; a wrong value is reported with its field path.
A ``plane3d`` detector on a ``lidar3d`` sensor with a P_D table over ``points``
and a ``planes`` section is the profile kind ``lidar3d-planes`` (:attr:`DetectorProfile.kind`).

Schema versions: 2 added richer models (a range x bearing P_D grid, model
selection records, negative-binomial clutter counts and a clutter density, the
Hotelling coverage, the spread between sensors). A schema-1 reader would refuse
them field by field, hence the new number. Every field added in 2 is optional
with a default meaning the schema-1 behaviour, so schema-1 documents load
unchanged and are written back byte for byte as schema 1 (:data:`V2_FIELDS` are
left out); a schema-1 document that uses a schema-2 field is refused by name.
The planar path (``plane3d`` detectors, ``sensor.lidar``, ``planes``) is schema 2.

Schema 3 changed how a profile is written, for a person who reads and diffs it
(:func:`profiles.store.dump_profile`): a unit in a comment after every
quantity (:mod:`profiles.units`), fitted figures to six significant digits, the
P_D table as ``pd.bins`` with one row per bin (so a change of one bin is a
one-line diff), and the provenance's ``commit`` and ``packages``. Schema-1 and
-2 documents are valid models of their own schema (and written back in their own
form); read from a file they are migrated to the current schema
(:mod:`profiles.migrate`).
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from typing import Any, Literal

from pydantic import Field, field_validator, model_validator

from profiles.planes import PlaneDetectorParams, PlaneStats
from profiles.registry import Registry, literal_field
from profiles.schema import PD_COVARIATES, CircleDetectorParams, ClutterParams, HotellingParams, MeasurementNoise, PdTable, SensorModel, Strict

SCHEMA_VERSION = 3
SUPPORTED_SCHEMAS = (1, 2, 3)
# schema-2 fields added after its first release: left out when absent, so profiles written before keep their bytes
LATER_OPTIONAL: dict[str, tuple[str, ...]] = {"pd": ("effective_counts",), "clutter": ("frames", "rate_se")}
# fields added in schema 2, as a pydantic ``exclude`` spec (left out when writing a schema-1 document)
V2_FIELDS: dict = {
    "pd": {"bearing_edges", "model", "shrinkage", "between_sensor_sd", "selection", "effective_counts"},
    "clutter": {"count_model", "size", "dispersion_test", "nb_gof", "density", "frames", "rate_se"},
    "hotelling": {"gamma_method", "coverage"},
    "sensors": True,
    "planes": True,
}
# fields added in schema 3 (left out when writing a schema-1 or -2 document)
V3_FIELDS: dict = {"provenance": {"commit", "packages"}}
NAME_RE = re.compile(r"^[a-z0-9][a-z0-9._-]*$")
SEMVER_RE = re.compile(r"^(0|[1-9]\d*)\.(0|[1-9]\d*)\.(0|[1-9]\d*)$")


def semver_key(v: str) -> tuple[int, int, int]:
    m = SEMVER_RE.match(v)
    if m is None:
        raise ValueError(f"{v!r} is not a semantic version MAJOR.MINOR.PATCH")
    return int(m.group(1)), int(m.group(2)), int(m.group(3))


@dataclass(frozen=True)
class DetectorKind:
    """What a detector kind means to a profile.

    ``params``: the field of :class:`DetectorSpec` holding its parameters (None: none); ``label``: the profile's
    kind is ``<sensor kind>-<label>``; ``planes``: its profiles have P_D over the points of planes, a planes
    section and clutter in plane space, on a ``sensor`` of that kind with its lidar geometry; ``schema``: the
    first profile schema that can say it. What it does at run time is in ``detectors.kinds``.
    """

    params: str | None = None
    label: str = "external"
    planes: bool = False
    sensor: str | None = None
    schema: int = 1


#: The detector kinds a profile may name (``detector.kind``); a new detector registers its kind here through
#: ``detectors.kinds.register`` (with what it does at run time).
DETECTOR_KINDS: Registry[DetectorKind] = Registry("detector kind")
DETECTOR_KINDS.add("circle2d", DetectorKind(params="circle", label="circles"))
DETECTOR_KINDS.add("external", DetectorKind())
DETECTOR_KINDS.add("plane3d", DetectorKind(params="plane", label="planes", planes=True, sensor="lidar3d", schema=2))

#: the parameter fields of :class:`DetectorSpec` and their models
_PARAMS = {"circle": CircleDetectorParams, "plane": PlaneDetectorParams}


class DetectorSpec(Strict):
    """Which detector and its parameters.

    ``circle2d``: the thesis's laser circle detector run by detcal (``circle`` holds
    its parameters). ``external``: detections produced elsewhere and read from the
    log (a camera's barcode detector, a vendor's tree extractor). ``plane3d``: detcal's
    plane detector on 3D lidar clouds (``plane`` holds its parameters).
    """

    kind: str = "circle2d"  # (one of DETECTOR_KINDS: set below)
    circle: CircleDetectorParams | None = None
    plane: PlaneDetectorParams | None = None
    k_sigma: float = Field(default=3.0, gt=0.0, description="occlusion tolerance of the n_p ray tracer, in sigma_r")
    buffer_samples: int = Field(default=5, ge=1, description="lateral samples of the buffer-zone rule (odd)")
    association_gate: float = Field(default=1.0, gt=0.0, description="detection-landmark gate used in calibration [m]")
    occluder_radius: float | None = Field(
        default=None,
        gt=0.0,
        description="external detectors of round landmarks: P_D of a feature hidden behind a nearer mapped feature of this radius [m] is 0 "
        "(the P_D table is then that of unoccluded features)",
    )

    @model_validator(mode="after")
    def _params(self) -> DetectorSpec:
        own = DETECTOR_KINDS.get(self.kind).params
        for field, model in _PARAMS.items():
            if own == field and getattr(self, field) is None:
                setattr(self, field, model())
            if own != field and getattr(self, field) is not None:
                raise ValueError(f"a {self.kind} detector has no {field} parameters")
        if self.buffer_samples % 2 == 0:
            raise ValueError("buffer_samples must be odd")
        return self


class HotellingModel(HotellingParams):
    """Hotelling ellipsoid (eq. 5.4) with the ROC areas measured in calibration (fig. 5.5)."""

    auc_hotelling: float | None = Field(default=None, ge=0.0, le=1.0)
    auc_fisher: float | None = Field(default=None, ge=0.0, le=1.0)
    samples: int | None = Field(default=None, ge=0, description="true detections the ellipsoid was fitted to")
    gamma_method: Literal["chi2", "empirical"] = Field(
        default="chi2",
        description="gamma from the chi-square quantile at `confidence` (eq. 5.4, exact for Gaussian descriptors) or the "
        "empirical quantile of the true detections' Mahalanobis distances (right whatever their distribution)",
    )
    coverage: float | None = Field(default=None, ge=0.0, le=1.0, description="share of the calibration's true detections inside the ellipsoid")


class DescriptorLikelihoods(Strict):
    """Eq. 5.6: true detections' descriptors ~ Gaussian truncated to the ellipsoid, false ones uniform over it."""

    true: Literal["truncated_gaussian"] = "truncated_gaussian"
    false: Literal["uniform_ellipsoid"] = "uniform_ellipsoid"
    gaussian_mass: float = Field(gt=0.0, le=1.0, description="chi2 CDF of gamma: the Gaussian's mass inside the ellipsoid")
    ellipsoid_volume: float = Field(gt=0.0, description="volume of the ellipsoid in descriptor space (g_FA = 1 / volume)")


class SensorSpread(Strict):
    """The sensors (robots, logs) behind a profile and how far they differ (schema 2).

    Lists run over ``names``. ``pd_observed`` is each sensor's detection rate over
    its own pairs and ``pd_predicted`` what the pooled model predicts for the same
    pairs (they differ when the sensors differ, not only by where they looked).
    Partial pooling in two levels: ``pd_logit_offset`` is each sensor's shift of
    logit P_D from the pooled table (shrunk by ``pd_logit_sd``, the offsets' spread
    beyond their sampling error), and ``pd_concentration`` is m of the beta prior
    on what the offset leaves cell by cell (None: the cells agree within their
    noise). ``pd_between_sd`` is the between-sensor standard deviation of P_D
    both imply at the pooled overall P_D. Clutter rates are pooled likewise:
    ``clutter_between_sd`` is the spread of the sensors' rates beyond their
    sampling error (batch means), and a member's rate is w own + (1 - w) pooled.
    ``member``: None for the pooled profile, else the sensor this profile is for.
    """

    names: list[str] = Field(min_length=1)
    member: str | None = None
    pairs: list[int]
    pd_observed: list[float]
    pd_predicted: list[float]
    frames: list[int]
    clutter_rate: list[float]
    pd_logit_offset: list[float]
    pd_logit_sd: float = Field(ge=0.0)
    pd_concentration: float | None = Field(default=None, gt=0.0)
    pd_between_sd: float = Field(ge=0.0)
    clutter_between_sd: float = Field(ge=0.0)
    clutter_weight: float | None = Field(default=None, ge=0.0, le=1.0, description="member: weight of its own clutter rate")

    @model_validator(mode="after")
    def _lengths(self) -> SensorSpread:
        n = len(self.names)
        for name in ("pairs", "pd_observed", "pd_predicted", "frames", "clutter_rate", "pd_logit_offset"):
            if len(getattr(self, name)) != n:
                raise ValueError(f"{name} has {len(getattr(self, name))} entries for {n} sensors")
        if self.member is not None and self.member not in self.names:
            raise ValueError(f"member {self.member!r} is not one of the sensors")
        return self


class InputRef(Strict):
    name: str
    sha256: str = Field(pattern=r"^[0-9a-f]{64}$")


class Provenance(Strict):
    """How a profile was made: from which inputs, by which detcal (version, source commit, the versions of the
    numerical packages), with which command line, parameters and seed."""

    inputs: list[InputRef] = Field(default_factory=list)
    detcal_version: str
    commit: str | None = Field(
        default=None, description="git commit of the detcal source that made it ('+dirty': with uncommitted changes); schema 3"
    )
    packages: dict[str, str] = Field(default_factory=dict, description="versions of the packages the numbers depend on; schema 3")
    command: str = Field(default="", description="the command line, paths as typed (absolute ones relative to the working folder or ~)")
    parameters: dict[str, Any] = Field(default_factory=dict)
    created: str = Field(description="ISO 8601 UTC time (SOURCE_DATE_EPOCH when set, for reproducible bytes)")
    seed: int | None = None


class DetectorProfile(Strict):
    schema_version: Literal[1, 2, 3] = SCHEMA_VERSION
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
    sensors: SensorSpread | None = Field(default=None, description="the sensors behind the profile and their spread (written only when several)")
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
        d, c = self.detector.kind, self.pd.covariate
        kind, cov = DETECTOR_KINDS.get(d), PD_COVARIATES.get(c)
        allowed = cov.detectors is None or d in cov.detectors
        if cov.sensor_needs:
            if not allowed:
                raise ValueError(cov.refusal)
            if any(getattr(self.sensor, f) is None for f in cov.sensor_needs):
                raise ValueError(f"pd.covariate {c} needs {' and '.join(f'sensor.{f}' for f in cov.sensor_needs)}")
        if (self.descriptor_likelihoods is not None) and self.hotelling is None:
            raise ValueError("descriptor_likelihoods need a hotelling model")
        if kind.planes and (self.sensor.kind != kind.sensor or self.sensor.lidar is None):
            raise ValueError(f"a {d} detector needs a {kind.sensor} sensor with its lidar geometry")
        if kind.planes and (not allowed or cov.detectors is None or self.planes is None or self.clutter.space != "plane"):
            own = ", ".join(n for n, v in PD_COVARIATES.items() if v.detectors is not None and d in v.detectors)
            raise ValueError(f"a {d} profile needs pd.covariate {own}, a planes section and clutter.space plane")
        of_planes = cov.detectors is not None and all(DETECTOR_KINDS.get(k, DetectorKind()).planes for k in cov.detectors)
        if not kind.planes and (self.planes is not None or of_planes):
            planar = " or ".join(n for n, v in DETECTOR_KINDS.items() if v.planes)
            raise ValueError(f"planes and a P_D table over points belong to {planar} detectors")
        if not allowed:
            raise ValueError(cov.refusal)
        if self.schema_version == 1:
            used = schema2_fields_used(self)
            if used:
                raise ValueError(f"{used[0]} needs schema_version 2 (this document says 1)")
        if self.schema_version < 3:
            used = [f"provenance.{k}" for k in sorted(V3_FIELDS["provenance"]) if getattr(self.provenance, k)]
            if used:
                raise ValueError(f"{used[0]} needs schema_version 3 (this document says {self.schema_version})")
        return self

    @property
    def kind(self) -> str:
        """What the profile is for: ``<sensor kind>-<the detector kind's label>`` (``laser2d-circles``,
        ``lidar3d-planes``, ``camera-external``)."""
        return f"{self.sensor.kind}-{DETECTOR_KINDS.get(self.detector.kind).label}"

    @property
    def ref(self) -> str:
        return f"{self.name}@{self.version}"


def schema2_fields_used(p: DetectorProfile) -> list[str]:
    """Field paths of ``p`` that hold something only schema 2 can say (a value other than the default)."""
    used = [f"pd.{k}" for k in sorted(V2_FIELDS["pd"]) if getattr(p.pd, k) != type(p.pd).model_fields[k].default]
    used += [f"clutter.{k}" for k in sorted(V2_FIELDS["clutter"]) if getattr(p.clutter, k) != type(p.clutter).model_fields[k].default]
    if PD_COVARIATES.get(p.pd.covariate).schema >= 2:
        used.insert(0, "pd.covariate")
    if p.hotelling is not None:
        h = p.hotelling
        used += [f"hotelling.{k}" for k in sorted(V2_FIELDS["hotelling"]) if getattr(h, k) != type(h).model_fields[k].default]
    if p.sensors is not None:
        used.append("sensors")
    if DETECTOR_KINDS.get(p.detector.kind).schema >= 2:
        used.insert(0, "detector.kind")
    if p.sensor.lidar is not None:
        used.append("sensor.lidar")
    if p.planes is not None:
        used.append("planes")
    return used


def _kinds() -> None:
    literal_field(DetectorSpec, "kind", DETECTOR_KINDS.names(), DetectorProfile)


_kinds()
DETECTOR_KINDS.on_change(_kinds)
PD_COVARIATES.on_change(lambda: DetectorProfile.model_rebuild(force=True))
