"""Are the data enough for the fits a profile would hold? A verdict with the counts that decide it.

A calibration can run to the end on data too thin to mean anything: two
landmarks and a score of true detections give a Hotelling ellipsoid of a
handful of points and a P_D table of zeros. The figures:

- ``landmarks``: landmarks the labelling used (all logs);
- ``true_detections``: detections associated with a landmark, which the
  Hotelling ellipsoid (eq. 5.4 of the thesis) is fitted to;
- ``populated_pd_bins``: P_D bins holding at least ``pd.min_count``
  landmark-scan pairs (eq. 6.2 is estimated bin by bin);
- ``pd_bins_with_detections``: populated bins where the detector fired at all
  (a table of zeros says the landmarks are not what the detector detects).
"""

from __future__ import annotations

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from calib.checks import Check, Verdict


class SufficiencyThresholds(BaseModel):
    """Least counts a profile needs (see the module docstring)."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)
    min_landmarks: int = Field(default=5, ge=1)
    min_true_detections: int = Field(default=100, ge=1)
    min_populated_pd_bins: int = Field(default=2, ge=1)
    min_pd_bins_with_detections: int = Field(default=1, ge=0)


def check_counts(
    landmarks: int, true_detections: int, pd_counts, pd_detections, min_count: int, thresholds: SufficiencyThresholds | None = None
) -> Verdict:
    """Verdict on the counts of a calibration: landmarks, true detections, and the P_D table's pairs and
    detections per bin (``pd_counts``, ``pd_detections``, (Q,) each), a bin being populated with ``min_count`` pairs."""
    th = thresholds or SufficiencyThresholds()
    counts = np.asarray(pd_counts if pd_counts is not None else [], dtype=np.int64).ravel()
    dets = np.asarray(pd_detections if pd_detections is not None else np.zeros_like(counts), dtype=np.int64).ravel()
    populated = counts >= min_count
    return Verdict(
        "data",
        (
            Check("landmarks", float(landmarks), th.min_landmarks, "min", "landmarks labelled"),
            Check("true_detections", float(true_detections), th.min_true_detections, "min", "detections associated with a landmark"),
            Check("populated_pd_bins", float(populated.sum()), th.min_populated_pd_bins, "min", f"P_D bins with at least {min_count} landmark-scan pairs"),
            Check("pd_bins_with_detections", float((populated & (dets > 0)).sum()), th.min_pd_bins_with_detections, "min", "populated P_D bins where the detector fired"),
        ),
    )
