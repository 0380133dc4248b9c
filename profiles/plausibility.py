"""Physical plausibility of a profile read from a file: values no real detector produces are refused, legal but
suspicious ones counted in a warning.

The schema checks what a value may be (a probability in [0, 1], a positive
definite covariance); these bounds say what a calibrated detector on a real
sensor can be. Refused (one line naming the file and the field):

- ``hotelling.covariance`` with a condition number beyond :data:`MAX_CONDITION`
  (checked by the schema itself, so also for a config file or a calibration's
  result): a profile writes its figures to six significant digits, which moves
  the inverse the gate uses by up to about cond x 5e-7 relative; beyond 1e6 not
  one digit of the gate is left;
- ``clutter.rate`` above :data:`MAX_CLUTTER_RATE` false alarms per frame, or, for
  the circle detector on a 2D laser, above the detections a scan can hold
  (``n_beams / circle.min_points``: every detection takes at least min_points
  returns);
- a P_D table that says every feature is always seen (every bin 1) with no
  clutter (rate 0): a perfect detector, which no calibration of a real sensor
  measures and under which a filter drops a feature at its first miss and
  trusts every detection; or that no feature is ever seen (every bin 0): a
  filter would never update its map.

Warned, with a count (legal, but a reader should look):

- a condition number beyond :data:`WARN_CONDITION` (the written gate uncertain
  beyond 0.5 %);
- P_D bins of exactly 1 in a profile with no clutter (a feature there is
  removed at its first miss, and nothing explains a detection as clutter);
- a clutter rate of 0 measured over frames (no false alarm in any of them).
"""

from __future__ import annotations

import numpy as np

#: a Hotelling covariance is refused beyond this condition number, warned about beyond :data:`WARN_CONDITION`
MAX_CONDITION = 1e6
WARN_CONDITION = 1e4
#: false alarms per frame: no detector of any sensor detcal reads reports more (the simulators stop at 10,000 too)
MAX_CLUTTER_RATE = 10_000.0


def condition(cov) -> float:
    """2-norm condition number of a symmetric positive definite matrix (largest / smallest eigenvalue)."""
    w = np.linalg.eigvalsh(np.asarray(cov, dtype=np.float64))
    return float(w[-1] / w[0])


def refusal(prof) -> tuple[str, str] | None:
    """(field path, what is wrong) for the first value of ``prof`` no real detector produces, else None."""
    c = prof.clutter
    if c.rate > MAX_CLUTTER_RATE:
        return "clutter.rate", f"{c.rate:g} false alarms per frame is beyond the plausible band [0, {MAX_CLUTTER_RATE:g}]"
    circle, s = prof.detector.circle, prof.sensor
    if prof.detector.kind == "circle2d" and circle is not None and s.n_beams:
        most = s.n_beams / circle.min_points
        if c.rate > most:
            return "clutter.rate", (
                f"{c.rate:g} false alarms per frame is more than a scan of {s.n_beams} beams can hold "
                f"({most:g}: each detection takes at least detector.circle.min_points = {circle.min_points} returns)"
            )
    pd = np.asarray(prof.pd.pd, dtype=np.float64)
    if pd.size and np.all(pd == 0.0):
        return "pd", "every P_D bin is 0: the profile says no feature is ever seen, and a filter would never update its map"
    if pd.size and np.all(pd == 1.0) and c.rate == 0.0:
        return "pd", "every P_D bin is 1 and clutter.rate is 0: a detector that always sees every feature and never reports a false one"
    return None


def suspicions(prof) -> list[str]:
    """What is legal but suspicious in ``prof``, one line each with its count."""
    found = []
    if prof.hotelling is not None:
        k = condition(prof.hotelling.covariance)
        if k > WARN_CONDITION:
            found.append(
                f"hotelling.covariance: condition number {k:.3g} beyond {WARN_CONDITION:g}: the written six-digit covariance leaves the gate "
                f"uncertain by up to {min(k * 5e-7, 1.0):.1%}"
            )
    pd = np.asarray(prof.pd.pd, dtype=np.float64)
    ones = int((pd == 1.0).sum())
    c = prof.clutter
    if c.rate == 0.0 and ones:
        found.append(f"pd: {ones} of {pd.size} P_D bins are 1 with clutter.rate 0: a feature there is removed at its first miss")
    if c.rate == 0.0 and c.frames:
        found.append(f"clutter.rate: 0 false alarms in {c.frames} frames")
    return found
