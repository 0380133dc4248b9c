"""Run a SLAM filter over a log, then evaluate it: run -> evaluate -> write (the CLI writes).

Takes a :class:`detectors.sensor_log.SensorLog` in memory and a profile object; no
file paths. :func:`build` turns the settings into a vehicle model, a feature
model, the profile's detection model, a map filter and a measurement source;
:func:`run_slam` drives the particle loop (:class:`slam_runtime.slam.RBSlam`)
frame by frame and records what happened; :func:`evaluate` compares the
result with the log's truth (trajectory RMSE beside dead reckoning, map
OSPA/GOSPA); per-step figures that need the truth come from hooks the caller
passes (:class:`MapOSPA`). The start pose is the log's first ground-truth pose
when it has one (so the map and the truth share a frame), else the origin.
"""

from __future__ import annotations

import re

import time
from dataclasses import dataclass, field

import numpy as np

from detectors.geometry import compose, interpolate_poses, relative, rigid_transform
from detectors.kinds import DETECTORS
from detectors.sensor_log import SensorLog
from profiles.errors import DataError, UsageError
from profiles.schema import PD_COVARIATES
from slam_runtime.config import SlamConfig, detection_model, feature_model, map_filter, vehicle_model
from slam_runtime.metrics import axis_rmse, gospa, ospa, trajectory_rmse
from slam_runtime.refine import refine_map
from slam_runtime.slam import RBSlam, resolve_proposal
from slam_runtime.sources import control_rows, delayed, frames
from slam_runtime.vehicle import VEHICLE_MODELS


@dataclass
class SlamResult:
    """What one run produced; every per-step array has one row per frame (T)."""

    filter: str
    stamps: np.ndarray  # (T,) frame stamps [ns]
    trajectory: np.ndarray  # (T, 3) the best particle's vehicle poses (its whole history), world frame
    mean_trajectory: np.ndarray  # (T, 3) the weighted mean of the particles at each step
    map_xy: np.ndarray  # (K, 2) the best particle's map estimate
    map_w: np.ndarray  # (K,)
    step_ms: np.ndarray  # (T,) wall time of the filter per frame (motion and update; the detector's time is stage_ms['detect'])
    n_measurements: np.ndarray  # (T,)
    ess: np.ndarray  # (T,) effective sample size after the update
    resampled: np.ndarray  # (T,) bool
    components: np.ndarray  # (T,) mean components per particle
    start: np.ndarray  # (3,) the pose the filter started from
    resample_ms: np.ndarray = field(default_factory=lambda: np.zeros(0))  # (T,) the resampling stage's time per frame
    step_cpu_ms: np.ndarray = field(default_factory=lambda: np.zeros(0))  # (T,) the process's CPU time per frame (fair on a loaded machine)
    stage_ms: dict = field(default_factory=dict)  # total ms per stage (detect, predict, pd, update, weight, merge, resample)
    capped_steps: int = 0  # steps at which the component cap bound
    per_step: dict = field(default_factory=dict)  # what hooks recorded, name -> (T,)
    map_all_xy: np.ndarray | None = None  # (K', 2) every component of the best particle's map, however light
    map_all_w: np.ndarray | None = None  # (K',)
    map_filter_xy: np.ndarray | None = None  # (K, 2) the filter's own map estimate, where map_xy was refined (map_refine)
    refine_iterations: int = 0
    log_evidence: float = float("nan")  # the run's log p(Z_1:T) up to the clutter model's constant (RBSlam.log_evidence)
    odometry: np.ndarray | None = None  # (T, 3) dead reckoning through the same frames (set by evaluate)
    metrics: dict = field(default_factory=dict)


