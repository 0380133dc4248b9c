"""Measurement sources and controls: what the filter loop gets from a log, frame by frame.

A log in memory (:class:`detectors.logs.SensorLog`) becomes a sequence of
:class:`FrameInput`: the control rows since the previous frame (for the
vehicle model) and the frame's :class:`slam_runtime.mapfilter.Measurements`.
One source per kind of log, so the runner does not care which filter runs:

* :class:`ScanCircles` -- laser scans: the profile's circle detector on each
  scan (with its Hotelling gate, and the scan's own beam layout), each
  detection's own fit covariance, the descriptor likelihood ratio (eq. 5.6),
  and the scan with its beam angles for ray-traced P_D;
* :class:`LoggedDetections` -- detection-level logs (Victoria Park, UTIAS):
  the log's detections; where the log labels them (UTIAS ``target``: 1
  landmark, 2 another robot, 0 unknown barcode), only the landmark ones;
* :class:`CloudPlanes` -- 3D lidar clouds: the profile's plane detector on each
  cloud, the landmark planes (steep enough, enough inliers) as (azimuth,
  elevation, offset) in the sensor frame with their fit covariances, and the
  cloud for P_D.

Controls (:func:`control_rows`): pose odometry becomes increments between
consecutive rows; increments are used as they are; a velocity or Ackermann
command holds until the next row, so the interval ending at row k is driven
by row k - 1 (the first row of the log has no interval before it).
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass

import numpy as np

from detectors.geometry import relative
from detectors.logs import SensorLog
from profiles.errors import DataError
from slam_runtime.mapfilter import Measurements


@dataclass
class FrameInput:
    index: int
    stamp: int  # ns
    controls: np.ndarray  # (R, k) control rows since the previous frame
    dts: np.ndarray  # (R,) how long each is held [s]
    meas: Measurements


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


class LoggedDetections:
    """The log's own detections, (range, bearing) in the sensor frame."""

    def __init__(self, log: SensorLog, *, landmarks_only: bool = True) -> None:
        self.log = log
        d = log.detections
        self.z = np.column_stack([d.range, d.bearing])
        self.use = np.ones(len(d), dtype=bool)
        if landmarks_only and "target" in d.descriptors:
            self.use = np.asarray(d.descriptors["target"]) == 1

    def __call__(self, frame) -> Measurements:
        sl = frame.rows
        return Measurements(self.z[sl][self.use[sl]])


class ScanCircles:
    """The profile's circle detector on every scan."""

    def __init__(self, log: SensorLog, profile, detection, *, descriptor_likelihood: bool = True) -> None:
        from profiles.schema import HotellingParams

        self.log = log
        self.params = profile.detector.circle
        self.detection = detection
        sensor = log.sensor if log.sensor is not None else profile.sensor
        self.range_sigma = sensor.range_sigma
        self.hot = None
        if profile.hotelling is not None:
            self.hot = HotellingParams.model_validate(profile.hotelling.model_dump(include=set(HotellingParams.model_fields)))
        self.ratio = descriptor_likelihood and self.hot is not None

    def __call__(self, frame) -> Measurements:
        from detectors.circle import detect_circles

        scan = self.log.scans.ranges[frame.rows]
        angles = self.log.scan_angles(frame.rows)  # this scan's own beam layout (NaN past its beams)
        det = detect_circles(scan, angles, self.params, self.hot, self.range_sigma)
        z = np.column_stack([det.range, det.bearing])
        ratio = None
        if self.ratio:
            desc = det.descriptors(tuple(self.hot.names))
            ratio = self.detection.g_true(desc) / np.maximum(self.detection.g_false(desc), 1e-300)
        return Measurements(z, det.cov, ratio, scan, angles)


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


class CloudPlanes:
    """The profile's plane detector on every cloud; landmark planes as sensor-frame charts (azimuth, elevation, offset)."""

    def __init__(self, log: SensorLog, profile, detection) -> None:
        self.log = log
        self.params = profile.detector.plane
        self.detection = detection
        self.min_points = profile.planes.min_points
        self.min_width = profile.planes.min_width

    def __call__(self, frame) -> Measurements:
        from detectors.plane import detect_planes

        cloud = self.log.clouds.frame(frame.rows)
        det = detect_planes(cloud, self.params, where=f"{self.log.name}: cloud {frame.rows}")
        use = self.detection.in_view(det.chart) & (det.inliers >= self.min_points) & (det.width >= self.min_width)
        return Measurements(det.chart[use], det.cov[use], cloud=cloud)
