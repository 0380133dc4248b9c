"""Settings of a SLAM run, and the factory that turns them into models and a filter.

One pydantic model with ``extra="forbid"`` at every level, so a misspelt key
in a YAML override is refused with its path. The map filter is a
discriminated union on ``filter.kind``; the particle settings, the motion
noise, the detection options and the measurement noise are shared by every
filter. ``detcal slam run --config F`` reads it; the run folder keeps a copy
of the settings actually used. Overrides go through :func:`override`, which
validates them (``particles: 0`` is refused, not copied in).

The parts that depend on what is registered are read from the registries: the
``filter`` union (:data:`slam_runtime.mapfilter.MAP_FILTERS`), the groups of
``motion`` (:data:`slam_runtime.vehicle.VEHICLE_MODELS`), the fields of
``measurement`` and the ``features`` choices
(:data:`slam_runtime.features.FEATURE_MODELS`); the models are rebuilt when one
is registered later.
"""

from __future__ import annotations

from typing import Annotated, Literal, Union

import numpy as np
from pydantic import AllowInfNan, BaseModel, ConfigDict, Field, ValidationInfo, field_validator
from pydantic.fields import FieldInfo
from pydantic_core import PydanticCustomError

from detectors.kinds import DETECTORS
from profiles.errors import DataError, UsageError
from profiles.override import updated
from slam_runtime.features import FEATURE_MODELS
from slam_runtime.mapfilter import MAP_FILTERS
from slam_runtime.vehicle import VEHICLE_MODELS


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)


def _choice(names: tuple[str, ...]):
    return Literal[names]  # type: ignore[valid-type]


class MotionNoise(_Strict):
    """The vehicle models' noise, one group per registered model (:data:`VEHICLE_MODELS`)."""

    model: str = "auto"  # (its choices and the groups are set by _rebuild from the registry)


class MeasurementNoiseConfig(_Strict):
    """The filter's measurement noise floor (the fields of every feature model's ``Noise``); default: the profile's."""


class DetectionOptions(_Strict):
    """How the filter uses the profile's detection statistics."""

    pd_mode: Literal["profile", "constant"] = Field(default="profile", description="P_D from the profile, or constant inside the sensor's range and field of view (for comparison)")
    constant_pd: float = Field(default=0.9, gt=0.0, le=1.0, description="P_D inside the field of view in constant mode")
    buffer_zone: bool = Field(default=True, description="keep a feature's weight when it is missed near the edges of the view (eq. 3.21)")
    buffer_sigmas: float = Field(default=2.0, gt=0.0, description="buffer-zone half-width in standard deviations")
    plane_extents: bool = Field(
        default=False, description="planes: n_p of a map plane bounded by its detections' outlines, ray-traced as in calibration"
    )
    landmark_radius: float | None = Field(
        default=None, gt=0.0, description="radius the n_p ray tracer gives map features [m]; default: the profile's typical true radius"
    )
    phase_average: bool = Field(default=True, description="n_p averaged over where the beams fall, not the integer count")
    frame_clutter: bool = Field(
        default=False,
        description="RB-PHD, LMB, delta-GLMB: a negative-binomial profile's clutter rate per frame, from its unexplained measurements",
    )
    clutter_memory: float = Field(default=0.0, ge=0.0, description="with frame_clutter: frames over which earlier frames' counts are remembered (0 or 1: none)")
    descriptor_likelihood: bool = Field(default=True, description="weigh detections by their descriptors' likelihood ratio (eqs. 2.26, 5.6) when the profile has one")
    occlusion_sigmas: Annotated[float, AllowInfNan(True)] | Literal["profile"] | None = Field(default=None, description="range sigmas a return must fall short to occlude a map feature ('profile', .inf; null: the filter's)")
    occlusion: bool = Field(
        default=True, description="detection-level profiles with an occluder radius: features hidden behind a nearer mapped one have P_D 0"
    )
    landmarks_only: bool = Field(
        default=True, description="detection-level logs that label their detections (UTIAS `target`): feed only the landmark ones to the filter"
    )
    identities: Literal["auto", "on", "off"] = Field(
        default="auto", description="the landmark identity each detection reads (UTIAS barcodes): auto (when the log has them), on, off"
    )

    @field_validator("identities", mode="before")
    @classmethod
    def _switch(cls, value):
        """YAML reads a bare on / off as true / false: take those for on and off."""
        return {True: "on", False: "off"}.get(value, value) if isinstance(value, bool) else value

    @field_validator("occlusion_sigmas", mode="before")
    @classmethod
    def _tolerance(cls, value):
        """Above 0, .inf or 'profile': one message for a wrong value instead of one per member of the union."""
        if value is None or value == "profile":
            return value
        try:
            k = float(value) if not isinstance(value, bool) else None
        except (TypeError, ValueError):
            k = None
        if k is None or not k > 0.0:
            msg = "expected a number of range sigmas above 0, .inf or 'profile', not {value}"
            raise PydanticCustomError("occlusion_sigmas", msg, {"value": repr(value)})
        return k