def check_inputs(log: SensorLog, profile) -> None:
    """Refuse a log this profile cannot run on: the measurements it needs, odometry, and for an
    n_p table the beam geometry it was measured with (it holds for no other)."""
    kind = DETECTORS.get(profile.detector.kind)
    if getattr(log, kind.stream) is None:
        raise UsageError(f"{log.name}: profile {profile.ref} {kind.needs}, and this log has none")
    if log.odometry is None:
        raise UsageError(f"{log.name}: no odometry to drive the filter")
    if PD_COVARIATES.get(profile.pd.covariate).ray_traced and log.sensor is not None:
        _same_beams(profile, log.sensor)


def _same_beams(profile, sensor) -> None:
    """A ray-traced table (n_p) holds only for the beam layouts it was measured with: the log's must be among them."""
    theirs = profile.sensor.layouts()
    for g in sensor.layouts():
        if not any(
            g.n_beams == t.n_beams and np.isclose(g.angle_min, t.angle_min, atol=1e-6) and np.isclose(g.angle_increment, t.angle_increment, atol=1e-9)
            for t in theirs
        ):
            t = theirs[0]
            raise UsageError(
                f"profile {profile.ref} was calibrated for {t.n_beams} beams from {np.degrees(t.angle_min):.2f} deg every "
                f"{np.degrees(t.angle_increment):.4f} deg"
                + (f" (and {len(theirs) - 1} more layouts)" if len(theirs) > 1 else "")
                + f"; this log's laser has {g.n_beams} from {np.degrees(g.angle_min):.2f} deg every {np.degrees(g.angle_increment):.4f} deg "
                "(calibrate a profile for this laser with detcal calibrate)"
            )


@dataclass
class Built:
    vehicle: object
    mapfilter: object
    measure: object
    mount: np.ndarray


def check_features(profile, cfg: SlamConfig, planes: str = "--features planes") -> None:
    """A profile goes with the features its detector makes (plane profiles with ``features: planes``, the others with
    points); ``planes`` is how the command sets planes."""
    made = DETECTORS.get(profile.detector.kind).features
    planar = made == "planes"
    if made != cfg.features:
        raise UsageError(
            f"profile {profile.ref} is a {profile.kind} profile; "
            + (f"run it with {planes}" if planar else f"{planes} needs a lidar3d-planes profile")
        )


def build(log: SensorLog, profile, cfg: SlamConfig) -> Built:
    """The models, the map filter and the measurement source of a run (the factory of the settings)."""
    sensor = (log.sensor if log.sensor is not None else profile.sensor).turned(cfg.mount_yaw)
    mount = np.array([sensor.mount.x, sensor.mount.y, sensor.mount.theta])
    check_features(profile, cfg)
    det = detection_model(profile, cfg.detection, None, filter_kind=cfg.filter.kind)
    feat = feature_model(cfg.features, det, cfg.measurement, mount, cfg.metric)
    mf = map_filter(cfg, feat, det)
    veh = vehicle_model(log.odometry.kind, cfg.motion, log.vehicle, cfg.features)
    detector = DETECTORS.get(profile.detector.kind)
    ids = uses_identities(cfg, detector.reads_identities(log), mf)
    measure = detector.source(log, profile, det, cfg.detection, identities=True) if ids else detector.source(log, profile, det, cfg.detection)
    return Built(veh, mf, measure, mount)


def uses_identities(cfg: SlamConfig, readable: bool, mf) -> bool:
    """Whether the run takes the identities its detections read (``detection.identities``): ``on`` refuses a log whose
    detections carry none (``readable``) and a filter that does not take them."""
    mode = cfg.detection.identities
    if mode == "on" and not readable:
        raise UsageError("detection.identities: on, but this log's detections name no landmark (no identity to read)")
    if mode == "on" and not mf.takes_identities:
        raise UsageError(f"detection.identities: on, but the {mf.name} filter does not take identities (RB-PHD, LMB and delta-GLMB do)")
    return mode != "off" and readable and mf.takes_identities


