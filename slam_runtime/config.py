"""Settings of a SLAM run: the filter, the motion-model noise and the map metric.

One pydantic model with ``extra="forbid"`` at every level, so a misspelt key
in a YAML override is refused with its path. ``detcal slam run --config F``
reads it; the run folder keeps a copy of the settings actually used.
"""

from __future__ import annotations

from typing import Literal

from pydantic import BaseModel, ConfigDict, Field

from slam_runtime.rbphd import RBPHDConfig


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid")


class IncrementNoise(_Strict):
    """Pose-increment odometry: std a_trans |d| along, lateral |d| across, a_rot |dtheta| + a_rot_trans |d| in heading."""

    a_trans: float = Field(default=0.05, ge=0.0)
    a_rot: float = Field(default=0.05, ge=0.0)
    a_rot_trans: float = Field(default=0.01, ge=0.0, description="rad per m")
    lateral: float = Field(default=0.02, ge=0.0)


class VelocityNoise(_Strict):
    """Unicycle (v, omega) commands."""

    sigma_v: float = Field(default=0.05, ge=0.0, description="m/s")
    sigma_omega: float = Field(default=0.05, ge=0.0, description="rad/s")


class AckermannNoise(_Strict):
    """Encoder speed and steering angle."""

    sigma_speed: float = Field(default=0.1, ge=0.0, description="m/s")
    sigma_steer: float = Field(default=0.02, ge=0.0, description="rad")


class MotionNoise(_Strict):
    increment: IncrementNoise = IncrementNoise()
    velocity: VelocityNoise = VelocityNoise()
    ackermann: AckermannNoise = AckermannNoise()


class MetricConfig(_Strict):
    ospa_c: float = Field(default=1.0, gt=0.0, description="OSPA / GOSPA cut-off [m]")
    ospa_p: float = Field(default=1.0, ge=1.0, description="OSPA / GOSPA order")


class SlamConfig(_Strict):
    filter: Literal["rbphd"] = "rbphd"
    rbphd: RBPHDConfig = RBPHDConfig()
    motion: MotionNoise = MotionNoise()
    metric: MetricConfig = MetricConfig()
