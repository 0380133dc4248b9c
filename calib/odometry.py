"""The odometry's noise and biases measured against ground truth (the vehicle model's calibration).

Over windows of ``window`` seconds, the true motion (from the reference poses,
e.g. Vicon) is compared with the motion the odometry rows integrate to:

* velocity odometry (v, omega commands): the heading change and the distance
  travelled along the heading; their mean errors per second are the biases
  (``omega_offset``: the turn rate the commands add; ``speed_scale``: true
  distance along the path / commanded distance; ``omega_scale``: true heading
  change / commanded heading change), and their spread (the errors once the
  scales are applied) the noise, expressed as the
  per-row standard deviations a filter draws (a white error of std s per row of
  duration dt spreads as s sqrt(dt) per second: s = spread / sqrt(dt)), on the
  command, as the unicycle adds it (before its scales). The plain
  standard deviation, not a robust spread: the errors are heavy-tailed.

The motion may follow the commands late (``delay``): the delay is the one, on a
grid of the row period up to ``max_delay``, at which the one-second windows'
heading errors (after the least-squares scale and offset of that delay) have the
smallest spread; every other figure is measured at it. The turn-rate scale is a
least-squares fit of the true heading change on the commanded one (with the
offset) over longer windows (``scale_window``, 5 s): what is left of the
command dynamics (a lag that is not a pure delay) biases a short window's slope
towards zero (regression dilution), a 5-s window's far less.

Windows over which the ground truth turns faster than ``max_turn_rate``
between two of its samples are left out: a motion-capture glitch (a heading
that jumps by radians in one sample) is not odometry noise.

The figures go into the SLAM settings' ``motion`` section (``detcal calibrate``
writes ``motion.yaml`` beside the profile), so a robot's vehicle model can be
calibrated on other robots' truth, as its detector is.
"""

from __future__ import annotations

import numpy as np

from detectors.geometry import interpolate_poses, relative
from detectors.sensor_log import SensorLog
from profiles.errors import DataError


class _Log:
    """One log's odometry and ground truth, prepared once for every window length and delay the fit tries: the
    commanded heading and distance integrated over the rows (a row's command holds until the next row), the
    truth's broken intervals (``bad`` (S-1,): a turn faster than ``max_turn_rate`` between two samples, or a heading
    that is not finite) and the median row period [s]."""

    def __init__(self, log: SensorLog, max_turn_rate: float) -> None:
        o, g = log.odometry, log.reference["ground_truth"]
        self.stamp, self.g = o.stamp, g
        dt = np.diff(o.stamp) / 1e9
        self.period = float(np.median(dt))
        self.cs_om = np.concatenate([[0.0], np.cumsum(o.values[:-1, 1] * dt)])
        self.cs_d = np.concatenate([[0.0], np.cumsum(o.values[:-1, 0] * dt)])
        turn = np.abs(np.mod(np.diff(g.poses[:, 2]) + np.pi, 2 * np.pi) - np.pi)
        gdt = np.diff(g.stamp) / 1e9
        # samples that share a stamp (UTIAS: a quarter of them) are held to the truth's usual sample period
        floor = float(np.median(gdt[gdt > 0])) if np.any(gdt > 0) else 1.0
        self.bad = ~(turn <= max_turn_rate * np.maximum(gdt, floor))

    def rows(self, seconds: float) -> int:
        """Odometry rows per window of ``seconds`` at this log's own row period."""
        return max(1, int(round(seconds / max(self.period, 1e-9))))


class _Windows:
    """Consecutive windows of ``seconds`` of a log's odometry rows inside the ground truth, the truth read ``shift``
    ns after the rows' stamps (the motion's delay): the true relative poses (W, 3), the commanded heading changes
    and distances (W,) [rad, m] and the durations (W,) [s]; windows over a broken stretch of the truth are left out."""

    def __init__(self, lg: _Log, seconds: float, shift: int) -> None:
        st, g, bad, per = lg.stamp, lg.g, lg.bad, lg.rows(seconds)
        ts = st + shift
        start = np.arange(0, max(st.size - per - 1, 0), per)
        start = start[(ts[start] >= g.stamp[0]) & (ts[start + per] <= g.stamp[-1])]
        if bad.any():  # any broken interval between the window's ends (a stamp shared by two samples: both sides)
            cum = np.concatenate([[0], np.cumsum(bad)])
            a = np.clip(np.searchsorted(g.stamp, ts[start], side="right") - 1, 0, bad.size)
            b = np.clip(np.searchsorted(g.stamp, ts[start + per], side="right"), 0, bad.size)
            start = start[cum[b] - cum[a] == 0]
        self.rel = relative(interpolate_poses(g.stamp, g.poses, ts[start]), interpolate_poses(g.stamp, g.poses, ts[start + per]))
        self.om = lg.cs_om[start + per] - lg.cs_om[start]
        self.d = lg.cs_d[start + per] - lg.cs_d[start]
        self.span = (st[start + per] - st[start]) / 1e9
        # the true heading change, unwrapped about the commanded one (a window may turn by more than pi)
        self.dth = self.om + np.mod(self.rel[:, 2] - self.om + np.pi, 2 * np.pi) - np.pi