class MetricConfig(_Strict):
    ospa_c: float = Field(default=1.0, gt=0.0, description="OSPA / GOSPA cut-off [m]")
    ospa_p: float = Field(default=1.0, ge=1.0, description="OSPA / GOSPA order")
    plane_length: float = Field(default=10.0, gt=0.0, description="planes: L of the distance sqrt(L^2 |n1 - n2|^2 + (d1 - d2)^2) [m]")




#: the settings that apply to point features only, and what each does to them (the message that refuses planes)
_POINTS_ONLY = {
    "map_refine": "re-estimates point features",
    "island_match": "pairs point features by position",
    "proposal": "'optimal' draws the pose from point features' measurements",
}


class SlamConfig(_Strict):
    features: str = Field(default="points", description="point landmarks (2D) or planes (3D lidar clouds)")
    particles: int = Field(default=20, ge=1, le=100_000, description="particles of the filter (over every island)")
    resampler: Literal["systematic", "stratified", "multinomial", "residual"] = Field(default="systematic", description="low-variance resampling scheme")
    resample_ess: float = Field(default=0.5, gt=0.0, le=1.0, description="resample when ESS < this x particles")
    resample_every: int = Field(default=1, ge=1, description="updates at least between two resamplings")
    islands: int = Field(default=1, ge=1, le=1_000, description="independent particle filters the particles are split into; particles must be a multiple of it")
    island_match: float | None = Field(default=None, gt=0.0, description="[m] pair islands' unlabelled features by position up to this distance (labelled filters; null: by label)")
    proposal: Literal["auto", "prior", "optimal"] = Field(
        default="auto",
        description="poses from the motion model (prior) or updated by the measurements (optimal); auto: the map filter's choice",
    )
    filter: BaseModel = Field(default=None)  # the union of the registered filters' settings (set by _rebuild)
    mount_yaw: float = Field(default=0.0, ge=-0.2, le=0.2, description="[rad] correction added to the sensor's mount yaw (chosen by the log evidence)")
    measurement: MeasurementNoiseConfig = Field(default_factory=MeasurementNoiseConfig)
    motion: MotionNoise = Field(default_factory=MotionNoise)
    detection: DetectionOptions = DetectionOptions()
    metric: MetricConfig = MetricConfig()
    map_refine: bool = Field(default=False, description="after the run, re-estimate the map's positions along the estimated trajectory (point features)")

    poses: Literal["estimated", "ground_truth"] = Field(default="estimated", description="estimated (full SLAM) or ground_truth (mapping only: the particles on the log's true path)")

    @field_validator("map_refine", "island_match", "proposal")
    @classmethod
    def _points_only(cls, value, info: ValidationInfo):
        if value not in (None, False, "prior", "auto") and info.data.get("features") == "planes":
            name = info.field_name
            raise PydanticCustomError(name, "{field} {does}; it does not apply to planes", {"field": name, "does": _POINTS_ONLY[name]})
        return value

    @field_validator("islands")
    @classmethod
    def _islands_share_the_particles(cls, islands: int, info: ValidationInfo) -> int:
        particles = info.data.get("particles")
        if particles is not None and particles % islands:
            raise PydanticCustomError(
                "islands", "{islands} islands cannot share {particles} particles equally (particles must be a multiple of islands)",
                {"islands": islands, "particles": particles},
            )
        return islands


def _copy(info: FieldInfo) -> FieldInfo:
    return FieldInfo.merge_field_infos(info)


def _rebuild() -> None:
    """Read the registries into the settings' models and rebuild them (the nested ones first)."""
    motion = {
        "model": FieldInfo.from_annotated_attribute(
            _choice(("auto", *VEHICLE_MODELS.names())),
            Field(default="auto", description="auto: the model of the odometry's kind and the features; a model's name: always that model"),
        )
    }
    for name, cls in VEHICLE_MODELS.items():
        motion[name] = FieldInfo.from_annotated_attribute(cls.Noise, Field(default_factory=cls.Noise))
    MotionNoise.__pydantic_fields__ = motion
    MotionNoise.model_rebuild(force=True)
    MeasurementNoiseConfig.__pydantic_fields__ = {n: _copy(f) for cls in FEATURE_MODELS.values() for n, f in cls.Noise.model_fields.items()}
    MeasurementNoiseConfig.model_rebuild(force=True)
    fields = SlamConfig.__pydantic_fields__
    old = fields["features"]
    fields["features"] = FieldInfo.from_annotated_attribute(_choice(FEATURE_MODELS.names()), Field(default=old.default, description=old.description))
    configs = [cls.Config for cls in MAP_FILTERS.values()]
    union = Annotated[Union[tuple(configs)], Field(discriminator="kind")] if len(configs) > 1 else configs[0]  # noqa: UP007
    fields["filter"] = FieldInfo.from_annotated_attribute(union, configs[0]())
    SlamConfig.model_rebuild(force=True)


