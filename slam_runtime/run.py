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
from detectors.geometry import compose, interpolate_poses, relative
from detectors.logs import SensorLog
from detectors.model import DetectionModel
from profiles.errors import DataError, UsageError
from profiles.schema import HotellingParams
from slam_runtime.metrics import gospa, ospa, trajectory_rmse
from slam_runtime.motion import ackermann, odometry_increment, unicycle
from slam_runtime.config import SlamConfig
from slam_runtime.rbphd import RBPHDConfig, RBPHDSlam


@dataclass
class SlamResult:
    """What one run produced; every per-step array has one row per frame (T)."""

    stamps: np.ndarray  # (T,) frame stamps [ns]
    trajectory: np.ndarray  # (T, 3) the best particle's vehicle poses (its whole history), world frame
    mean_trajectory: np.ndarray  # (T, 3) the weighted mean of the particles at each step
    map_xy: np.ndarray  # (K, 2) the best particle's components of weight >= map_threshold
    map_w: np.ndarray  # (K,)
    step_ms: np.ndarray  # (T,) wall time per frame (motion, detection and update)
    n_measurements: np.ndarray  # (T,)
    ess: np.ndarray  # (T,) effective sample size after the update
    resampled: np.ndarray  # (T,) bool
    components: np.ndarray  # (T,) mean components per particle
    map_ospa: np.ndarray  # (T,) OSPA of the map estimate at each step (NaN without landmark truth)
    start: np.ndarray = field(default_factory=lambda: np.zeros(3))  # (3,) the pose the filter started from
    odometry: np.ndarray | None = None  # (T, 3) dead reckoning through the same frames (set by evaluate)
    metrics: dict = field(default_factory=dict)


def _mover(log: SensorLog, rows: slice, motion: dict):
    """Motion over the odometry rows ``rows`` (those up to a frame): ``move(poses, rng) -> poses``.

    A velocity or Ackermann command holds until the next row, so the interval
    from the previous row of the whole log (not of the frame) to row k is
    driven by that previous row. Pose odometry (CARMEN ODOM) moves by the
    increment from the previous row's pose.
    """
    o = log.odometry
    start = rows.start or 0
    vals, stamps = o.values[rows], o.stamp[rows]
    before = o.stamp[start - 1] if start > 0 else (stamps[0] if stamps.size else 0)
    prev = np.concatenate([[before], stamps[:-1]])
    # a velocity or Ackermann command holds until the next row: the interval ending at row k
    # is driven by row k - 1 (the first row of the log has no interval before it)
    held = np.vstack([o.values[start - 1][None] if start > 0 else vals[:1], vals[:-1]]) if len(vals) else vals
    if o.kind == "pose":
        base = o.values[start - 1] if start > 0 else (vals[0] if len(vals) else np.zeros(3))
        chain = np.vstack([base[None], vals])
        incs = relative(chain[:-1], chain[1:])

    def move(poses, rng):
        for k in range(vals.shape[0]):  # rows of one frame (a handful); each vectorised over particles
            if o.kind == "pose":
                poses = odometry_increment(poses, incs[k], rng, **motion.get("increment", {}))
            elif o.kind == "increment":
                poses = odometry_increment(poses, vals[k], rng, **motion.get("increment", {}))
            elif o.kind == "velocity":
                dt = (stamps[k] - prev[k]) / 1e9
                poses = unicycle(poses, held[k, 0], held[k, 1], dt, rng, **motion.get("velocity", {}))
            elif o.kind == "ackermann":
                dt = (stamps[k] - prev[k]) / 1e9
                veh = log.vehicle
                poses = ackermann(poses, held[k, 0], held[k, 1], dt, veh.wheelbase, veh.encoder_offset, rng, **motion.get("ackermann", {}))
            else:
                raise DataError(f"odometry of kind {o.kind!r} cannot drive the filter")
        return poses

    return move


def check_inputs(log: SensorLog, profile) -> None:
    """Refuse a log this profile cannot run on: the measurements it needs, odometry, and for an
    n_p table the beam geometry it was measured with (it holds for no other)."""
    if profile.detector.kind == "circle2d" and log.scans is None:
        raise UsageError(f"{log.name}: profile {profile.ref} detects circles in laser scans, and this log has none")
    if profile.detector.kind != "circle2d" and log.detections is None:
        raise UsageError(f"{log.name}: profile {profile.ref} takes the log's detections, and this log has none")
    if log.odometry is None:
        raise UsageError(f"{log.name}: no odometry to drive the filter")
    if profile.pd.covariate == "n_p" and log.sensor is not None:
        _same_beams(profile, log.sensor)


