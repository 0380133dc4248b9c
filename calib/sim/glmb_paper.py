"""``glmb-paper``: the simulation of the delta-GLMB-SLAM paper (Moratuwage, Adams & Inostroza, sec. IV, Table I).

A car-like robot drives a pre-planned path among 23 point landmarks:

* a closed loop of waypoints (a 24 m x 16 m circuit, then 14 m along its
  first side again, so the end of the run closes the loop), followed at
  ``speed`` = 1 m/s by steering towards the current waypoint (steering at most
  ``max_steer`` = 30 deg, changing by at most ``steer_rate`` = 20 deg/s; the next
  waypoint is taken within ``switch`` of the current one);
* the vehicle moves as a bicycle of wheelbase ``wheelbase`` (the Ackermann
  model of :class:`slam_runtime.vehicle.Ackermann`, rear-axle frame), controls
  every ``dt``; the logged controls are the true ones plus Gaussian noise
  sigma_v = 0.1 m/s and sigma_steer = 2 deg per control step (Table I);
* the sensor sees the full circle (bearing -pi..pi) out to 3 m, every
  ``observe_every`` control steps; each landmark in range is detected
  with P_D = 0.7, its range and bearing with noise sigma_r = 0.3 m and
  sigma_b = 2 deg (Table I) (a noisy range may exceed 3 m);
* Poisson clutter of ``clutter`` points per scan (1, 5, 10 or 15 in the
  paper), uniform in range [0, 3] m and bearing [-pi, pi).

The controls, the detections and the clutter are drawn from three separate
streams of the seed, so the logs of one seed at the four clutter rates share
the same path, control noise and landmark detections and differ only in their
clutter, as the paper's four runs do. :func:`truth_profile` states the
simulator's detection statistics (P_D, clutter, noise) as a detector profile.
Same config and seed, same bytes.

The paper does not state the vehicle geometry, the control and scan periods or
the path; the defaults are those of Bailey's MATLAB EKF/FastSLAM simulators
(the family the paper's Table I parameters come from: speed, steering noise,
range-bearing noise): wheelbase 4 m, controls every 0.025 s, a scan every
8 controls (0.2 s), steering at most 30 deg changing by 20 deg/s. The circuit
and the landmark layout are this project's (the paper's figure is not
reproducible from its text).
"""

from __future__ import annotations

import dataclasses

import numpy as np

from calib.sim import SIMULATORS, Option, Simulated, Simulator, truth_provenance, with_truth
from detectors.sensor_log import Detections, Landmarks, Odometry, ReferencePoses, SensorLog, SensorModel, Vehicle, wrap_angle
from profiles.errors import UsageError
from profiles.parameters import GlmbPaperConfig

def sensor_model(cfg: GlmbPaperConfig) -> SensorModel:
    """The sensor as the filter sees it: its reports reach 4 range sigmas past the detection range (noise)."""
    return SensorModel(kind="detector", range_min=0.0, range_max=reach(cfg), fov=2 * np.pi, range_sigma=cfg.sigma_range)


def reach(cfg: GlmbPaperConfig) -> float:
    """The largest range a detection reports: the detection range plus 4 sigma of range noise [m]."""
    return float(cfg.range_max + 4.0 * cfg.sigma_range)


def drive(cfg: GlmbPaperConfig) -> tuple[np.ndarray, np.ndarray]:
    """The true path: poses (N + 1, 3) at every control step and the commands (N, 2) (speed, steering)
    applied from each pose to the next (bicycle model, rear-axle frame)."""
    wp = np.asarray(cfg.waypoints, dtype=np.float64)
    pose = np.zeros(3)
    poses, cmds = [pose.copy()], []
    steer, i = 0.0, 0
    for _ in range(cfg.max_steps):
        last = i == len(wp) - 1
        if np.hypot(*(wp[i] - pose[:2])) < (cfg.arrive if last else cfg.switch):
            if last:
                break
            i += 1
        err = wrap_angle(np.arctan2(wp[i, 1] - pose[1], wp[i, 0] - pose[0]) - pose[2])
        want = float(np.clip(err, -cfg.max_steer, cfg.max_steer))
        step = cfg.steer_rate * cfg.dt
        steer = float(np.clip(want, steer - step, steer + step))
        v = cfg.speed
        pose = np.array(
            [pose[0] + cfg.dt * v * np.cos(pose[2]), pose[1] + cfg.dt * v * np.sin(pose[2]), wrap_angle(pose[2] + cfg.dt * v / cfg.wheelbase * np.tan(steer))]
        )
        poses.append(pose)
        cmds.append((v, steer))
    return np.array(poses), np.array(cmds, dtype=np.float64).reshape(-1, 2)