def start_pose(log: SensorLog, stamp: int) -> np.ndarray:
    """The true pose at ``stamp`` when the log has ground truth there; the first true pose when the first frame comes
    before the ground truth starts (a UTIAS log whose camera starts before the motion capture: the origin would be a
    pose the robot never had, and every error would be measured from it); else the origin (GPS gives no heading)."""
    ref = log.reference.get("ground_truth")
    if ref is not None and ref.stamp[0] <= stamp <= ref.stamp[-1]:
        return interpolate_poses(ref.stamp, ref.poses, np.array([stamp]))[0]
    if ref is not None and stamp < ref.stamp[0] and np.isfinite(ref.poses[0]).all():
        return ref.poses[0].astype(np.float64).copy()
    return np.zeros(3)


def ground_truth_poses(log: SensorLog, stamps: np.ndarray) -> np.ndarray:
    """(frames, 3) the vehicle's pose (x, y, heading) at each frame's stamp, interpolated in the log's ground truth
    (at the vehicle's reference point: a reference given at another point is moved back by its lever arm): the path
    that ``poses: ground_truth`` puts the particles on. Refused, naming the log and the frame, when the log has no
    ground truth or a frame falls outside its time span (interpolation there would be a guess)."""
    ref = log.reference.get("ground_truth")
    if ref is None:
        have = ", ".join(sorted(log.reference)) or "none"
        raise DataError(f"log {log.name!r}: poses: ground_truth needs ground-truth poses, and the log has none (its references: {have})")
    no_heading = np.flatnonzero(~np.isfinite(ref.poses[:, 2]))
    if no_heading.size:
        raise DataError(
            f"log {log.name!r}: reference[ground_truth].poses[{int(no_heading[0])}]: heading is not finite "
            f"({no_heading.size} of {ref.stamp.size} rows); poses: ground_truth needs the heading at every row"
        )
    stamps = np.asarray(stamps, dtype=np.int64)
    outside = np.flatnonzero((stamps < ref.stamp[0]) | (stamps > ref.stamp[-1]))
    if outside.size:
        k = int(outside[0])
        span = (int(ref.stamp[0]) - int(stamps[0])) / 1e9, (int(ref.stamp[-1]) - int(stamps[0])) / 1e9
        raise DataError(
            f"log {log.name!r}, frame {k} (t = {(int(stamps[k]) - int(stamps[0])) / 1e9:.2f} s): outside the ground truth's "
            f"time span ({span[0]:.2f} to {span[1]:.2f} s; {outside.size} of {stamps.size} frames outside); poses: ground_truth "
            "needs the truth at every frame (--frames N runs the first N only)"
        )
    poses = interpolate_poses(ref.stamp, ref.poses, stamps)
    if any(ref.point):
        poses = compose(poses, np.array([-ref.point[0], -ref.point[1], 0.0]))
    return poses


def check_poses(log: SensorLog, cfg: SlamConfig, max_frames: int | None = None) -> None:
    """With ``poses: ground_truth``, refuse up front a log whose frames (the first ``max_frames``) the ground truth
    does not span (:func:`ground_truth_poses`); nothing to check otherwise."""
    if cfg.poses == "ground_truth":
        ground_truth_poses(log, log.frame_stamps()[:max_frames])


class MapOSPA:
    """Hook: OSPA of the best particle's map against the truth after every step (evaluation, not filtering).

    distance: the base distance of the OSPA (default Euclidean; planes pass theirs)."""

    name = "map_ospa"

    def __init__(self, truth_xy: np.ndarray, c: float = 1.0, p: float = 1.0, every: int = 1, distance=None) -> None:
        self.truth, self.c, self.p, self.every, self.distance = truth_xy, c, p, every, distance

    def __call__(self, k: int, slam: RBSlam) -> float:
        if k % self.every:
            return np.nan
        return ospa(slam.mf.feature.position(slam.map_estimate()[0]), self.truth, self.c, self.p, self.distance)


class LogEvidence:
    """Hook: the run's log marginal likelihood of the measurements so far, log p(Z_1:k) up to a constant that
    depends only on the clutter model (sum over steps of the log normaliser of the particle weights; with the
    optimal proposal the weights include prior / proposal). Settings of one filter on one log compare by it
    without ground truth: the larger, the better the model explains the measurements."""

    name = "log_evidence"

    def __call__(self, k: int, slam: RBSlam) -> float:
        return float(slam.log_evidence)