def _same_beams(profile, sensor) -> None:
    p = profile.sensor
    same = p.n_beams == sensor.n_beams and np.isclose(p.angle_min, sensor.angle_min, atol=1e-6) and np.isclose(
        p.angle_increment, sensor.angle_increment, atol=1e-9
    )
    if not same:
        raise UsageError(
            f"profile {profile.ref} was calibrated for {p.n_beams} beams from {np.degrees(p.angle_min):.2f} deg every "
            f"{np.degrees(p.angle_increment):.4f} deg; this log's laser has {sensor.n_beams} from "
            f"{np.degrees(sensor.angle_min):.2f} deg every {np.degrees(sensor.angle_increment):.4f} deg "
            "(calibrate a profile for this laser with detcal calibrate)"
        )


def run_slam(log: SensorLog, profile, cfg: SlamConfig, seed: int, *, progress=None, max_frames: int | None = None) -> SlamResult:
    """Run the filter ``cfg.filter`` over ``log`` (see :func:`run_rbphd`)."""
    return run_rbphd(
        log, profile, cfg.rbphd, seed, motion=cfg.motion.model_dump(), progress=progress,
        ospa_c=cfg.metric.ospa_c, ospa_p=cfg.metric.ospa_p, max_frames=max_frames,
    )


def run_rbphd(
    log: SensorLog,
    profile,
    cfg: RBPHDConfig,
    seed: int,
    *,
    motion: dict | None = None,
    progress=None,
    ospa_c: float = 1.0,
    ospa_p: float = 1.0,
    max_frames: int | None = None,
) -> SlamResult:
    """Run the filter over every frame (or the first ``max_frames``) of ``log`` with the statistics of ``profile``.

    Laser logs: the profile's circle detector runs on each scan (with its
    Hotelling gate) and the scan is ray-traced for P_D. Detection-level logs
    (Victoria Park, UTIAS): the log's detections are the measurements and P_D
    comes from the profile's covariate (range). ``motion`` overrides the
    motion-model noise, e.g. ``{"increment": {"a_trans": 0.1}}``.
    """
    check_inputs(log, profile)
    model = DetectionModel.from_profile(profile)
    sensor = log.sensor if log.sensor is not None else profile.sensor
    mount = np.array([sensor.mount.x, sensor.mount.y, sensor.mount.theta])
    frames = list(log.frames())[:max_frames]
    if not frames:
        raise DataError(f"log {log.name!r}: no scans or detections to run on")
    # start at the true first pose when the log has one (map and truth then share a frame);
    # GPS has no heading, so a GPS-only log starts at the origin and is scored after a rigid fit
    start = np.zeros(3)
    ref = log.reference.get("ground_truth")
    if ref is not None and ref.stamp[0] <= frames[0].stamp <= ref.stamp[-1]:
        start = interpolate_poses(ref.stamp, ref.poses, np.array([frames[0].stamp]))[0]
    rng = np.random.default_rng(seed)
    slam = RBPHDSlam(model, mount, cfg, rng, start)
    hot = None
    if profile.hotelling is not None and profile.detector.kind == "circle2d":
        hot = HotellingParams.model_validate(profile.hotelling.model_dump(include=set(HotellingParams.model_fields)))
    ang = sensor.angles() if log.scans is not None else None
    truth_xy = log.landmarks.xy if log.landmarks is not None else None
    n = len(frames)
    times, counts, ess, res_, comp, osp = (np.zeros(n), np.zeros(n, np.int64), np.zeros(n), np.zeros(n, bool), np.zeros(n), np.full(n, np.nan))
    mean_traj = np.zeros((n, 3))
    it = range(n) if progress is None else progress(range(n), n, "RB-PHD-SLAM")
    for k in it:
        fr = frames[k]
        t0 = time.perf_counter()
        if k > 0 and fr.odometry.stop > fr.odometry.start:  # the start pose is the first frame's
            slam.predict(_mover(log, fr.odometry, motion or {}))
        if fr.kind == "scan":
            scan = log.scans.ranges[fr.rows]
            det = detect_circles(scan, ang, profile.detector.circle, hot, sensor.range_sigma)
            z = np.column_stack([det.range, det.bearing])
            ratio = None
            if cfg.descriptor_likelihood and hot is not None:
                desc = det.descriptors(tuple(hot.names))
                ratio = model.g_true(desc) / np.maximum(model.g_false(desc), 1e-300)
            info = slam.update(z, scan, det.cov, ratio)
        else:
            d = log.detections
            z = np.column_stack([d.range[fr.rows], d.bearing[fr.rows]])
            info = slam.update(z)
        times[k] = (time.perf_counter() - t0) * 1e3
        counts[k], ess[k], res_[k], comp[k] = info.n_measurements, info.ess, info.resampled, info.components
        mean_traj[k] = slam.mean_pose()
        if truth_xy is not None:
            osp[k] = ospa(slam.map_estimate()[0], truth_xy, ospa_c, ospa_p)
    traj = slam.trajectory()[1:]
    map_xy, map_w = slam.map_estimate()
    res = SlamResult(np.array([f.stamp for f in frames]), traj, mean_traj, map_xy, map_w, times, counts, ess, res_, comp, osp, start)
    res.metrics = evaluate(log, res, ospa_c, ospa_p)
    return res


