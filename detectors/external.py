"""``external``: detections made elsewhere and read from the log (a camera's barcode detector, a vendor's tree
extractor), as (range, bearing) in the sensor frame.

Where the log labels its detections (UTIAS ``target``: 1 landmark, 2 another
robot, 0 unknown barcode), the filter gets only the landmark ones
(``detection.landmarks_only``). Where it names the landmark each detection reads
(UTIAS ``subject``, from the barcode; -1 for a code outside the map) and the run
takes identities (``detection.identities``), each measurement carries it.
"""

from __future__ import annotations

import numpy as np

from detectors.kinds import Detector, Measurements, register

#: the detections' descriptor that names the landmark a detection reads
IDENTITY = "subject"


class LoggedDetections:
    """The log's own detections, (range, bearing) in the sensor frame."""

    def __init__(self, log, *, landmarks_only: bool = True, identities: bool = False) -> None:
        self.log = log
        d = log.detections
        self.z = np.column_stack([d.range, d.bearing])
        self.use = np.ones(len(d), dtype=bool)
        if landmarks_only and "target" in d.descriptors:
            self.use = np.asarray(d.descriptors["target"]) == 1
        self.ident = np.asarray(d.descriptors[IDENTITY], dtype=np.int64) if identities else None

    def __call__(self, frame) -> Measurements:
        sl = frame.rows
        use = self.use[sl]
        return Measurements(self.z[sl][use], ident=None if self.ident is None else self.ident[sl][use])


class ExternalDetector(Detector):
    """The log's detections, with the profile's P_D table and clutter."""

    stream = "detections"
    needs = "takes the log's detections"

    def source(self, log, profile, detection, options, identities: bool = False):
        return LoggedDetections(log, landmarks_only=options.landmarks_only, identities=identities)

    def reads_identities(self, log) -> bool:
        return log.detections is not None and IDENTITY in log.detections.descriptors


register("external", ExternalDetector())
