"""Measurement sources and controls: what the filter loop gets from a log, frame by frame.

A log in memory (:class:`detectors.sensor_log.SensorLog`) becomes a sequence of
:class:`FrameInput`: the control rows since the previous frame (for the
vehicle model) and the frame's :class:`detectors.kinds.Measurements`, made by
the measurement source of the profile's detector kind
(:data:`detectors.kinds.DETECTORS`: the circle detector on each laser scan, the
log's own detections, the plane detector on each point cloud), so the runner
does not care which filter runs.

Controls (:func:`control_rows`): pose odometry becomes increments between
consecutive rows; increments are used as they are; a velocity or Ackermann
command holds until the next row, so the interval ending at row k is driven
by row k - 1 (the first row of the log has no interval before it). A vehicle
model whose motion follows its commands late (``motion.velocity.delay``) runs
on the log with its odometry stamped when the rows act (:func:`delayed`).
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass, replace

import numpy as np

from detectors.geometry import relative
from detectors.kinds import Measurements
from detectors.sensor_log import SensorLog
from profiles.errors import DataError


@dataclass
class FrameInput:
    index: int
    stamp: int  # ns
    controls: np.ndarray  # (R, k) control rows since the previous frame
    dts: np.ndarray  # (R,) how long each is held [s]
    meas: Measurements


def delayed(log: SensorLog, delay: float) -> SensorLog:
    """The log with its odometry rows stamped ``delay`` seconds later, when they act on the motion (the frames, the
    ground truth and the measurements keep their stamps); the log itself when the delay is 0."""
    if not delay or log.odometry is None:
        return log
    o = log.odometry
    return replace(log, odometry=replace(o, stamp=o.stamp + int(round(delay * 1e9))))


def control_rows(log: SensorLog, rows: slice) -> tuple[np.ndarray, np.ndarray]:
    """Control rows (R, k) and their durations (R,) [s] for the odometry rows ``rows`` of the log."""
    o = log.odometry
    start = rows.start or 0
    vals, stamps = o.values[rows], o.stamp[rows]
    if len(vals) == 0:
        return np.zeros((0, o.values.shape[1])), np.zeros(0)
    before = o.stamp[start - 1] if start > 0 else stamps[0]
    dts = np.diff(np.concatenate([[before], stamps])).astype(np.float64) / 1e9
    if o.kind == "pose":
        base = o.values[start - 1] if start > 0 else vals[0]
        chain = np.vstack([base[None], vals])
        return relative(chain[:-1], chain[1:]), dts
    if o.kind == "increment":
        return vals.astype(np.float64), dts
    if o.kind in ("velocity", "ackermann"):
        held = np.vstack([o.values[start - 1][None] if start > 0 else vals[:1], vals[:-1]])
        return held.astype(np.float64), dts
    raise DataError(f"odometry of kind {o.kind!r} cannot drive the filter")


def frames(log: SensorLog, measure, max_frames: int | None = None) -> Iterator[FrameInput]:
    """Every frame (or the first ``max_frames``) with its controls and measurements; frame 0 has no motion
    (the filter starts at its pose)."""
    for fr in log.frames():
        if max_frames is not None and fr.index >= max_frames:
            return
        if fr.index == 0 or log.odometry is None:
            u, dt = np.zeros((0, 0)), np.zeros(0)
        else:
            u, dt = control_rows(log, fr.odometry)
        yield FrameInput(fr.index, fr.stamp, u, dt, measure(fr))


