"""The exported data of the C++ RFS-SLAM library's 2D simulator (``rbphdslam2dSim``, Leung & Inostroza).

A folder (the simulator's ``logDirPrefix``) with ``gtPose.dat`` (``t x y
theta``, one row per time step), ``odometry.dat`` (``t dx dy dtheta``: the
noisy pose increment into step k, in the frame of step k - 1),
``measurement.dat`` (``t range bearing``, bearing from the vehicle's heading,
landmarks and clutter unlabelled), ``gtLandmark.dat`` (``x y t_first_seen``)
and ``simSettings.xml`` (the copy of the configuration the simulator ran). The
log carries one frame per time step (steps without a measurement too),
increment odometry with the noise the configuration states (``vardx``,
``vardy``, ``vardz``: variance x dt^2 per step), ground truth and the
landmarks; the sensor is a detection-level range-bearing sensor over the full
circle between the configuration's range limits. :func:`scenario` reads the
configuration as :class:`profiles.parameters.RfsSimConfig` (detcal's
``rfs-sim`` scenario), whose :func:`calib.sim.rfs.truth_profile` is the
profile of the simulator's true detection statistics.
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np

from calib.io.common import file_digest, read_table, require_rows, table_stamps
from detectors.sensor_log import Detections, Landmarks, Odometry, ReferencePoses, SensorLog, SensorModel
from profiles.errors import DataError, UsageError
from profiles.parameters import RfsSimConfig

FILES = ("gtPose.dat", "odometry.dat", "measurement.dat", "gtLandmark.dat", "simSettings.xml")

#: (RfsSimConfig field, path in simSettings.xml) of the settings the reader uses
_SETTINGS = {
    "dt": "sec_per_timestep", "var_odometry": "trajectory/vardx", "landmarks": "landmarks/nLandmarks",
    "range_min": "measurements/rangeLimitMin", "range_max": "measurements/rangeLimitMax", "pd": "measurements/probDetection",
    "clutter_intensity": "measurements/clutterIntensity", "var_range": "measurements/varzr", "var_bearing": "measurements/varzb",
}  # fmt: skip


def looks_like_rfsslam(path: Path) -> bool:
    return path.is_dir() and all((path / f).is_file() for f in FILES)


def _settings(path: Path) -> dict[str, float]:
    f = path / "simSettings.xml"
    if not f.is_file():
        raise UsageError(f"{f}: missing; the simulator's export folder holds the copy of its configuration")
    try:
        root = ET.parse(f).getroot()
    except ET.ParseError as exc:
        raise DataError(f"{f}: not readable XML ({exc})") from None
    out = {}
    for key, where in (*_SETTINGS.items(), ("vardy", "trajectory/vardy"), ("vardz", "trajectory/vardz"), ("steps", "timesteps")):
        node = root.find(where)
        try:
            out[key] = float(node.text)
        except (AttributeError, TypeError, ValueError):
            raise DataError(f"{f}: config/{where}: expected a number") from None
    return out


def scenario(path: str | Path) -> RfsSimConfig:
    """The simulator's configuration (``simSettings.xml``) as detcal's rfs-sim scenario settings."""
    s = _settings(Path(path))
    try:
        return RfsSimConfig(steps=int(s["steps"]), landmarks=int(s["landmarks"]), **{k: s[k] for k in _SETTINGS if k not in ("landmarks",)})
    except ValueError as exc:
        raise DataError(f"{Path(path) / 'simSettings.xml'}: {exc}") from None


def read_rfsslam(path: str | Path) -> SensorLog:
    path = Path(path)
    if not path.is_dir():
        raise UsageError(f"{path}: expected the simulator's export folder (with {', '.join(FILES)})")
    for f in FILES:
        if not (path / f).is_file():
            raise UsageError(f"{path / f}: missing; the simulator's export folder holds {', '.join(FILES)}")
    s = _settings(path)
    pose = read_table(path / "gtPose.dat", 4, "t x y theta")
    stamps = table_stamps(pose[:, 0], path / "gtPose.dat", "t x y theta")
    require_rows(path / "gtPose.dat", pose, np.r_[True, np.diff(stamps) > 0], "t x y theta", "time not after the previous row's")
    odo = read_table(path / "odometry.dat", 4, "t dx dy dtheta")
    ostamp = table_stamps(odo[:, 0], path / "odometry.dat", "t dx dy dtheta")
    require_rows(path / "odometry.dat", odo, np.r_[True, np.diff(ostamp) > 0], "t dx dy dtheta", "time not after the previous row's")
    meas = read_table(path / "measurement.dat", 3, "t range bearing")
    require_rows(path / "measurement.dat", meas, meas[:, 1] >= 0, "t range bearing", "negative range")
    mstamp = table_stamps(meas[:, 0], path / "measurement.dat", "t range bearing")
    # every measurement at one of the steps (the times are printed to the microsecond: matched to the nearest step)
    k = np.clip(np.searchsorted(stamps, mstamp), 1, stamps.size - 1)
    k = np.where(np.abs(stamps[k - 1] - mstamp) < np.abs(stamps[k] - mstamp), k - 1, k)
    require_rows(path / "measurement.dat", meas, np.abs(stamps[k] - mstamp) < 1e6, "t range bearing", "time at no time step of gtPose.dat")
    require_rows(path / "measurement.dat", meas, np.r_[True, np.diff(k) >= 0], "t range bearing", "time before the previous row's")
    lm = read_table(path / "gtLandmark.dat", 3, "x y t_first_seen")
    dt = s["dt"]
    sigma = tuple(float(np.sqrt(s[v] * dt)) for v in ("var_odometry", "vardy", "vardz"))  # per-step std sqrt(var) dt, per sqrt(s)
    sensor = SensorModel(kind="detector", range_min=s["range_min"], range_max=s["range_max"], fov=2 * np.pi, range_sigma=float(np.sqrt(s["var_range"])))
    return SensorLog(
        name=f"rfsslam_{path.name}",
        sensor=sensor,
        odometry=Odometry("increment", ostamp, odo[:, 1:], sigma),
        reference={"ground_truth": ReferencePoses("ground_truth", stamps, pose[:, 1:])},
        landmarks=Landmarks(np.arange(1, lm.shape[0] + 1, dtype=np.int64), lm[:, :2]),
        detections=Detections(stamps, k.astype(np.int64), meas[:, 1], meas[:, 2], {}),
        source={"reader": "rfsslam", "files": {f: file_digest(path / f) for f in FILES}},
    )
