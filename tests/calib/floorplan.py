"""A seeded floor-plan laser simulator: walls as segments, a path through them, noisy odometry.

The truth for the ground-truth tests: the vehicle's true poses are the log's
``ground_truth`` reference; the odometry is the true path with noisy
increments composed (CARMEN-style odometry poses logged with each scan), and
may be given a jump (a kidnapped robot: from scan ``jump_at`` on, the
odometry is offset by the pose ``jump``).
"""

from __future__ import annotations

import numpy as np

from detectors.geometry import cast, compose, relative
from detectors.sensor_log import ReferencePoses, ScanBatch, SensorLog, SensorModel

RATE_HZ = 5.0


def rectangle(x0: float, y0: float, x1: float, y1: float) -> np.ndarray:
    """(4, 4) segments (x0, y0, x1, y1) of an axis-aligned box."""
    return np.array([[x0, y0, x1, y0], [x1, y0, x1, y1], [x1, y1, x0, y1], [x0, y1, x0, y0]], dtype=float)


def path_poses(waypoints: np.ndarray, speed: float, turn_rate: float = 1.0) -> np.ndarray:
    """(S, 3) poses at RATE_HZ along a polyline (W, 2): straight legs at ``speed`` [m/s], turns in place at ``turn_rate`` [rad/s]."""
    out = []
    heading = np.arctan2(*(waypoints[1] - waypoints[0])[::-1])
    for a, b in zip(waypoints[:-1], waypoints[1:], strict=True):
        want = np.arctan2(b[1] - a[1], b[0] - a[0])
        turn = np.mod(want - heading + np.pi, 2 * np.pi) - np.pi
        n_turn = int(np.ceil(abs(turn) / (turn_rate / RATE_HZ)))
        for k in range(1, n_turn + 1):
            out.append([a[0], a[1], heading + turn * k / n_turn])
        heading = want
        n = max(1, int(np.ceil(np.hypot(*(b - a)) / (speed / RATE_HZ))))
        for k in range(n):
            p = a + (b - a) * k / n
            out.append([p[0], p[1], heading])
    out.append([*waypoints[-1], heading])
    p = np.array(out)
    p[:, 2] = np.mod(p[:, 2] + np.pi, 2 * np.pi) - np.pi
    return p


def floorplan_log(
    walls: np.ndarray,
    poses: np.ndarray,
    seed: int,
    *,
    range_max: float = 12.0,
    range_sigma: float = 0.01,
    odo_trans: float = 0.02,
    odo_rot: float = 0.01,
    jump_at: int | None = None,
    jump: tuple[float, float, float] = (0.0, 0.0, 0.0),
    name: str = "floorplan",
) -> SensorLog:
    """A log of 181-beam scans (pi field of view) of ``walls`` (M, 4) from true vehicle poses (S, 3).

    Odometry increments get Gaussian noise of ``odo_trans`` per metre and ``odo_rot`` rad per metre and per
    radian turned; the jump is added to the increment into scan ``jump_at``.
    """
    rng = np.random.default_rng(seed)
    sensor = SensorModel(n_beams=181, angle_min=-np.pi / 2, angle_increment=np.pi / 180, range_max=range_max, range_sigma=range_sigma)
    ang = sensor.angles()
    ranges = np.empty((poses.shape[0], ang.size), dtype=np.float32)
    for k, p in enumerate(poses):
        r, _ = cast(p, ang, np.zeros((0, 2)), np.zeros(0), walls[:, :2], walls[:, 2:], range_max)
        r = r + range_sigma * rng.standard_normal(r.size)
        ranges[k] = np.where(np.isfinite(r) & (r < range_max), r, np.nan)
    inc = relative(poses[:-1], poses[1:])
    d = np.hypot(inc[:, 0], inc[:, 1])
    noise = rng.standard_normal(inc.shape)
    inc[:, 0] += odo_trans * d * noise[:, 0]
    inc[:, 1] += odo_trans * d * noise[:, 1]
    inc[:, 2] += odo_rot * (d + np.abs(inc[:, 2])) * noise[:, 2]
    if jump_at is not None:
        inc[jump_at - 1] = compose(inc[jump_at - 1], np.asarray(jump, dtype=float))
    odo = np.zeros_like(poses)
    odo[0] = poses[0]
    for k in range(1, poses.shape[0]):
        odo[k] = compose(odo[k - 1], inc[k - 1])
    stamp = (np.arange(poses.shape[0]) * (1e9 / RATE_HZ)).astype(np.int64) + 1_000_000_000
    return SensorLog(
        name=name,
        sensor=sensor,
        scans=ScanBatch(stamp, ranges, None, odo),
        reference={"ground_truth": ReferencePoses("ground_truth", stamp, poses)},
        source={"reader": "test floorplan", "seed": seed},
    )