def _turn_fit(w: list[_Windows]) -> tuple[float | None, np.ndarray]:
    """Least squares of the true heading change on the commanded one and the duration: the scale (None with fewer
    than 10 windows or no turn) and the residuals."""
    dth = np.concatenate([x.dth for x in w])
    a = np.column_stack([np.concatenate([x.om for x in w]), np.concatenate([x.span for x in w])])
    if dth.size < 10 or float(np.sum(a[:, 0] ** 2)) == 0.0:
        return None, dth - a[:, 0]
    sol = np.linalg.lstsq(a, dth, rcond=None)[0]
    return float(sol[0]), dth - a @ sol


def fit_velocity_odometry(
    logs: list[SensorLog],
    window: float = 1.0,
    scale_window: float = 5.0,
    max_delay: float = 0.5,
    max_turn_rate: float = 10.0,
) -> dict:
    """sigma_v [m/s], sigma_omega [rad/s] per row, speed_scale, omega_scale, omega_offset [rad/s] and delay [s]
    (0 to ``max_delay``, at most 1 s, the settings' bound), pooled over ``logs``."""
    if not 0.0 <= max_delay <= 1.0:
        raise ValueError(f"max_delay: expected 0-1 s, got {max_delay}")
    usable = []
    for log in logs:
        o, g = log.odometry, log.reference.get("ground_truth")
        if o is None or o.kind != "velocity" or g is None:
            raise DataError(f"log {log.name!r}: measuring velocity odometry needs velocity odometry and ground-truth poses")
        if len(o) >= 3 and g.stamp.size >= 2:
            usable.append(_Log(log, max_turn_rate))
    if not usable:
        raise DataError("too little odometry inside the ground truth to measure it")
    dt = float(np.median(np.concatenate([np.diff(lg.stamp) / 1e9 for lg in usable])))

    def windows(seconds: float, shift: int) -> list[_Windows]:
        return [_Windows(lg, seconds, shift) for lg in usable]

    # the delay: the grid of row periods up to max_delay, the smallest spread of the one-second heading errors
    best, delay, w = np.inf, 0.0, []
    for d in np.arange(0.0, max_delay + 0.5 * dt, dt) if dt > 0 else np.zeros(1):
        at = windows(window, int(round(d * 1e9)))
        res = _turn_fit(at)[1]
        spread = float(np.std(res)) if res.size >= 10 else np.inf
        if spread < best:  # the first of equal spreads: the shorter delay
            best, delay, w = spread, float(d), at
    if not np.isfinite(best):
        raise DataError("too little odometry inside the ground truth to measure it")
    shift = int(round(delay * 1e9))
    # the scale over the long windows; a log too short for 10 of them takes the one-second windows' (diluted) slope
    omega_scale, _ = _turn_fit(windows(scale_window, shift))
    scale_from = scale_window
    if omega_scale is None:
        omega_scale, _ = _turn_fit(w)
        scale_from = window
    omega_scale = 1.0 if omega_scale is None else omega_scale
    span = np.concatenate([x.span for x in w])
    rel = np.concatenate([x.rel for x in w])
    e_th = (np.mod(rel[:, 2] - omega_scale * np.concatenate([x.om for x in w]) + np.pi, 2 * np.pi) - np.pi) / span
    # the true distance along the path: the chord over a constant-curvature arc of the true heading
    # change (the displacement along the start heading alone is short by ~omega^2 T^2 / 6 on curves)
    half = 0.5 * np.mod(rel[:, 2] + np.pi, 2 * np.pi) - 0.5 * np.pi
    arc = np.hypot(rel[:, 0], rel[:, 1]) * np.where(np.abs(half) > 1e-9, half / np.sin(np.where(half == 0, 1.0, half)), 1.0)
    arc = np.copysign(arc, rel[:, 0])
    d = np.concatenate([x.d for x in w])
    dist_true, dist_cmd = float(np.abs(arc).sum()), float(np.abs(d).sum())
    scale = dist_true / dist_cmd if dist_cmd > 0 else 1.0
    e_d = (arc - scale * d) / span  # the distance error once the scale is applied: the noise
    omega_offset = -float(np.median(e_th))  # commands turn by omega; truth by omega_scale * omega - offset
    if not (0.5 < scale < 2.0 and 0.5 < omega_scale < 2.0):  # the unicycle's bounds (slam_runtime.vehicle.VelocityNoise)
        raise DataError(
            f"the odometry and the ground truth do not describe one motion: the truth goes {scale:.3g} times the commanded"
            f" distance and turns {omega_scale:.3g} times the commanded angle (a unicycle takes 0.5-2)"
        )
    # the plain standard deviation, not a robust one: the errors are heavy-tailed (slips, bumps; on UTIAS
    # the std of the heading error is 2-3x its MAD-based spread), and a Gaussian filter must cover the tails
    spread_th = float(np.std(e_th)) * np.sqrt(window)
    spread_d = float(np.std(e_d)) * np.sqrt(window)
    return {
        "velocity": {
            # on the command: the unicycle draws the noise before it applies the scales
            "sigma_v": spread_d / np.sqrt(dt) / scale,
            "sigma_omega": spread_th / np.sqrt(dt) / abs(omega_scale),
            "speed_scale": scale,
            "omega_offset": omega_offset,
            "omega_scale": omega_scale,
            "delay": delay,
        },
        "row_period_s": dt,
        "windows": int(e_th.size),
        "window_s": window,
        "scale_window_s": scale_from,
        "broken_truth_intervals": int(sum(int(lg.bad.sum()) for lg in usable)),
    }
