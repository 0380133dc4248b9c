"""Calibration: log readers/writers, simulators, ground truth, labelling, the fits and the validation scores."""

from profiles.version import __version__

__all__ = ["__version__"]
