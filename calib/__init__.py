"""Calibration: log readers/writers, the park simulator, ground truth, fits, reports and the CLI."""

__version__ = "0.1.0"
