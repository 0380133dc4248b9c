"""``rfs-sim``: the 2D range-bearing scenario of the open C++ RFS-SLAM library's RB-PHD-SLAM simulator.

Reproduces its ``rbphdslam2dSim`` scenario (config ``rbphdslam2dSim.xml``) so
detcal's filters can be compared with that reference on the same kind of data:

* time steps of ``dt`` = 0.1 s; the vehicle stands still for the first 50
  steps, then follows ``segments`` = 20 constant-velocity segments of equal
  length: forward speed U(min_dx, max_dx) = U(0.1, 0.3) m/s, no sideways
  motion, turn rate U(-0.5, 0.5) rad/s;
* ``landmarks`` = 50 landmarks, placed one every steps / 50 steps at a uniform
  range in [0, 2.5] m and a uniform bearing in [0, 2 pi) from the true pose of
  that step (so they line the path);
* odometry: the true increment plus Gaussian noise of variance
  var_odometry * dt^2 per axis (dx, dy, dtheta), var_odometry = 2e-3 (s^-1 as the
  library writes it: a velocity noise);
* measurements at every step after the first: each landmark's (range, bearing)
  with noise var_r = 5e-4 m^2, var_b = 5e-5 rad^2, kept when the noisy range
  lies in [0.5, 2.5] m, with probability P_D = 0.99; bearing over the full
  circle; Poisson clutter of intensity 1e-4 per m rad, uniform in range
  [0.5, 2.5] m and bearing [-pi, pi).

The sensor model is a detection-level sensor (kind ``detector``, full-circle
field of view, 0.5-2.5 m); :func:`truth_profile` is the profile that states
the simulator's own statistics (P_D, clutter, noise), the reference a
calibration of these logs should recover. Same config and seed, same bytes.
"""

from __future__ import annotations

import numpy as np

from calib.sim import SIMULATORS, Option, Simulated, Simulator, truth_provenance, with_truth
from detectors.geometry import compose
from detectors.sensor_log import Detections, Landmarks, Odometry, ReferencePoses, SensorLog, SensorModel, wrap_angle
from profiles.parameters import RfsSimConfig


def sensor_model(cfg: RfsSimConfig) -> SensorModel:
    return SensorModel(kind="detector", range_min=cfg.range_min, range_max=cfg.range_max, fov=2 * np.pi, range_sigma=float(np.sqrt(cfg.var_range)))