def simulate_glmb_paper(cfg: GlmbPaperConfig, seed: int, clutter_draw: int | None = None) -> SensorLog:
    """One run of the scenario as a detection-level log with truth (poses at every control step, landmarks).

    ``clutter_draw`` (>= 0) draws the false alarms from another stream and keeps the path, the controls and the
    detections of ``seed``: the same world under other clutter (None: the seed's own clutter stream)."""
    rng_ctrl, rng_det, rng_clut = (np.random.default_rng(s) for s in np.random.SeedSequence(seed).spawn(3))
    if clutter_draw is not None:
        if isinstance(clutter_draw, bool) or not isinstance(clutter_draw, (int, np.integer)) or clutter_draw < 0:
            raise UsageError(f"simulate_glmb_paper: clutter_draw must be an integer >= 0 or None, not {clutter_draw!r}")
        # the seed's child stream 3 + draw (children 0-2 are the streams above; a fourth stream added to the
        # simulator would have to be spawned past the draws' keys, or it would share draw 0's)
        rng_clut = np.random.default_rng(np.random.SeedSequence(seed, spawn_key=(3 + int(clutter_draw),)))
    poses, cmds = drive(cfg)
    n = cmds.shape[0]
    # logged controls: row k holds from t_k to t_k+1 (the command that moved pose k to pose k + 1)
    noisy = cmds + rng_ctrl.standard_normal(cmds.shape) * [cfg.sigma_v, cfg.sigma_steer]
    stamps = np.arange(n + 1, dtype=np.int64) * int(round(cfg.dt * 1e9))
    odo = np.vstack([noisy, noisy[-1:]])  # the last row is held past the end of the run
    # scans at every observe_every-th control step, from the first pose on
    at = np.arange(0, n + 1, cfg.observe_every)
    sp = poses[at]
    lm = np.asarray(cfg.landmarks, dtype=np.float64)
    d = lm[None, :, :] - sp[:, None, :2]
    r_true = np.hypot(d[..., 0], d[..., 1])
    b_true = wrap_angle(np.arctan2(d[..., 1], d[..., 0]) - sp[:, None, 2])
    seen = (r_true >= cfg.range_min) & (r_true <= cfg.range_max) & (rng_det.uniform(size=r_true.shape) < cfg.pd)
    zr = r_true + rng_det.standard_normal(r_true.shape) * cfg.sigma_range
    zb = wrap_angle(b_true + rng_det.standard_normal(r_true.shape) * cfg.sigma_bearing)
    # a landmark in range is detected and its measurement kept whatever the noise (as the MATLAB simulators
    # do: a noisy range may exceed the range limit); only a negative range is impossible
    keep = seen & (zr > 0.0)
    nc = rng_clut.poisson(cfg.clutter, at.size)
    ck = np.repeat(np.arange(at.size), nc)
    cr = rng_clut.uniform(cfg.range_min, cfg.range_max, ck.size)
    cb = rng_clut.uniform(-np.pi, np.pi, ck.size)
    kk, ll = np.nonzero(keep)
    frame = np.concatenate([kk, ck])
    order = np.argsort(frame, kind="stable")
    det = Detections(
        stamps[at],
        frame[order].astype(np.int64),
        np.concatenate([zr[keep], cr])[order],
        np.concatenate([zb[keep], cb])[order],
        {"landmark": np.concatenate([ll + 1, np.zeros(ck.size, np.int64)])[order].astype(np.int64)},
    )
    return SensorLog(
        name=f"glmb_paper_c{cfg.clutter:g}_{seed}",
        sensor=sensor_model(cfg),
        odometry=Odometry("ackermann", stamps, odo),
        reference={"ground_truth": ReferencePoses("ground_truth", stamps, poses)},
        landmarks=Landmarks(np.arange(1, lm.shape[0] + 1, dtype=np.int64), lm),
        detections=det,
        vehicle=Vehicle(wheelbase=cfg.wheelbase, encoder_offset=0.0),
        source={
            "reader": "simulate glmb-paper",
            "seed": int(seed),
            "config": cfg.model_dump(mode="json"),
            **({} if clutter_draw is None else {"clutter_draw": int(clutter_draw)}),
        },
    )


