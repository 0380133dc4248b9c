"""The parameters a calibration records in a profile (``provenance.parameters``), as validated models.

A profile records the config it was made with and the choices the data made
(where the poses, the landmarks and sigma_r came from; the camera's frame
period and identity audit; the SLAM run of a self-calibration). These models
say exactly which keys may appear -- one model per way detcal makes profiles
of a detector kind: laser calibration; detection-level calibration,
self-calibration and a simulator's truth profile (the rfs-sim and glmb-paper
scenarios) -- so a misspelt or foreign key in a profile is refused with its
field path like everywhere else. They are known to :mod:`profiles.store`
whatever else a program imports; parameters recorded by another detcal
version are kept as recorded. A new way of making profiles registers its model
with :func:`register_parameters`.
"""

from __future__ import annotations

from typing import Literal

from pydantic import BaseModel, Field, model_validator

from profiles.parameters import CalibrateConfig, DetectionCalibConfig, GlmbPaperConfig, RfsSimConfig, SelfCalConfig
from profiles.registry import Registry
from profiles.version import __version__


class LaserCalibrationParameters(CalibrateConfig):
    pose_source: list[Literal["reference", "icp"]] = Field(min_length=1)
    landmarks: Literal["log", "cloud", "csv"]
    range_sigma_source: Literal["log", "option", "estimated"]
    # recorded (true) only when --accept-poor-ground-truth let a poor ground truth or thin data through
    accept_poor_ground_truth: bool = False


class DetectionCalibrationParameters(DetectionCalibConfig):
    frame_period: float = Field(gt=0.0)  # type: ignore[assignment]  (always recorded: given or estimated)
    identity_remap: dict[str, int] = {}  # barcodes the identity audit found swapped in the truth


class SelfCalibrationParameters(SelfCalConfig):
    slam_run: str
    iteration: int = Field(ge=0)
    prior: str
    # --average-from: the iterations whose measurements were averaged, and each run's own figures
    averaged_iterations: list[int] | None = Field(default=None, min_length=2)
    clutter_count_model_of_iteration: int | None = Field(default=None, ge=0)
    clutter_rate_per_run: list[float] | None = None
    range_sigma_per_run: list[float | None] | None = None

    @model_validator(mode="after")
    def _per_run(self):
        n = len(self.averaged_iterations or [])
        for key in ("clutter_rate_per_run", "range_sigma_per_run"):
            v = getattr(self, key)
            if v is not None and len(v) != n:
                raise ValueError(f"{key}: {len(v)} values for {n} averaged iterations")
        return self


#: Per detector kind, the models the recorded parameters of a profile this detcal made must fit (one of them).
PARAMETER_MODELS: Registry[list[type[BaseModel]]] = Registry("profile parameters of detector kind")


def register_parameters(kind: str, *models: type[BaseModel]) -> None:
    """A way of making ``kind`` profiles: their recorded parameters may fit ``models`` (added to those known)."""
    PARAMETER_MODELS.add(kind, [*PARAMETER_MODELS.get(kind, []), *models], replace=True)


def parameter_models(kind: str, detcal_version: str) -> list[type[BaseModel]]:
    """The models parameters recorded by ``detcal_version`` in a ``kind`` profile must fit; none (not checked) for
    another version's records or an unknown kind."""
    return PARAMETER_MODELS.get(kind, []) if detcal_version == __version__ else []


register_parameters("circle2d", LaserCalibrationParameters)
# the truth profile of a simulated scenario records the scenario's config
register_parameters("external", DetectionCalibrationParameters, SelfCalibrationParameters, RfsSimConfig, GlmbPaperConfig)
