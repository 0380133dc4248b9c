"""Detector kinds at run time: what a profile's ``detector.kind`` does when a filter runs on a log.

A :class:`Detector` says which stream of a log it reads (scans, point clouds or
the log's own detections), which feature kind its detections are (points,
planes), how its runtime detection model is built from a profile and the
filter's detection options, and the measurement source that turns each frame
of a log into :class:`Measurements`. Every kind is found through
:data:`DETECTORS`; :func:`register` adds a new one here and its profile facts
to :data:`profiles.profile.DETECTOR_KINDS` (one line for a new detector
module). The built-in kinds: ``circle2d`` (:mod:`detectors.circle`),
``external`` (:mod:`detectors.external`), ``plane3d`` (:mod:`detectors.plane`).
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from profiles.profile import DETECTOR_KINDS, DetectorKind
from profiles.registry import Registry


@dataclass
class Measurements:
    """One frame's measurements, sensor frame.

    z (M, dz); cov (M, dz, dz) each measurement's own covariance (e.g. a circle
    fit's), added to the filter's noise floor, or None; ratio (M,) the
    descriptor likelihood ratio g_x(d) / g_FA(d) of eq. 5.6, or None; scan (B,)
    and angles (B,) the laser scan the measurements came from (ray-traced P_D),
    or None; cloud (N, 4) the point cloud they came from (3D features), or None;
    outlines: (vertices (V, 3), offsets (M + 1,)) each measured plane's convex outline in the sensor frame
    (measurement m's are ``vertices[offsets[m]:offsets[m + 1]]``; planar features' extents), or None;
    ident (M,) int64 the identity each measurement reads (the landmark a barcode names; -1: none), or None when the
    run takes no identities.
    """

    z: np.ndarray
    cov: np.ndarray | None = None
    ratio: np.ndarray | None = None
    scan: np.ndarray | None = None
    angles: np.ndarray | None = None
    cloud: np.ndarray | None = None
    outlines: tuple[np.ndarray, np.ndarray] | None = None
    ident: np.ndarray | None = None

    def __len__(self) -> int:
        return int(self.z.shape[0])


class Detector(ABC):
    """A detector kind at run time (module docstring)."""

    #: the stream of a :class:`detectors.sensor_log.SensorLog` it reads: "scans", "clouds" or "detections"
    stream: str
    #: what it needs, for the message that refuses a log without that stream ("detects circles in laser scans")
    needs: str
    #: the feature kind of its detections (the SLAM settings' ``features``)
    features: str = "points"

    def detection_model(self, profile, sensor, options, k_sigma: float | None):
        """The runtime detection model of ``profile`` with the filter's detection ``options`` (an object with the
        attributes of ``slam_runtime.config.DetectionOptions``); ``k_sigma``: the occlusion tolerance [range sigmas]
        the filter runs with (None: the profile's); ``sensor``: the log's sensor model (None: the profile's). By
        default the point features' model (:class:`detectors.model.DetectionModel`)."""
        from detectors.model import DetectionModel

        return DetectionModel.from_options(profile, sensor, options, k_sigma)

    @abstractmethod
    def source(self, log, profile, detection, options) -> Callable[[object], Measurements]:
        """``measure(frame) -> Measurements`` for every frame of ``log`` (a :class:`detectors.sensor_log.Frame`).
        A detector that :meth:`reads_identities` also takes ``identities=True``: its measurements then carry them."""

    def reads_identities(self, log) -> bool:
        """Whether its detections in ``log`` name the landmark they read (a barcode): none by default."""
        return False


#: The detector kinds by the profile's ``detector.kind``.
DETECTORS: Registry[Detector] = Registry("detector", builtins=("detectors.circle", "detectors.external", "detectors.plane"))


def register(name: str, detector: Detector, kind: DetectorKind | None = None) -> Detector:
    """Add a detector kind: what it does at run time, and (``kind``, for a kind profiles do not know yet) what it
    means to a profile."""
    if kind is not None:
        DETECTOR_KINDS.add(name, kind)
    return DETECTORS.add(name, detector, _depth=2)  # the module that called register, not this one
