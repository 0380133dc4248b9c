"""The odometry's noise and biases measured against ground truth (the vehicle model's calibration).

Over windows of ``window`` seconds, the true motion (from the reference poses,
e.g. Vicon) is compared with the motion the odometry rows integrate to:

* velocity odometry (v, omega commands): the heading change and the distance
  travelled along the heading; their mean errors per second are the biases
  (``omega_offset``: the turn rate the commands add; ``speed_scale``: true
  distance along the path / commanded distance), and their spread (distance
  errors once the scale is applied) the noise, expressed as the
  per-row standard deviations a filter draws (a white error of std s per row of
  duration dt spreads as s sqrt(dt) per second: s = spread / sqrt(dt)). The plain
  standard deviation, not a robust spread: the errors are heavy-tailed.

The figures go into the SLAM settings' ``motion`` section (``detcal calibrate``
writes ``motion.yaml`` beside the profile), so a robot's vehicle model can be
calibrated on other robots' truth, as its detector is.
"""

from __future__ import annotations

import numpy as np

from detectors.geometry import interpolate_poses, relative
from detectors.sensor_log import SensorLog
from profiles.errors import DataError


def fit_velocity_odometry(logs: list[SensorLog], window: float = 1.0) -> dict:
    """sigma_v [m/s], sigma_omega [rad/s] per row, speed_scale and omega_offset [rad/s], pooled over ``logs``."""
    e_th, e_d, dist_true, dist_cmd, rows_dt = [], [], 0.0, 0.0, []
    for log in logs:
        o, g = log.odometry, log.reference.get("ground_truth")
        if o is None or o.kind != "velocity" or g is None:
            raise DataError(f"log {log.name!r}: measuring velocity odometry needs velocity odometry and ground-truth poses")
        st = o.stamp
        dt = np.diff(st) / 1e9
        rows_dt.append(dt)
        per = max(1, int(round(window / max(float(np.median(dt)), 1e-9))))
        start = np.arange(0, st.size - per - 1, per)
        inside = (st[start] >= g.stamp[0]) & (st[start + per] <= g.stamp[-1])
        start = start[inside]
        if start.size < 10:
            continue
        rel = relative(interpolate_poses(g.stamp, g.poses, st[start]), interpolate_poses(g.stamp, g.poses, st[start + per]))
        # the command of row k holds until row k + 1
        cs_om = np.concatenate([[0.0], np.cumsum(o.values[:-1, 1] * dt)])
        cs_d = np.concatenate([[0.0], np.cumsum(o.values[:-1, 0] * dt)])
        om = cs_om[start + per] - cs_om[start]
        d = cs_d[start + per] - cs_d[start]
        span = (st[start + per] - st[start]) / 1e9
        e_th.append((np.mod(rel[:, 2] - om + np.pi, 2 * np.pi) - np.pi) / span)
        # the true distance along the path: the chord over a constant-curvature arc of the true heading
        # change (the displacement along the start heading alone is short by ~omega^2 T^2 / 6 on curves)
        half = 0.5 * np.mod(rel[:, 2] + np.pi, 2 * np.pi) - 0.5 * np.pi
        arc = np.hypot(rel[:, 0], rel[:, 1]) * np.where(np.abs(half) > 1e-9, half / np.sin(np.where(half == 0, 1.0, half)), 1.0)
        arc = np.copysign(arc, rel[:, 0])
        e_d.append(np.column_stack([arc, d, span]))
        dist_true += float(np.abs(arc).sum())
        dist_cmd += float(np.abs(d).sum())
    if not e_th:
        raise DataError("too little odometry inside the ground truth to measure it")
    scale = dist_true / dist_cmd if dist_cmd > 0 else 1.0
    e_th, dd = np.concatenate(e_th), np.concatenate(e_d)
    e_d = (dd[:, 0] - scale * dd[:, 1]) / dd[:, 2]  # the distance error once the scale is applied: the noise
    dt = float(np.median(np.concatenate(rows_dt)))
    omega_offset = -float(np.median(e_th))  # commands turn by omega; truth by omega - offset
    # the plain standard deviation, not a robust one: the errors are heavy-tailed (slips, bumps; on UTIAS
    # the std of the heading error is 2-3x its MAD-based spread), and a Gaussian filter must cover the tails
    spread_th = float(np.std(e_th)) * np.sqrt(window)
    spread_d = float(np.std(e_d)) * np.sqrt(window)
    return {
        "velocity": {
            "sigma_v": spread_d / np.sqrt(dt),
            "sigma_omega": spread_th / np.sqrt(dt),
            "speed_scale": scale,
            "omega_offset": omega_offset,
        },
        "row_period_s": dt,
        "windows": int(e_th.size),
        "window_s": window,
    }