class SteeringOffset:
    """Hook: the heaviest particle's estimated steering offset [rad] (``motion.ackermann.steer_offset_sd`` > 0; else NaN)."""

    name = "steer_offset"

    def __call__(self, k: int, slam: RBSlam) -> float:
        return float(slam.x[slam.best(), 3]) if slam.vehicle.adaptive else float("nan")


def run_slam(
    log: SensorLog,
    profile,
    cfg: SlamConfig,
    seed: int,
    *,
    progress=None,
    max_frames: int | None = None,
    hooks: tuple = (),
) -> SlamResult:
    """Run the filter ``cfg.filter`` over every frame (or the first ``max_frames``) of ``log``.

    hooks: callables ``hook(k, slam) -> float`` called after every step, recorded
    under ``hook.name`` in ``per_step`` (e.g. :class:`MapOSPA`).
    ``cfg.poses: ground_truth`` puts every particle at the log's ground-truth pose (:func:`ground_truth_poses`)
    before each frame's update (:meth:`RBSlam.place`): mapping only, the map filter alone with the path given.
    """
    check_inputs(log, profile)
    b = build(log, profile, cfg)
    log = delayed(log, b.vehicle.delay)
    stamps = log.frame_stamps()[:max_frames]
    n = stamps.size
    if n == 0:
        raise DataError(f"log {log.name!r}: no scans or detections to run on")
    poses = ground_truth_poses(log, stamps) if cfg.poses == "ground_truth" else None
    start = start_pose(log, int(stamps[0]))
    slam = RBSlam(
        b.vehicle, b.mapfilter, cfg.particles, start, np.random.default_rng(seed),
        resampler=cfg.resampler, resample_ess=cfg.resample_ess, resample_every=cfg.resample_every, proposal=cfg.proposal,
        islands=cfg.islands, island_match=cfg.island_match,
    )
    times, counts, ess_, res_, comp, rs_ms, cpu = (np.zeros(n), np.zeros(n, np.int64), np.zeros(n), np.zeros(n, bool), np.zeros(n), np.zeros(n), np.zeros(n))
    mean_traj = np.zeros((n, 3))
    per_step = {h.name: np.full(n, np.nan) for h in hooks}
    detect_s = 0.0
    kept: list = []  # every frame's measurements, for map_refine
    it = frames(log, b.measure, n)
    if progress is not None:
        it = progress(it, n, b.mapfilter.name + "-SLAM")
    t_prev = time.perf_counter()
    for fi in it:  # the source detects (laser) while the loop advances: that time is the "detect" stage
        k = fi.index
        t0 = time.perf_counter()
        c0 = time.process_time()
        detect_s += t0 - t_prev
        if fi.controls.shape[0]:
            slam.predict(fi.controls, fi.dts)
        if poses is not None:
            slam.place(poses[k])
        try:
            info = slam.update(fi.meas)
        except FloatingPointError as exc:  # every particle at zero weight: the filter cannot go on
            raise DataError(
                f"log {log.name!r}, frame {k} (t = {(int(stamps[k]) - int(stamps[0])) / 1e9:.2f} s): {exc}: no particle explains "
                "this frame's measurements; widen the measurement or motion noise (--config), use more particles, or check the profile"
            ) from None
        times[k] = (time.perf_counter() - t0) * 1e3
        cpu[k] = (time.process_time() - c0) * 1e3
        counts[k], ess_[k], res_[k], comp[k], rs_ms[k] = info.n_measurements, info.ess, info.resampled, info.components, info.resample_ms
        mean_traj[k] = slam.mean_pose()
        for h in hooks:
            per_step[h.name][k] = h(k, slam)
        if cfg.map_refine:
            kept.append(fi.meas)
        t_prev = time.perf_counter()
    traj = b.vehicle.pose(slam.trajectory())[1:]
    est_x, est_w = slam.map_estimate()
    all_x, all_w = b.mapfilter.components(slam.maps, slam.best())
    stage = {"detect": detect_s * 1e3, **{k: v * 1e3 for k, v in slam.time.items()}, **{k: v * 1e3 for k, v in b.mapfilter.timers.total.items()}}
    map_xy = b.mapfilter.feature.position(est_x)
    filter_xy, refine_it = None, 0
    if cfg.map_refine:
        t0 = time.perf_counter()
        filter_xy = map_xy
        map_xy, refine_it = refine_map(b.mapfilter, traj, kept, map_xy)
        stage["refine"] = (time.perf_counter() - t0) * 1e3
    return SlamResult(
        b.mapfilter.name, stamps, traj, mean_traj, map_xy, est_w, times, counts, ess_, res_, comp, start,
        resample_ms=rs_ms, step_cpu_ms=cpu, stage_ms=stage, capped_steps=b.mapfilter.capped_steps, per_step=per_step,
        map_all_xy=b.mapfilter.feature.position(all_x), map_all_w=all_w, map_filter_xy=filter_xy, refine_iterations=refine_it,
        log_evidence=slam.log_evidence,
    )


