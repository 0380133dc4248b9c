"""The parameters a calibration records in a profile (``provenance.parameters``), as validated models.

A profile records the config it was made with and the choices the data made
(where the poses, the landmarks and sigma_r came from; the camera's frame
period and identity audit; the SLAM run of a self-calibration). These models
say exactly which keys may appear -- one model per way detcal makes profiles
of a detector kind: laser calibration; detection-level calibration,
self-calibration and a simulator's truth profile (the rfs-sim and glmb-paper scenarios) -- so a misspelt or foreign
key in a profile is refused with its field path like everywhere else. They are registered with the profile store (:func:`register`), which
cannot import ``calib`` itself; parameters recorded by another detcal version
are kept as recorded.
"""

from __future__ import annotations

from functools import cache
from typing import Literal

from pydantic import Field, model_validator

from calib import __version__


@cache
def laser_parameters() -> type:
    from calib.calibrate import CalibrateConfig

    class LaserCalibrationParameters(CalibrateConfig):
        pose_source: list[Literal["reference", "icp"]] = Field(min_length=1)
        landmarks: Literal["log", "cloud", "csv"]
        range_sigma_source: Literal["log", "option", "estimated"]
        # recorded (true) only when --accept-poor-ground-truth let a poor ground truth or thin data through
        accept_poor_ground_truth: bool = False

    return LaserCalibrationParameters


@cache
def detection_parameters() -> type:
    from calib.detlevel import DetectionCalibConfig

    class DetectionCalibrationParameters(DetectionCalibConfig):
        frame_period: float = Field(gt=0.0)  # type: ignore[assignment]  (always recorded: given or estimated)
        identity_remap: dict[str, int] = {}  # barcodes the identity audit found swapped in the truth

    return DetectionCalibrationParameters


@cache
def selfcal_parameters() -> type:
    from calib.selfcal import SelfCalConfig

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

    return SelfCalibrationParameters


@cache
def simulator_parameters() -> type:
    from calib.sim.rfs import RfsSimConfig

    return RfsSimConfig  # the truth profile of a simulated scenario records the scenario's config


@cache
def glmb_paper_parameters() -> type:
    from calib.sim.glmb_paper import GlmbPaperConfig

    return GlmbPaperConfig  # the truth profile of the delta-GLMB paper's scenario records its config


def register() -> None:
    """Every way this detcal makes profiles, per detector kind (a profile's parameters must fit one)."""
    from profiles.store import register_parameters

    register_parameters("circle2d", __version__, laser_parameters)
    register_parameters(
        "external", __version__, detection_parameters, selfcal_parameters, simulator_parameters, glmb_paper_parameters
    )
