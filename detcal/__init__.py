"""detcal, the application: the command line, the pipelines (calibrate, self-calibrate, SLAM run, sweep), the
execution engine, run folders, reports and figures, over the libraries ``profiles``, ``detectors``, ``calib`` and
``slam_runtime``."""

from profiles.version import __version__

__all__ = ["__version__"]
