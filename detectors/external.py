"""``external``: detections made elsewhere and read from the log (a camera's barcode detector, a vendor's tree
extractor), as (range, bearing) in the sensor frame.

Where the log labels its detections (UTIAS ``target``: 1 landmark, 2 another
robot, 0 unknown barcode), the filter gets only the landmark ones
(``detection.landmarks_only``).
"""

from __future__ import annotations

import numpy as np

from detectors.kinds import Detector, Measurements, register


class LoggedDetections:
    """The log's own detections, (range, bearing) in the sensor frame."""

    def __init__(self, log, *, landmarks_only: bool = True) -> None:
        self.log = log
        d = log.detections
        self.z = np.column_stack([d.range, d.bearing])
        self.use = np.ones(len(d), dtype=bool)
        if landmarks_only and "target" in d.descriptors:
            self.use = np.asarray(d.descriptors["target"]) == 1

    def __call__(self, frame) -> Measurements:
        sl = frame.rows
        return Measurements(self.z[sl][self.use[sl]])


class ExternalDetector(Detector):
    """The log's detections, with the profile's P_D table and clutter."""

    stream = "detections"
    needs = "takes the log's detections"

    def source(self, log, profile, detection, options):
        return LoggedDetections(log, landmarks_only=options.landmarks_only)


register("external", ExternalDetector())