def dead_reckoning(log: SensorLog, stamps: np.ndarray, start: np.ndarray, cfg: SlamConfig | None = None) -> np.ndarray:
    """(T, 3) the odometry alone at ``stamps`` (T,) from ``start``: the vehicle model without noise."""
    veh = vehicle_model(log.odometry.kind, (cfg or SlamConfig()).motion, log.vehicle)
    log = delayed(log, veh.delay)
    out = np.zeros((stamps.size, 3))
    x = veh.initial(np.zeros(3), 1)
    o = log.odometry
    j = 0
    for k, t in enumerate(stamps):
        stop = int(np.searchsorted(o.stamp, t, side="right"))
        if stop > j:
            u, dt = control_rows(log, slice(j, stop))
            if k > 0:  # the motion before the first frame is not the filter's either
                for uu, d in zip(u, dt, strict=True):
                    x = veh.mean(x, uu, float(d))
            j = stop
        out[k] = veh.pose(x)[0]
    return compose(start, relative(out[0], out))


#: Why a metric of :func:`evaluate` can be NaN (not defined for the run), by metric name pattern: what a summary
#: prints instead of ``nan``.
UNDEFINED_WHY: dict[str, str] = {
    r"final_position_error_vs_gps_m": "a rigid fit to GPS places the end; the whole path's RMSE is the measure",
    r"(mean_)?trajectory_rmse_vs_\w+_m|odometry_rmse_vs_\w+_m": "fewer than 3 reference points in the run; a rigid fit needs 3",
    r"cpu_ms_per_step_mean": "no step was timed",
    r"log_evidence": "this filter does not compute it",
    r"map_ospa\w*|map_gospa": "no map and no truth to compare",
}


def why_undefined(metric: str) -> str:
    """Why ``metric`` is NaN in a run's metrics (:data:`UNDEFINED_WHY`), or a plain 'not defined for this run'."""
    return next((why for pat, why in UNDEFINED_WHY.items() if re.fullmatch(pat, metric)), "not defined for this run")