def simulate_rfs(cfg: RfsSimConfig, seed: int) -> SensorLog:
    """One run of the scenario as a detection-level log with truth (poses at every step, landmarks)."""
    rng = np.random.default_rng(seed)
    n, dt = cfg.steps, cfg.dt
    # the true increments: still, then piecewise constant
    inc = np.zeros((n, 3))
    seg_len = n // cfg.segments
    current = np.zeros(3)
    seg = 0
    for k in range(1, n):
        if k <= cfg.still_steps:
            continue
        if k >= seg_len * seg:
            seg += 1
            dx = rng.uniform(cfg.min_dx, cfg.max_dx) * dt
            dy = rng.uniform(-cfg.max_dy, cfg.max_dy) * dt
            dz = rng.uniform(-cfg.max_dtheta, cfg.max_dtheta) * dt
            current = np.array([dx, dy, dz])
        inc[k] = current
    poses = np.zeros((n, 3))
    for k in range(1, n):
        poses[k] = compose(poses[k - 1], inc[k])
    odo = inc + rng.standard_normal((n, 3)) * np.sqrt(cfg.var_odometry) * dt
    odo[0] = 0.0
    # landmarks along the path
    at = (np.arange(cfg.landmarks) * (n // cfg.landmarks)).clip(1, n - 1)
    r0 = rng.uniform(0.0, cfg.range_max, cfg.landmarks)
    b0 = rng.uniform(0.0, 2 * np.pi, cfg.landmarks)
    a = poses[at, 2] + b0
    lm = np.column_stack([poses[at, 0] + r0 * np.cos(a), poses[at, 1] + r0 * np.sin(a)])
    # measurements: every landmark from every pose, noisy, then range-limited and thinned by P_D
    d = lm[None, :, :] - poses[:, None, :2]
    rng_true = np.hypot(d[..., 0], d[..., 1])
    brg_true = wrap_angle(np.arctan2(d[..., 1], d[..., 0]) - poses[:, None, 2])
    zr = rng_true + rng.standard_normal(rng_true.shape) * np.sqrt(cfg.var_range)
    zb = wrap_angle(brg_true + rng.standard_normal(rng_true.shape) * np.sqrt(cfg.var_bearing))
    keep = (zr >= cfg.range_min) & (zr <= cfg.range_max) & (rng.uniform(size=zr.shape) <= cfg.pd)
    keep[0] = False  # the library measures from step 1 on
    lam = cfg.clutter_intensity * (cfg.range_max - cfg.range_min) * 2 * np.pi
    n_clutter = rng.poisson(lam, n)
    n_clutter[0] = 0
    ck = np.repeat(np.arange(n), n_clutter)
    cr = rng.uniform(cfg.range_min, cfg.range_max, ck.size)
    cb = rng.uniform(-np.pi, np.pi, ck.size)
    kk, _ = np.nonzero(keep)
    frame = np.concatenate([kk, ck])
    rr = np.concatenate([zr[keep], cr])
    bb = np.concatenate([zb[keep], cb])
    truth_label = np.concatenate([np.nonzero(keep)[1] + 1, np.zeros(ck.size, dtype=np.int64)])  # landmark id, 0 = clutter
    order = np.argsort(frame, kind="stable")
    stamps = (np.arange(n, dtype=np.int64) * int(round(dt * 1e9))).astype(np.int64)
    det = Detections(stamps, frame[order].astype(np.int64), rr[order], bb[order], {"landmark": truth_label[order].astype(np.int64)})
    return SensorLog(
        name=f"rfs_sim_{seed}",
        sensor=sensor_model(cfg),
        # the stated noise: a per-step std sqrt(var_odometry) dt on every axis, as a random walk sqrt(var_odometry dt) per sqrt(s)
        odometry=Odometry("increment", stamps, odo, (float(np.sqrt(cfg.var_odometry * dt)),) * 3),
        reference={"ground_truth": ReferencePoses("ground_truth", stamps, poses)},
        landmarks=Landmarks(np.arange(1, cfg.landmarks + 1, dtype=np.int64), lm),
        detections=det,
        source={"reader": "simulate rfs-sim", "seed": int(seed), "config": cfg.model_dump(mode="json")},
    )


def oracle_noise(cfg: RfsSimConfig) -> dict:
    """The simulator's noise as :func:`slam_runtime.oracle.batch_oracle` takes it: per-step increment sigmas
    (sqrt(var_odometry) x dt on each axis), range and bearing sigmas."""
    s = float(np.sqrt(cfg.var_odometry) * cfg.dt)
    return {"odometry_sigma": (s, s, s), "range_sigma": float(np.sqrt(cfg.var_range)), "bearing_sigma": float(np.sqrt(cfg.var_bearing))}


def truth_profile(cfg: RfsSimConfig, *, name: str = "rfs-sim", version: str = "1.0.0"):
    """The profile of the simulated detector's true statistics (P_D, clutter, noise)."""
    from profiles.profile import DetectorProfile, DetectorSpec
    from profiles.schema import ClutterParams, MeasurementNoise, PdTable

    vol = (cfg.range_max - cfg.range_min) * 2 * np.pi
    return DetectorProfile(
        name=name,
        version=version,
        description="The rfs-sim scenario's true detection statistics (the simulator's settings, not a calibration).",
        detector=DetectorSpec(kind="external"),
        sensor=sensor_model(cfg),
        pd=PdTable(covariate="range", edges=[cfg.range_min, cfg.range_max], pd=[cfg.pd], clamping="none (simulator truth)"),
        clutter=ClutterParams(rate=cfg.clutter_intensity * vol, volume=vol),
        noise=MeasurementNoise(range_sigma=float(np.sqrt(cfg.var_range)), bearing_sigma=float(np.sqrt(cfg.var_bearing))),
        provenance=truth_provenance(cfg, "detcal simulate rfs-sim"),
    )


def summary(log: SensorLog, cfg: RfsSimConfig) -> dict:
    d = log.detections
    clutter = int((np.asarray(d.descriptors["landmark"]) == 0).sum())
    poses = log.reference["ground_truth"].poses
    return {
        "steps": int(cfg.steps),
        "duration_s": float(cfg.steps * cfg.dt),
        "path_length_m": float(np.sum(np.hypot(*np.diff(poses[:, :2], axis=0).T))),
        "landmarks": int(cfg.landmarks),
        "detections": int(len(d)),
        "false_alarms": clutter,
        "measurements_per_step": float(len(d) / cfg.steps),
    }


def _run(cfg: RfsSimConfig, seed: int, progress=None) -> Simulated:
    log = simulate_rfs(cfg, seed)
    return with_truth(log, {"seed": seed, **summary(log, cfg)}, truth_profile(cfg))


SIMULATORS.add("rfs-sim", Simulator(
    RfsSimConfig, "rfs_sim",
    "The C++ RFS-SLAM library's 2D RB-PHD-SLAM scenario: 50 landmarks along a piecewise constant-velocity path, range-bearing "
    "sensor 0.5-2.5 m, P_D 0.99; writes the log and the profile of its true statistics.",
    "rfs-sim scenario", _run, Option("steps", int, "Time steps of 0.1 s (default: the config's, 1,000)."),
))  # fmt: skip
