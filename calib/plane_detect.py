"""The plane detector over every cloud of a log: its settings, the planes and their convex outlines as tables.

``planes_table``: one row per plane (frame, time [s], plane index, normal,
offset [m], azimuth and elevation [rad], their standard deviations and the
offset's from the fit covariance, inliers, residual sigma [m], area [m^2] of the
convex outline, width [m] of the enclosing rectangle; sensor frame);
``outlines_table``: frame, plane, vertex, x, y, z. ``detcal detect`` writes
them (:mod:`detcal.reports.detect`).
"""

from __future__ import annotations

import time

import numpy as np
import pandas as pd
from pydantic import BaseModel, ConfigDict

from calib.progress import progress
from detectors.sensor_log import SensorLog
from detectors.plane import PlaneDetections, detect_planes
from profiles.errors import DataError
from profiles.planes import PlaneDetectorParams


class PlaneDetectConfig(BaseModel):
    """What ``detcal detect --config`` reads for point clouds."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)
    detector: PlaneDetectorParams = PlaneDetectorParams()


def run_plane_detector(log: SensorLog, params: PlaneDetectorParams, *, show_progress: bool = True) -> tuple[PlaneDetections, np.ndarray]:
    """Planes of every cloud of ``log`` and the ms each frame took (F,)."""
    if log.clouds is None:
        raise DataError(f"log {log.name!r} has no point clouds to detect planes in")
    n = len(log.clouds)
    it = progress(range(n), n, "detecting planes") if show_progress else range(n)
    parts, ms = [], np.zeros(n)
    for k in it:  # one cloud at a time; the detector is vectorised inside
        t0 = time.perf_counter()
        d = detect_planes(log.clouds.frame(k), params, where=f"{log.name}: cloud {k}")
        ms[k] = (time.perf_counter() - t0) * 1e3
        parts.append(d.with_frame(k))
    return PlaneDetections.concat(parts), ms


def planes_table(log: SensorLog, det: PlaneDetections) -> pd.DataFrame:
    sd = np.sqrt(np.maximum(np.diagonal(det.cov, axis1=1, axis2=2), 0.0)) if len(det) else np.zeros((0, 3))
    per = np.bincount(det.frame, minlength=len(log.clouds))
    first = np.concatenate([[0], np.cumsum(per)])[det.frame]
    return pd.DataFrame(
        {
            "frame": det.frame, "time": log.clouds.stamp[det.frame] / 1e9, "plane": np.arange(len(det)) - first, "sensor_frame": "sensor",
            "nx": det.normal[:, 0], "ny": det.normal[:, 1], "nz": det.normal[:, 2], "offset": det.offset,
            "azimuth": det.chart[:, 0], "elevation": det.chart[:, 1],
            "sd_azimuth": sd[:, 0], "sd_elevation": sd[:, 1], "sd_offset": sd[:, 2],
            "inliers": det.inliers, "sigma": det.sigma, "area": det.area, "width": det.width,
        }
    )


def outlines_table(det: PlaneDetections, table: pd.DataFrame) -> pd.DataFrame:
    counts = np.diff(det.outline_offsets)
    return pd.DataFrame(
        {
            "frame": np.repeat(det.frame, counts), "plane": np.repeat(table["plane"].to_numpy(), counts),
            "vertex": np.arange(det.outline.shape[0]) - np.repeat(det.outline_offsets[:-1], counts),
            "x": det.outline[:, 0], "y": det.outline[:, 1], "z": det.outline[:, 2],
        }
    )


def frame_sensor_poses(log: SensorLog) -> tuple[np.ndarray | None, str]:
    """(F, 3) sensor poses at the clouds (ground truth, else dead-reckoned speed and yaw-rate odometry), and their source."""
    from detectors.geometry import compose, interpolate_poses

    m = log.sensor.mount if log.sensor is not None else None
    mount = np.zeros(3) if m is None else np.array([m.x, m.y, m.theta])
    ref = log.reference.get("ground_truth")
    st = log.clouds.stamp
    if ref is not None and ref.stamp[0] <= st[0] and st[-1] <= ref.stamp[-1]:
        return compose(interpolate_poses(ref.stamp, ref.poses, st), mount), "ground truth"
    o = log.odometry
    if o is not None and o.kind == "velocity" and o.stamp[0] <= st[0]:
        t = o.stamp / 1e9
        pose = np.zeros((o.stamp.size, 3))
        for i in range(1, o.stamp.size):  # dead reckoning, sequential by nature
            v, w = o.values[i - 1]
            dt = t[i] - t[i - 1]
            th = pose[i - 1, 2]
            pose[i] = pose[i - 1] + np.array([v * dt * np.cos(th + w * dt / 2), v * dt * np.sin(th + w * dt / 2), w * dt])
        return compose(interpolate_poses(o.stamp, pose, st), mount), "odometry"
    return None, "none"


