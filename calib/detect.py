"""``detcal detect``: run the circle detector over a log and write a detections table.

The run folder holds ``detections.csv`` (one row per detection: time [s], scan
index, frame, centre x/y [m, sensor frame], range [m], bearing [rad], radius
[m], fit error [m^2], convexity [m], points, squared Mahalanobis distance),
``config.yaml`` (the detector parameters actually used), ``summary.yaml`` and,
with ``plot_scan``, ``scan_<k>.png``.
"""

from __future__ import annotations

from pathlib import Path

import pandas as pd
from pydantic import BaseModel, ConfigDict, Field

from calib.config import dump_yaml
from calib.io.atomic import atomic_output
from calib.progress import progress
from detectors.circle import CircleDetections, detect_circles
from detectors.logs import SensorLog
from profiles.errors import DataError, UsageError
from profiles.schema import CircleDetectorParams, HotellingParams, PdTable

#: Thesis Table 6.1 (a real park data set), clamped as in ch. 6: above n_p = 6 use
#: the value at 6, values below 0.1 become 0. Used for plots when no profile is given.
THESIS_TABLE_6_1 = PdTable(
    covariate="n_p",
    edges=[0, 1, 2, 3, 4, 5, 6, 7],
    pd=[0.0, 0.0, 0.0, 0.3595, 0.7562, 0.8854, 0.8987],
    counts=[273025, 62025, 28582, 19423, 10374, 6909, 4185],
    clamping="thesis: n_p > 6 uses n_p = 6; P_D < 0.1 set to 0",
)

CHUNK = 500


class DetectConfig(BaseModel):
    """What ``detcal detect --config`` reads."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)
    detector: CircleDetectorParams = CircleDetectorParams()
    hotelling: HotellingParams | None = None
    k_sigma: float = Field(default=3.0, gt=0.0, description="occlusion tolerance of the ray tracer, in sigma_r")


def detect_config(profile_ref: str | None, config: Path | None) -> tuple[DetectConfig, PdTable | None]:
    """The detector settings of ``detcal detect``: a profile's detector, gate and n_p table, or a config file."""
    from calib.config import load_yaml_model
    from profiles.errors import UsageError

    if profile_ref is None:
        return load_yaml_model(DetectConfig, config), None
    if config is not None:
        raise UsageError("--profile and --config both set the detector; give one")
    from profiles.store import resolve

    prof = resolve(profile_ref)
    if prof.detector.kind != "circle2d":
        raise UsageError(f"profile {prof.ref} is a {prof.kind} profile, not one of the circle detector")
    hot = None if prof.hotelling is None else HotellingParams.model_validate(prof.hotelling.model_dump(include=set(HotellingParams.model_fields)))
    cfg = DetectConfig(detector=prof.detector.circle, hotelling=hot, k_sigma=prof.detector.k_sigma)
    return cfg, prof.pd if prof.pd.covariate == "n_p" else None


def run_detector(log: SensorLog, cfg: DetectConfig, *, show_progress: bool = True) -> CircleDetections:
    """Detections of every scan of ``log`` (chunked so memory stays flat)."""
    if log.scans is None or log.sensor is None:
        raise DataError(f"log {log.name!r} has no laser scans to detect circles in")
    n = len(log.scans)
    parts = []
    chunks = range(0, n, CHUNK)
    it = progress(chunks, len(chunks), "detecting") if show_progress else chunks
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


def write_detect_run(
    log: SensorLog, cfg: DetectConfig, out: Path, *, plot_scan: int | None = None, pd_table: PdTable | None = None, overwrite: bool = False
) -> dict:
    if plot_scan is not None and log.scans is not None and not 0 <= plot_scan < len(log.scans):
        raise UsageError(f"--plot: scan {plot_scan} is outside the log (0..{len(log.scans) - 1})")
    det = run_detector(log, cfg)
    table = detections_table(log, det)
    summary = {
        "log": log.name,
        "scans": len(log.scans),
        "detections": len(det),
        "per_scan_mean": float(len(det) / max(1, len(log.scans))),
        "gated": cfg.hotelling is not None,
    }
    with atomic_output(out, overwrite=overwrite, directory=True) as tmp:
        tmp.mkdir()
        table.to_csv(tmp / "detections.csv", index=False, float_format="%.9g")
        (tmp / "config.yaml").write_text(dump_yaml(cfg.model_dump(mode="json")))
        (tmp / "summary.yaml").write_text(dump_yaml(summary))
        if plot_scan is not None:
            from calib.plots import plot_scan_detections

            plot_scan_detections(log, det, plot_scan, pd_table or THESIS_TABLE_6_1, cfg.k_sigma, tmp / f"scan_{plot_scan:05d}.png")
    return summary
