"""Per-step hooks of the labelled map filters (LMB, delta-GLMB): the label history and the hypothesis count.

Hooks are called by :func:`slam_runtime.run.run_slam` after every step as
``hook(k, slam) -> float`` (recorded per step under ``hook.name``); with a
filter that has no labels they record NaN.

* :class:`LabelHistory` follows the best particle's labelled map estimate: a
  label that enters the estimate starts a span (a track birth), one that leaves
  it ends its span (a track death); its per-step value is the number of labels
  in the estimate. A label is the step and measurement its birth track came
  from (:func:`slam_runtime.labelled.label_parts`), so the same landmark keeps its
  label across a loop, and particles that gave birth to a landmark from the
  same measurement share the label.
* :class:`HypothesisCount` records the mean number of hypotheses per particle.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from slam_runtime.labelled import label_parts


@dataclass
class Span:
    """One stretch of steps during which a label was in the best particle's map estimate."""

    label: int
    first: int  # step it entered the estimate
    last: int  # last step it was in the estimate
    ended: bool  # it left the estimate before the end of the run
    state: np.ndarray  # (dx,) its last estimated state
    existence: float  # its last existence probability


class LabelHistory:
    """Hook: births and deaths of the labels of the best particle's map estimate (module docstring)."""

    name = "map_labels"

    def __init__(self) -> None:
        self.spans: list[Span] = []
        self._open: dict[int, Span] = {}

    def __call__(self, k: int, slam) -> float:
        mf = slam.mf
        if not mf.labelled:
            return float("nan")
        lab, x, r = mf.labels(slam.maps, slam.best())
        seen = set()
        for i, lb in enumerate(lab.tolist()):
            seen.add(lb)
            sp = self._open.get(lb)
            if sp is None:
                sp = self._open[lb] = Span(lb, k, k, False, x[i].copy(), float(r[i]))
                self.spans.append(sp)
            sp.last, sp.state, sp.existence = k, x[i].copy(), float(r[i])
        for lb in [lb for lb in self._open if lb not in seen]:
            self._open.pop(lb).ended = True
        return float(lab.size)

    def births(self) -> np.ndarray:
        """(S,) step of every span's start."""
        return np.array([s.first for s in self.spans], dtype=np.int64)

    def deaths(self) -> np.ndarray:
        """(D,) step after the last of every span that ended."""
        return np.array([s.last + 1 for s in self.spans if s.ended], dtype=np.int64)

    def table(self, stamps: np.ndarray) -> tuple[list[str], list[np.ndarray], list[str]]:
        """Columns of ``labels.csv`` (one row per span): header, columns, printf formats."""
        n = len(self.spans)
        lab = np.array([s.label for s in self.spans], dtype=np.int64)
        step, meas = label_parts(lab)
        first = np.array([s.first for s in self.spans], dtype=np.int64)
        last = np.array([s.last for s in self.spans], dtype=np.int64)
        d = self.spans[0].state.size if n else 2
        state = np.array([s.state for s in self.spans]).reshape(n, d)
        cols = [lab, step, meas, first, last, stamps[first] if n else first, stamps[last] if n else last,
                np.array([s.ended for s in self.spans], dtype=np.int64), *state.T, np.array([s.existence for s in self.spans])]  # fmt: skip
        header = ["label", "birth_step", "birth_measurement", "first_step", "last_step", "first_stamp_ns", "last_stamp_ns", "ended",
                  *[f"x{i}" if d != 2 else "xy"[i] for i in range(d)], "existence"]  # fmt: skip
        fmts = ["%d"] * 8 + ["%.6f"] * d + ["%.6f"]
        return header, cols, fmts


class HypothesisCount:
    """Hook: the mean number of hypotheses per particle after every step."""

    name = "hypotheses"

    def __call__(self, k: int, slam) -> float:
        mf = slam.mf
        if not mf.labelled:
            return float("nan")
        return float(np.mean(mf.hypotheses(slam.maps)))


def labelled_hooks() -> tuple[LabelHistory, HypothesisCount]:
    return LabelHistory(), HypothesisCount()