def evaluate(log: SensorLog, res: SlamResult, c: float = 1.0, p: float = 1.0, cfg: SlamConfig | None = None) -> dict:
    """Trajectory RMSE and map OSPA / GOSPA, each beside dead reckoning from the same start.

    No rigid alignment is applied where the log has ground truth: the filter
    starts at its first pose, so map and truth share a frame. Where the
    reference is GPS (no heading), the comparison is over the GPS fixes inside
    the run, after the best rigid fit (said in the metrics).

    With ground truth the metrics are also given after the path's best rigid fit (``*_path_aligned``): the
    frame of a SLAM solution is fixed only by its first pose and the odometry before the first landmarks pin it
    (a heading drawn in the first seconds turns path and map together and the data cannot tell), so the fit of
    the estimated path onto the truth, the same transform applied to the map, measures the solution's shape
    apart from that gauge. The fit uses the path only: the map's figures stay a test of the map.
    """
    out: dict = {
        "filter": res.filter,
        "frames": int(res.stamps.size),
        "ms_per_step_mean": float(res.step_ms.mean()),
        "ms_per_step_median": float(np.median(res.step_ms)),
        "cpu_ms_per_step_mean": float(res.step_cpu_ms.mean()) if res.step_cpu_ms.size else float("nan"),
        "resampled_steps": int(res.resampled.sum()),
        "cap_bound_steps": int(res.capped_steps),
        # log p(Z_1:T) [nats] up to a constant of the clutter model (the profile's): runs of one profile on one log compare
        # by it without ground truth, the larger the likelier (LogEvidence)
        "log_evidence": float(res.log_evidence),
    }
    odo = res.odometry = dead_reckoning(log, res.stamps, res.start, cfg)
    gauge = None  # the path's best rigid fit onto the ground truth (3,)
    for key in ("ground_truth", "gps"):
        ref = log.reference.get(key)
        if ref is None:
            continue
        align = key == "gps" and "ground_truth" not in log.reference
        out[f"alignment_vs_{key}"] = "rigid (best fit; GPS gives no heading)" if align else "none (started at the true pose)"
        at = res.stamps if key == "ground_truth" else ref.stamp[(ref.stamp >= res.stamps[0]) & (ref.stamp <= res.stamps[-1])]
        at = at[(at >= ref.stamp[0]) & (at <= ref.stamp[-1])]
        if at.size == 0:
            continue
        truth = interpolate_poses(ref.stamp, ref.poses, at)
        # compared at the point of the vehicle the reference locates (a GPS antenna's lever arm turns with the heading)
        est = ref.at_point(interpolate_poses(res.stamps, res.trajectory, at))
        dr = ref.at_point(interpolate_poses(res.stamps, odo, at))
        if not ref.on_vehicle_point:
            out[f"reference_point_{key}_m"] = list(ref.point)
        # a rigid fit has three degrees of freedom: one point it fits exactly, two leave one residual; no RMSE is claimed
        # on fewer than three
        rmse = trajectory_rmse if not align or at.size >= 3 else (lambda *_: float("nan"))
        out[f"trajectory_rmse_vs_{key}_m"] = rmse(est, truth, align)
        mean = ref.at_point(interpolate_poses(res.stamps, res.mean_trajectory, at))
        out[f"mean_trajectory_rmse_vs_{key}_m"] = rmse(mean, truth, align)
        out[f"odometry_rmse_vs_{key}_m"] = rmse(dr, truth, align)
        if key == "ground_truth":  # per axis (the delta-GLMB-SLAM paper's figs. 2-4)
            rx, ry, rh = axis_rmse(est, truth)
            out[f"rmse_x_vs_{key}_m"], out[f"rmse_y_vs_{key}_m"], out[f"rmse_heading_vs_{key}_deg"] = rx, ry, float(np.degrees(rh))
            rx, ry, rh = axis_rmse(mean, truth)  # the particles' weighted mean pose at each step
            out[f"mean_rmse_x_vs_{key}_m"], out[f"mean_rmse_y_vs_{key}_m"], out[f"mean_rmse_heading_vs_{key}_deg"] = rx, ry, float(np.degrees(rh))
        out[f"final_position_error_vs_{key}_m"] = float(np.hypot(*(est[-1, :2] - truth[-1, :2]))) if not align else float("nan")
        if key == "ground_truth" and at.size >= 3:
            gauge = rigid_transform(est, truth)
            out["trajectory_rmse_vs_ground_truth_path_aligned_m"] = trajectory_rmse(compose(gauge, est), truth)
            out["path_alignment_deg"] = float(np.degrees(gauge[2]))
        out[f"points_vs_{key}"] = int(at.size)
    if log.planes is not None and res.map_xy.ndim == 2 and res.map_xy.shape[1] == 4:
        from slam_runtime.plane_metrics import plane_map_metrics

        out.update(plane_map_metrics(log, res.map_xy, c, p, (cfg or SlamConfig()).metric.plane_length))
    elif log.landmarks is not None:
        truth_xy = log.landmarks.xy
        out["map_ospa"] = ospa(res.map_xy, truth_xy, c, p)
        if res.map_filter_xy is not None:  # map_refine: the filter's own map beside the refined one
            out["map_ospa_filter"] = ospa(res.map_filter_xy, truth_xy, c, p)
            out["map_refine_iterations"] = int(res.refine_iterations)
        g = gospa(res.map_xy, truth_xy, c, p)
        out["map_gospa"] = g["gospa"]
        out["map_features"] = int(res.map_xy.shape[0])
        out["landmarks_true"] = int(truth_xy.shape[0])
        out["landmarks_mapped"] = int(truth_xy.shape[0] - g["n_missed"])
        out["ospa_c_m"], out["ospa_p"] = c, p
        # landmarks with a map feature within 0.3 m (GOSPA's assignment with c = 0.3 m), as mapped and after the path's fit
        out["landmarks_within_03_m"] = int(truth_xy.shape[0] - gospa(res.map_xy, truth_xy, 0.3, 1.0)["n_missed"])
        if gauge is not None:
            moved = compose(gauge, np.column_stack([res.map_xy[:, :2], np.zeros(res.map_xy.shape[0])]))[:, :2]
            out["map_ospa_path_aligned"] = ospa(moved, truth_xy, c, p)
            out["landmarks_within_03_m_path_aligned"] = int(truth_xy.shape[0] - gospa(moved, truth_xy, 0.3, 1.0)["n_missed"])
    out["stage_ms_per_step"] = {k: round(v / max(res.stamps.size, 1), 4) for k, v in res.stage_ms.items()}
    return out


