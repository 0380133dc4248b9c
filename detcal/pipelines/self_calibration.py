"""The self-calibration loop: run SLAM, measure the detector (and the odometry's biases) against the
run's own map and trajectory, run again with what was measured, until the profile stops changing.

The measuring is injected (``measure``: :func:`calib.selfcal.self_calibrate` in
``detcal selfcal``); this module only alternates the two steps and keeps the
history. For Ackermann odometry the steering offset and the speed
scale are measured too (:func:`slam_runtime.vehicle.fit_ackermann_bias`) and go
into the next run's settings.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from detectors.logs import SensorLog
from slam_runtime.config import SlamConfig, override
from slam_runtime.run import SlamResult, build, evaluate, run_slam
from slam_runtime.sources import control_rows
from slam_runtime.vehicle import fit_ackermann_bias


@dataclass
class Iteration:
    index: int
    profile: object  # the profile the SLAM run used
    config: SlamConfig  # the settings it used
    result: SlamResult
    measured: object  # the profile measured against this run
    summary: dict  # what the measurement reported
    bias: dict = field(default_factory=dict)  # odometry biases measured against this run
    change: float = float("nan")  # largest change of the measured profile from the one the run used
    next_config: SlamConfig | None = None  # the settings with the measured biases, for the next run


def frame_controls(log: SensorLog) -> list[tuple[np.ndarray, np.ndarray]]:
    """Per frame, its control rows and durations (frame 0: none)."""
    out = []
    for fr in log.frames():
        if fr.index == 0:
            out.append((np.zeros((0, log.odometry.values.shape[1])), np.zeros(0)))
        else:
            out.append(control_rows(log, fr.odometry))
    return out


def self_calibration(
    log: SensorLog,
    profile,
    cfg: SlamConfig,
    seed: int,
    measure: Callable,
    change: Callable,
    *,
    iterations: int = 5,
    tolerance: float = 0.02,
    biases: bool = True,
    average_from: int | None = None,
    progress=None,
) -> list[Iteration]:
    """Alternate SLAM and measurement.

    measure(log, trajectory (T, 3), map_xy (K, 2), map_w (K,), prior profile, iteration) -> (profile, summary),
    given the best particle's trajectory and its whole map with the weights;
    change(new profile, old profile) -> float. Stops after ``iterations`` runs, or
    when the measured profile changes by less than ``tolerance`` (and the steering
    offset by less than 0.5 mrad). The last iteration's measured profile is the result.

    ``average_from`` K (Polyak-Ruppert averaging): from iteration K on, the next run's
    odometry biases are the mean of those measured in iterations K..k (``Iteration.bias``
    keeps each run's own), as ``measure`` is expected to average its profiles from K on;
    each run's map is a random draw, so the plain iteration scatters about its fixed
    point by the run-to-run spread and only the average settles.
    """
    if average_from is not None and average_from < 0:
        raise ValueError(f"average_from must be a non-negative iteration, got {average_from}")
    history: list[Iteration] = []
    controls = frame_controls(log) if biases and log.odometry is not None and log.odometry.kind == "ackermann" else None
    for k in range(iterations):
        res = run_slam(log, profile, cfg, seed, progress=progress)
        res.metrics = evaluate(log, res, cfg.metric.ospa_c, cfg.metric.ospa_p, cfg)
        vehicle = build(log, profile, cfg).vehicle
        traj = vehicle.pose(np.asarray(res.trajectory))
        measured, summary = measure(log, traj, res.map_all_xy, res.map_all_w, profile, k)
        it = Iteration(k, profile, cfg, res, measured, summary, change=change(measured, profile))
        new_cfg = cfg
        if controls is not None:
            it.bias = fit_ackermann_bias(vehicle, controls, traj)
            # measured from the raw odometry: absolute values, not corrections of the last ones
            first = k if average_from is None else min(average_from, k)  # the runs whose biases are averaged: first..k
            runs = [h.bias for h in history[first:]] + [it.bias]
            new_cfg = override(
                cfg,
                **{
                    "motion.ackermann.steer_offset": float(np.mean([b["steer_offset"] for b in runs])),
                    "motion.ackermann.speed_scale": float(np.mean([b["speed_scale"] for b in runs])),
                },
            )
        it.next_config = new_cfg
        history.append(it)
        moved = abs(new_cfg.motion.ackermann.steer_offset - cfg.motion.ackermann.steer_offset) if it.bias else 0.0
        steady = it.change < tolerance and moved < 5e-4
        profile, cfg = measured, new_cfg
        if steady:
            break
    return history