def with_steering_bias(log: SensorLog, bias: float) -> SensorLog:
    """The log with ``bias`` [rad] added to every steering reading of its Ackermann odometry (the truth unchanged): a
    vehicle whose steering offset the filter has to find."""
    values = log.odometry.values.copy()
    values[:, 1] += bias
    return dataclasses.replace(log, odometry=dataclasses.replace(log.odometry, values=values))


def oracle_noise(cfg: GlmbPaperConfig) -> dict:
    """The simulator's noise as :func:`slam_runtime.oracle.batch_oracle` takes it: control (speed, steering),
    range and bearing sigmas."""
    return {"odometry_sigma": (cfg.sigma_v, cfg.sigma_steer), "range_sigma": cfg.sigma_range, "bearing_sigma": cfg.sigma_bearing}


def truth_profile(cfg: GlmbPaperConfig, *, name: str | None = None, version: str = "1.0.0"):
    """The profile of the simulated detector's true statistics (P_D, clutter, noise)."""
    from profiles.profile import DetectorProfile, DetectorSpec
    from profiles.schema import ClutterParams, MeasurementNoise, PdTable

    # P_D 0.7 out to the detection range (by the landmark's true range), 0 beyond, over a field of view that
    # reaches as far as a noisy report can; the clutter lies in [range_min, range_max], so its intensity there
    # is clutter / ((range_max - range_min) 2 pi): the profile's rate is scaled to the whole field of view
    # (beyond range_max the filter then assumes a little clutter where there is none, which costs nothing)
    far = reach(cfg)
    vol = far * 2 * np.pi
    rate = cfg.clutter * far / (cfg.range_max - cfg.range_min)
    edges, pds = ([cfg.range_min, cfg.range_max, far], [cfg.pd, 0.0]) if cfg.range_min == 0.0 else ([0.0, cfg.range_min, cfg.range_max, far], [0.0, cfg.pd, 0.0])
    return DetectorProfile(
        name=name or f"glmb-paper-c{cfg.clutter:g}".replace(".", "p"),
        version=version,
        description="The glmb-paper scenario's true detection statistics (the simulator's settings, not a calibration).",
        detector=DetectorSpec(kind="external"),
        sensor=sensor_model(cfg),
        pd=PdTable(covariate="range", edges=edges, pd=pds, clamping="none (simulator truth)"),
        clutter=ClutterParams(rate=rate, volume=vol),
        noise=MeasurementNoise(range_sigma=cfg.sigma_range, bearing_sigma=cfg.sigma_bearing),
        provenance=truth_provenance(cfg, "detcal simulate glmb-paper"),
    )


def summary(log: SensorLog, cfg: GlmbPaperConfig) -> dict:
    d = log.detections
    lab = np.asarray(d.descriptors["landmark"])
    poses = log.reference["ground_truth"].poses
    return {
        "control_steps": int(poses.shape[0] - 1),
        "scans": int(d.n_frames),
        "duration_s": float((poses.shape[0] - 1) * cfg.dt),
        "path_length_m": float(np.sum(np.hypot(*np.diff(poses[:, :2], axis=0).T))),
        "landmarks": len(cfg.landmarks),
        "landmarks_seen": int(np.unique(lab[lab > 0]).size),
        "detections": int(len(d)),
        "false_alarms": int((lab == 0).sum()),
        "false_alarms_per_scan": float((lab == 0).sum() / max(d.n_frames, 1)),
    }


def _run(cfg: GlmbPaperConfig, seed: int, progress=None) -> Simulated:
    log = simulate_glmb_paper(cfg, seed)
    return with_truth(log, {"seed": seed, **summary(log, cfg)}, truth_profile(cfg))


SIMULATORS.add("glmb-paper", Simulator(
    GlmbPaperConfig, "glmb_paper",
    "The delta-GLMB-SLAM paper's simulation: 23 landmarks beside a pre-planned loop, v = 1 m/s, range-bearing sensor 0-3 m "
    "over the full circle, P_D 0.7, noise 0.3 m / 2 deg, Poisson clutter; writes the log and the profile of its true statistics.",
    "glmb-paper scenario", _run, Option("clutter", float, "False alarms per scan (the paper: 1, 5, 10, 15; default: the config's, 5)."),
))  # fmt: skip
