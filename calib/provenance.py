"""The parameters a calibration records in a profile (``provenance.parameters``), as validated models.

A profile records the calibration config it was made with and the choices the
data made (where the poses, the landmarks and sigma_r came from; the camera's
frame period). These models say exactly which keys may appear, so a misspelt
or foreign key in a profile is refused with its field path like everywhere
else. They are registered with the profile store (:func:`register`), which
cannot import ``calib`` itself; parameters recorded by another detcal version
are kept as recorded.
"""

from __future__ import annotations

from functools import cache
from typing import Literal

from pydantic import Field

from calib import __version__


@cache
def laser_parameters() -> type:
    from calib.calibrate import CalibrateConfig

    class LaserCalibrationParameters(CalibrateConfig):
        pose_source: list[Literal["reference", "icp"]] = Field(min_length=1)
        landmarks: Literal["log", "cloud", "csv"]
        range_sigma_source: Literal["log", "option", "estimated"]

    return LaserCalibrationParameters


@cache
def detection_parameters() -> type:
    from calib.detlevel import DetectionCalibConfig

    class DetectionCalibrationParameters(DetectionCalibConfig):
        frame_period: float = Field(gt=0.0)  # type: ignore[assignment]  (always recorded: given or estimated)
        identity_remap: dict[str, int] = {}  # barcodes the identity audit found swapped in the truth

    return DetectionCalibrationParameters


def register() -> None:
    from profiles.store import register_parameters

    register_parameters("circle2d", __version__, laser_parameters)
    register_parameters("external", __version__, detection_parameters)
