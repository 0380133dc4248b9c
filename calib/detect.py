"""The circle detector over every scan of a log: its settings and the detections as a table.

The table has one row per detection: time [s], scan index, frame, centre x/y
[m, sensor frame], range [m], bearing [rad], radius [m], fit error [m^2],
convexity [m], points, squared Mahalanobis distance (``detcal detect`` writes
it as ``detections.csv``: :mod:`detcal.reports.detect`).
"""

from __future__ import annotations


import pandas as pd
from pydantic import BaseModel, ConfigDict, Field

from calib.progress import progress
from detectors.circle import CircleDetections, detect_circles
from detectors.sensor_log import SensorLog
from profiles.errors import DataError
from profiles.schema import CircleDetectorParams, HotellingParams

CHUNK = 500


class DetectConfig(BaseModel):
    """What ``detcal detect --config`` reads."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)
    detector: CircleDetectorParams = CircleDetectorParams()
    hotelling: HotellingParams | None = None
    k_sigma: float = Field(default=3.0, gt=0.0, description="occlusion tolerance of the ray tracer, in sigma_r")


def run_detector(log: SensorLog, cfg: DetectConfig, *, show_progress: bool = True, label: str = "detecting") -> CircleDetections:
    """Detections of every scan of ``log`` (chunked so memory stays flat; a bar named ``label`` on a terminal)."""
    if log.scans is None or log.sensor is None:
        raise DataError(f"log {log.name!r} has no laser scans to detect circles in")
    n = len(log.scans)
    parts = []
    chunks = range(0, n, CHUNK)
    it = progress(chunks, len(chunks), label) if show_progress else chunks
    for a in it:
        rows = slice(a, a + CHUNK)
        d = detect_circles(log.scans.ranges[rows], log.scan_angles(rows), cfg.detector, cfg.hotelling, log.sensor.range_sigma)
        parts.append(d.offset(a))
    return CircleDetections.concat(parts)


def detections_table(log: SensorLog, det: CircleDetections) -> pd.DataFrame:
    return pd.DataFrame(
        {
            "time": log.scans.stamp[det.scan] / 1e9,
            "scan": det.scan,
            "frame": "sensor",
            "x": det.x,
            "y": det.y,
            "range": det.range,
            "bearing": det.bearing,
            "radius": det.radius,
            "fit_error": det.fit_error,
            "convexity": det.convexity,
            "points": det.n_points,
            "maha2": det.maha2,
        }
    )


