"""Records outside the time span of a log's ground truth.

Calibration and validation give every scan or detection frame the vehicle pose
interpolated from the ground truth. Before the first or after the last truth
pose there is nothing to interpolate: clamping to the end pose would label a
detection against a pose the vehicle may not have had. Library code refuses
such logs (:func:`check_within_truth`); the command line trims them explicitly
(:func:`trim_to_truth`) and says how many records it dropped.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from detectors.sensor_log import NS, Detections, ScanBatch, SensorLog
from profiles.errors import DataError


def _outside(log: SensorLog) -> tuple[np.ndarray | None, np.ndarray | None]:
    """(scans outside (S,) bool or None, detection frames outside (F,) bool or None)."""
    ref = log.reference.get("ground_truth")
    if ref is None or len(ref) == 0:
        return None, None
    lo, hi = ref.stamp[0], ref.stamp[-1]
    scans = None if log.scans is None else (log.scans.stamp < lo) | (log.scans.stamp > hi)
    frames = None if log.detections is None else (log.detections.frame_stamp < lo) | (log.detections.frame_stamp > hi)
    return scans, frames


def check_within_truth(log: SensorLog) -> None:
    """DataError when a scan or detection frame lies outside the ground truth's time span."""
    scans, frames = _outside(log)
    ref = log.reference.get("ground_truth")
    for what, out, stamps in (("scan", scans, None if log.scans is None else log.scans.stamp),
                              ("detection frame", frames, None if log.detections is None else log.detections.frame_stamp)):  # fmt: skip
        if out is not None and out.any():
            i = int(np.flatnonzero(out)[0])
            raise DataError(
                f"log {log.name!r}: {int(out.sum())} {what}s lie outside the ground truth's time span "
                f"({ref.stamp[0] / NS:.3f}-{ref.stamp[-1] / NS:.3f} s), the first at {stamps[i] / NS:.3f} s; "
                "the command line drops them (calib.truth.trim_to_truth)"
            )


def trim_to_truth(log: SensorLog) -> tuple[SensorLog, dict[str, int]]:
    """``log`` without the scans and detection frames outside its ground truth's time span, and how many went."""
    scans, frames = _outside(log)
    dropped: dict[str, int] = {}
    new = {}
    if scans is not None and scans.any():
        keep = ~scans
        s = log.scans
        new["scans"] = ScanBatch(
            s.stamp[keep],
            s.ranges[keep],
            None if s.intensities is None else s.intensities[keep],
            None if s.odom_pose is None else s.odom_pose[keep],
            None if s.geometry is None else s.geometry[keep],
        )
        dropped["scans"] = int(scans.sum())
    if frames is not None and frames.any():
        d = log.detections
        keep_f = ~frames
        keep_d = keep_f[d.frame]
        renumber = np.cumsum(keep_f) - 1
        new["detections"] = Detections(
            d.frame_stamp[keep_f],
            renumber[d.frame[keep_d]],
            d.range[keep_d],
            d.bearing[keep_d],
            {k: v[keep_d] for k, v in d.descriptors.items()},
        )
        dropped["detection frames"] = int(frames.sum())
    if not new:
        return log, {}
    return dataclasses.replace(log, **new), dropped
