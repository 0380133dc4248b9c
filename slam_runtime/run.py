"""Drive RB-PHD-SLAM over a log: motion per odometry row, the profile's detector per scan.

Takes a :class:`detectors.logs.SensorLog` in memory and a profile object; no
file paths (the CLI reads them). The start pose is the log's first reference
pose when it has one (so the map and the truth share a frame), else the origin.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from detectors.circle import detect_circles
from detectors.geometry import interpolate_poses
from detectors.logs import SensorLog
from detectors.model import DetectionModel
from profiles.errors import DataError
from profiles.schema import HotellingParams
from slam_runtime.metrics import gospa, ospa, trajectory_rmse
from slam_runtime.motion import ackermann, odometry_increment, unicycle
from slam_runtime.rbphd import RBPHDConfig, RBPHDSlam


@dataclass
class SlamResult:
    stamps: np.ndarray  # (T,) frame stamps [ns]
    trajectory: np.ndarray  # (T, 3) best particle's vehicle poses
    map_xy: np.ndarray  # (K, 2)
    map_w: np.ndarray  # (K,)
    step_ms: np.ndarray  # (T,) wall time per frame
    n_measurements: np.ndarray  # (T,)
    metrics: dict = field(default_factory=dict)


def _mover(log: SensorLog, rows: slice, motion: dict):
    o = log.odometry
    vals, stamps = o.values[rows], o.stamp[rows]
    prev = np.concatenate([[stamps[0] if stamps.size else 0], stamps[:-1]])

    def move(poses, rng):
        for k in range(vals.shape[0]):  # rows of one frame (a handful); each vectorised over particles
            if o.kind == "increment":
                poses = odometry_increment(poses, vals[k], rng, **motion.get("increment", {}))
            elif o.kind == "velocity":
                dt = (stamps[k] - prev[k]) / 1e9
                poses = unicycle(poses, vals[k, 0], vals[k, 1], dt, rng, **motion.get("velocity", {}))
            elif o.kind == "ackermann":
                dt = (stamps[k] - prev[k]) / 1e9
                veh = log.vehicle
                poses = ackermann(poses, vals[k, 0], vals[k, 1], dt, veh.wheelbase, veh.encoder_offset, rng, **motion.get("ackermann", {}))
            else:
                raise DataError(f"odometry of kind {o.kind!r} cannot drive the filter")
        return poses

    return move


def run_rbphd(log: SensorLog, profile, cfg: RBPHDConfig, seed: int, *, motion: dict | None = None, progress=None) -> SlamResult:
    """Run the filter over every frame of ``log`` with the statistics of ``profile``."""
    if log.odometry is None:
        raise DataError(f"log {log.name!r} has no odometry")
    model = DetectionModel.from_profile(profile)
    sensor = log.sensor if log.sensor is not None else profile.sensor
    mount = np.array([sensor.mount.x, sensor.mount.y, sensor.mount.theta])
    start = np.zeros(3)
    truth = log.reference.get("ground_truth")
    frames = list(log.frames())
    if truth is not None and frames:
        start = interpolate_poses(truth.stamp, truth.poses, np.array([frames[0].stamp]))[0]
    rng = np.random.default_rng(seed)
    slam = RBPHDSlam(model, mount, cfg, rng, start)
    hot = None
    if profile.hotelling is not None and profile.detector.kind == "circle2d":
        hot = HotellingParams.model_validate(profile.hotelling.model_dump(include=set(HotellingParams.model_fields)))
    ang = sensor.angles() if log.scans is not None else None
    times, counts = [], []
    it = frames if progress is None else progress(frames, len(frames), "RB-PHD-SLAM")
    for fr in it:
        t0 = time.perf_counter()
        if fr.odometry.stop > fr.odometry.start:
            slam.predict(_mover(log, fr.odometry, motion or {}))
        if fr.kind == "scan":
            scan = log.scans.ranges[fr.rows]
            det = detect_circles(scan, ang, profile.detector.circle, hot, sensor.range_sigma)
            z = np.column_stack([det.range, det.bearing])
            info = slam.update(z, scan, det.cov)
        else:
            d = log.detections
            z = np.column_stack([d.range[fr.rows], d.bearing[fr.rows]])
            info = slam.update(z)
        times.append((time.perf_counter() - t0) * 1e3)
        counts.append(info.n_measurements)
    traj = slam.trajectory()[1:]
    map_xy, map_w = slam.map_estimate()
    res = SlamResult(np.array([f.stamp for f in frames]), traj, map_xy, map_w, np.array(times), np.array(counts))
    res.metrics = evaluate(log, res)
    return res


def evaluate(log: SensorLog, res: SlamResult, c: float = 1.0, p: float = 1.0) -> dict:
    """Trajectory RMSE (no alignment: the filter starts at the true first pose) and map OSPA / GOSPA."""
    out: dict = {"frames": int(res.stamps.size), "ms_per_step_mean": float(res.step_ms.mean()) if res.step_ms.size else 0.0}
    for key in ("ground_truth", "gps"):
        ref = log.reference.get(key)
        if ref is None or res.stamps.size == 0:
            continue
        inside = (res.stamps >= ref.stamp[0]) & (res.stamps <= ref.stamp[-1])
        truth = interpolate_poses(ref.stamp, ref.poses, res.stamps[inside])
        out[f"trajectory_rmse_vs_{key}_m"] = trajectory_rmse(res.trajectory[inside], truth)
    if log.landmarks is not None:
        out["map_ospa"] = ospa(res.map_xy, log.landmarks.xy, c, p)
        out["map_gospa"] = gospa(res.map_xy, log.landmarks.xy, c, p)["gospa"]
        out["map_features"] = int(res.map_xy.shape[0])
        out["ospa_c_m"], out["ospa_p"] = c, p
    return out
