"""Detector profiles: schema, load/save and registry (filled by the calibration work).

This package imports nothing else of detcal; the shared error hierarchy lives
here so that every other package can raise it.
"""

from profiles.errors import DataError, DetcalError, UsageError

__all__ = ["DataError", "DetcalError", "UsageError"]
