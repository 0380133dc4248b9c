"""Named figures against thresholds: the pass/fail verdicts of the ground-truth quality and data sufficiency.

A :class:`Check` is one figure (a name a user can look up, its value, its
unit) against one threshold, either a floor (``min``) or a ceiling (``max``).
A :class:`Verdict` is a list of checks; it passes when every check does, and
its message names the first failed figure with its value and threshold.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal


@dataclass(frozen=True)
class Check:
    """One figure against a threshold; a NaN value (nothing to measure) passes and says so in ``note``."""

    name: str
    value: float
    threshold: float
    bound: Literal["min", "max"]
    what: str
    unit: str = ""

    @property
    def passed(self) -> bool:
        if math.isnan(self.value):
            return True
        return self.value >= self.threshold if self.bound == "min" else self.value <= self.threshold

    def describe(self) -> str:
        """'name value < threshold (what)' for a failure, 'name value (>= threshold)' otherwise."""
        u = f" {self.unit}" if self.unit else ""
        if self.passed:
            return f"{self.name} {_fmt(self.value)}{u} ({'>=' if self.bound == 'min' else '<='} {_fmt(self.threshold)}{u})"
        op = "<" if self.bound == "min" else ">"
        return f"{self.name} {_fmt(self.value)}{u} {op} {_fmt(self.threshold)}{u} ({self.what})"

    def as_dict(self) -> dict:
        return {
            "value": None if math.isnan(self.value) else float(self.value),
            "threshold": float(self.threshold),
            "bound": self.bound,
            "passed": self.passed,
            "what": self.what,
            **({"unit": self.unit} if self.unit else {}),
        }


def _fmt(v: float) -> str:
    if math.isnan(v):
        return "n/a"
    if float(v).is_integer() and abs(v) < 1e9:
        return str(int(v))
    return f"{v:.3g}"


@dataclass(frozen=True)
class Verdict:
    """Checks of one kind (``kind``: 'ground truth', 'data') for one log or calibration."""

    kind: str
    checks: tuple[Check, ...]

    @property
    def passed(self) -> bool:
        return all(c.passed for c in self.checks)

    @property
    def failures(self) -> list[Check]:
        return [c for c in self.checks if not c.passed]

    def message(self, subject: str) -> str:
        """One line: '<subject>: <kind> fails: <first failed figure> [and N more]' (or passes)."""
        f = self.failures
        if not f:
            return f"{subject}: {self.kind} passes its {len(self.checks)} checks"
        more = f" (and {len(f) - 1} more: {', '.join(c.name for c in f[1:])})" if len(f) > 1 else ""
        return f"{subject}: {self.kind} fails: {f[0].describe()}{more}"

    def as_dict(self) -> dict:
        return {"passed": self.passed, "checks": {c.name: c.as_dict() for c in self.checks}}