def describe(log: SensorLog, profile, cfg: SlamConfig) -> dict[str, str]:
    """What a run of ``cfg`` on ``log`` with ``profile`` uses, one line per role: the filter, the vehicle model and its
    noise, the measurement noise floor, P_D and clutter, each with where it comes from (the settings, the profile or a
    model's defaults). ``detcal slam run`` prints it when it derived the settings."""
    b = build(log, profile, cfg)
    group = next(n for n, c in VEHICLE_MODELS.items() if isinstance(b.vehicle, c))
    noise = getattr(cfg.motion, group)
    given = {k: v for k, v in cfg.measurement.model_dump().items() if v is not None}
    sig = np.sqrt(np.diag(b.mapfilter.feature.r))
    src = "the settings" if given else ("the profile" if profile.noise is not None or cfg.features == "planes" else "the defaults")
    pd = profile.pd
    rows = {
        "filter": f"{b.mapfilter.name} ({cfg.filter.kind}), {cfg.particles} particles, "
        + f"{resolve_proposal(cfg.proposal, b.vehicle, b.mapfilter)} proposal" + (" (auto)" if cfg.proposal == "auto" else ""),
        "features": cfg.features,
        "motion": f"{b.vehicle.label} model for {log.odometry.kind} odometry, motion.{group}: "
        + ", ".join(f"{k} {v:g}" for k, v in noise.model_dump().items()),
        "measurement noise": f"{', '.join(f'{s:.4g}' for s in sig)} (sigmas of the measurement's components, from {src})",
        "P_D": f"constant {cfg.detection.constant_pd:g} in view" if cfg.detection.pd_mode == "constant"
        else f"the profile's {pd.covariate} table ({len(pd.edges) - 1} bins)",
        "clutter": f"{profile.clutter.rate:.4g} false alarms per frame ({profile.clutter.count_model}, the profile's)",
    }  # fmt: skip
    return rows