def odometry_trajectory(log: SensorLog, stamps: np.ndarray, start: np.ndarray) -> np.ndarray:
    """Dead reckoning at ``stamps`` (T,) from ``start``: the motion model without noise."""
    out = np.zeros((stamps.size, 3))
    pose = np.asarray(start, dtype=np.float64)[None].copy()
    o = log.odometry
    j = 0
    for k, t in enumerate(stamps):
        stop = int(np.searchsorted(o.stamp, t, side="right"))
        if stop > j:
            pose = _mover(log, slice(j, stop), {"increment": {"noise": False}, "velocity": {"noise": False}, "ackermann": {"noise": False}})(pose, None)
            j = stop
        out[k] = pose[0]
    return out


def dead_reckoning(log: SensorLog, res: SlamResult) -> np.ndarray:
    """(T, 3) the odometry alone through the run's frames, from the filter's start pose."""
    odo = odometry_trajectory(log, res.stamps, np.zeros(3))
    return compose(res.start, relative(odo[0], odo))


def evaluate(log: SensorLog, res: SlamResult, c: float = 1.0, p: float = 1.0) -> dict:
    """Trajectory RMSE and map OSPA / GOSPA, each beside dead reckoning from the same start.

    No rigid alignment is applied: the filter starts at the reference's first
    pose, so map and truth share a frame. Where the reference is GPS (no
    heading), the comparison is over the GPS fixes inside the run.
    """
    out: dict = {
        "frames": int(res.stamps.size),
        "ms_per_step_mean": float(res.step_ms.mean()),
        "ms_per_step_median": float(np.median(res.step_ms)),
        "resampled_steps": int(res.resampled.sum()),
    }
    odo = res.odometry = dead_reckoning(log, res)
    for key in ("ground_truth", "gps"):
        ref = log.reference.get(key)
        if ref is None:
            continue
        align = key == "gps" and "ground_truth" not in log.reference
        out[f"alignment_vs_{key}"] = "rigid (best fit; GPS gives no heading)" if align else "none (started at the true pose)"
        at = res.stamps if key == "ground_truth" else ref.stamp[(ref.stamp >= res.stamps[0]) & (ref.stamp <= res.stamps[-1])]
        inside = (at >= ref.stamp[0]) & (at <= ref.stamp[-1])
        at = at[inside]
        if at.size == 0:
            continue
        truth = interpolate_poses(ref.stamp, ref.poses, at)
        est = interpolate_poses(res.stamps, res.trajectory, at)
        dr = interpolate_poses(res.stamps, odo, at)
        out[f"trajectory_rmse_vs_{key}_m"] = trajectory_rmse(est, truth, align)
        out[f"mean_trajectory_rmse_vs_{key}_m"] = trajectory_rmse(interpolate_poses(res.stamps, res.mean_trajectory, at), truth, align)
        out[f"odometry_rmse_vs_{key}_m"] = trajectory_rmse(dr, truth, align)
        out[f"points_vs_{key}"] = int(at.size)
    if log.landmarks is not None:
        out["map_ospa"] = ospa(res.map_xy, log.landmarks.xy, c, p)
        out["map_gospa"] = gospa(res.map_xy, log.landmarks.xy, c, p)["gospa"]
        out["map_features"] = int(res.map_xy.shape[0])
        out["landmarks_true"] = int(log.landmarks.xy.shape[0])
        out["ospa_c_m"], out["ospa_p"] = c, p
    return out
