"""Settings derived from the log and the profile where the run's settings give none.

The settings' own defaults (:mod:`slam_runtime.config`) hold for every log:
the optimal pose proposal where the features and the map filter allow it, and
RB-PHD's single-cluster weighting. What depends on the data is derived here,
for the settings the user did not give (a ``--config`` file's keys, the
command's options and ``--set`` changes are given; a group given in part
counts as given whole, so a file's choice is never mixed with a derived one):

* the vehicle model's noise from the noise the log's source states for its
  odometry (:attr:`detectors.sensor_log.Odometry.sigma`: a simulator's
  setting, a data set's documentation), as constant random-walk terms with the
  distance-proportional ones zero, the variance inflated by
  :data:`MOTION_INFLATION`.

The measurement noise floor, P_D and clutter already come from the profile
(:func:`slam_runtime.config.feature_model`, the detection model).
"""

from __future__ import annotations

import numpy as np

from slam_runtime.config import SlamConfig, vehicle_model, with_settings
from slam_runtime.vehicle import VEHICLE_MODELS

#: Factor on the variance of the odometry noise the log states: the C++ RFS-SLAM library's process noise
#: inflation for its simulator (processNoiseInflationFactor 1.5), and on rfs-sim (worlds 4-9) the setting whose final
#: pose sat as close to the batch oracle's posterior as a posterior sample does (docs/results/slam.md).
MOTION_INFLATION = 1.5


def given(key: str, keys: set[str]) -> bool:
    """Whether the dotted setting ``key`` or a group holding it, or a setting inside it, is among ``keys``."""
    return any(k == key or key.startswith(k + ".") or k.startswith(key + ".") for k in keys)


def derived(cfg: SlamConfig, log, profile, keys: set[str]) -> tuple[SlamConfig, dict[str, str]]:
    """(``cfg`` with the derived settings the dotted ``keys`` do not give, {setting group: where it came from})."""
    changes: dict[str, object] = {}
    why: dict[str, str] = {}
    odo = getattr(log, "odometry", None)
    if odo is not None and odo.sigma is not None:
        veh = vehicle_model(odo.kind, cfg.motion, log.vehicle, cfg.features)
        group = next(n for n, c in VEHICLE_MODELS.items() if isinstance(veh, c))
        noise = _from_stated(group, odo.kind, np.asarray(odo.sigma) * np.sqrt(MOTION_INFLATION))
        if noise is not None and not given(f"motion.{group}", keys):
            changes[f"motion.{group}"] = noise
            why["motion"] = f"the log's stated odometry noise, variance x {MOTION_INFLATION:g}"
    return (with_settings(cfg, changes) if changes else cfg), why


def _from_stated(group: str, kind: str, sigma: np.ndarray) -> dict | None:
    """The noise group of the vehicle model ``group`` for odometry of ``kind`` whose columns have the random-walk
    sigmas (per sqrt(s)) ``sigma``; None where the model has no such terms."""
    if group == "increment" and kind == "increment":
        s = [float(v) for v in sigma]
        return {"a_trans": 0.0, "a_rot": 0.0, "a_rot_trans": 0.0, "lateral": 0.0, "s_x": s[0], "s_y": s[1], "s_theta": s[2]}
    return None