_rebuild()
for _registry in (MAP_FILTERS, VEHICLE_MODELS, FEATURE_MODELS):
    _registry.on_change(_rebuild)


def override(cfg: SlamConfig, **changes) -> SlamConfig:
    """A validated copy of ``cfg`` with dotted-path changes, e.g. ``override(cfg, particles=50, **{"detection.pd_mode": "constant"})``;
    a change of None is skipped (an option not given); a bad value raises a UsageError naming the field."""
    return with_settings(cfg, {k: v for k, v in changes.items() if v is not None})


def with_settings(cfg: SlamConfig, changes: dict) -> SlamConfig:
    """A validated copy of ``cfg`` with ``changes`` ({dotted path: value}; None sets None); a bad key or value raises a
    UsageError naming it; a change of ``filter.kind`` starts the filter from its own defaults."""
    return updated(cfg, changes, reset=("filter.kind",))


#: Settings whose name two filters share but whose meaning or default differs: never carried from one filter to another
#: (RB-PHD's ``prune`` drops Gaussian components of weight below it, delta-GLMB's drops hypotheses; ``factor_independent``
#: is on by default for delta-GLMB and off for LMB, whose comparison runs keep the fast LMB update unless asked; so is
#: ``merge_alternatives``, 0.1 for delta-GLMB and off for LMB).
_NOT_CARRIED = frozenset({"kind", "prune", "factor_independent", "merge_alternatives"})


def with_filter(cfg: SlamConfig, kind: str | None) -> SlamConfig:
    """``cfg`` with the map filter ``kind``; the settings the two filters share and that mean the same in both
    (gate, noise inflation, landmark noise, map threshold; survival and birth of LMB and delta-GLMB) carry over,
    the others take the new filter's defaults."""
    if kind is None or kind == cfg.filter.kind:
        return cfg
    if kind not in MAP_FILTERS:
        raise UsageError(f"filter.kind: {kind!r} is not available (expected one of {', '.join(MAP_FILTERS.names())})")
    target = MAP_FILTERS.get(kind).Config
    shared = {k: v for k, v in cfg.filter.model_dump().items() if k not in _NOT_CARRIED and k in target.model_fields}
    return override(cfg, **{"filter": {**shared, "kind": kind}})


# ---------------------------------------------------------------------- factory
def vehicle_model(kind: str, noise: MotionNoise, vehicle=None, features: str = "points"):
    """The vehicle model that odometry of ``kind`` drives: ``noise.model`` when it names one, else the first registered
    model that takes this odometry for these features (the ECT model for planes on speed and yaw-rate odometry)."""
    if noise.model != "auto":
        cls = VEHICLE_MODELS.get(noise.model)
        if kind not in cls.odometry:
            raise DataError(f"the {cls.label} model takes {cls.takes}, not {kind!r}")
    else:
        cls = next((c for c in VEHICLE_MODELS.values() if kind in c.odometry and features in c.features), None)
        if cls is None:
            raise DataError(f"odometry of kind {kind!r} cannot drive the filter")
    name = next(n for n, c in VEHICLE_MODELS.items() if c is cls)
    return cls.from_settings(getattr(noise, name), vehicle)


def occlusion_sigmas(opts: DetectionOptions, filter_kind: str) -> float | None:
    """The occlusion tolerance a filter runs with, in range sigmas (None: the profile's): the settings', else the
    filter's own default (``MapFilter.occlusion_default``)."""
    k = MAP_FILTERS.get(filter_kind).occlusion_default if opts.occlusion_sigmas is None else opts.occlusion_sigmas
    return None if k == "profile" else k


def detection_model(profile, opts: DetectionOptions, sensor=None, *, filter_kind: str | None = None):
    """The profile's runtime detection model (its detector kind's, :data:`detectors.kinds.DETECTORS`) with the
    filter's options; ``filter_kind`` chooses the occlusion tolerance when the options give none
    (``MapFilter.occlusion_default``; default: the first registered filter's)."""
    k = occlusion_sigmas(opts, filter_kind or MAP_FILTERS.names()[0])
    return DETECTORS.get(profile.detector.kind).detection_model(profile, sensor, opts, k)


def feature_model(features: str, detection, noise: MeasurementNoiseConfig, mount: np.ndarray, metric: MetricConfig | None = None):
    """The feature model ``features`` (:data:`FEATURE_MODELS`) with its noise floor from the settings and the profile."""
    return FEATURE_MODELS.get(features).from_settings(detection, noise, mount, metric)


def map_filter(cfg: SlamConfig, feature, detection):
    """The map filter ``cfg.filter.kind`` (:data:`MAP_FILTERS`) with its settings."""
    return MAP_FILTERS.get(cfg.filter.kind)(feature, detection, cfg.filter)
