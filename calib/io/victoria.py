"""Victoria Park ASCII release (ACFR; Guivant & Nebot 2001).

A folder with ``measurements.dat`` (``t range bearing diameter``, bearing in
the laser frame 0..pi with pi/2 straight ahead), ``inputs.dat`` (``t speed
steering``: encoder speed of the rear left wheel, front-wheel steering) and
``gps.dat`` (``t x y``, local frame, dropouts and jumps). The log carries:

* detections, one frame per distinct timestamp, bearing moved to the sensor
  frame (0 = straight ahead, left positive) and ``diameter`` as a descriptor;
* Ackermann odometry (speed at the encoder, as recorded);
* GPS as a ``gps`` reference (theta NaN) that locates the laser, 3.78 m ahead of and 0.50 m left of
  the rear-axle centre the filters estimate: the data set's own vehicle model (Guivant & Nebot 2001)
  propagates the laser's position, and published results compare that state with the GPS; the
  antenna's own lever arm is not published. The data bear it out: the lever arm that best fits three
  RB-PHD trajectories to the GPS (a rigid fit plus two offsets) is (4.3, 1.4), (4.0, 1.1) and
  (4.3, 1.6) m, within a metre of the laser, where the rear axle is 4 m off;
* the commonly used geometry: wheelbase 2.83 m, encoder 0.76 m from the
  rear-axle centre, laser 3.78 m forward and 0.50 m left of the rear axle.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from calib.io.common import DEFAULT_MAX_BACKSTEP, file_digest, read_table, require_rows, table_stamps, table_time_order
from detectors.sensor_log import Detections, Mount, Odometry, ReferencePoses, SensorLog, SensorModel, Vehicle
from profiles.errors import UsageError

FILES = ("measurements.dat", "inputs.dat", "gps.dat")
WHEELBASE = 2.83
ENCODER_OFFSET = 0.76
LASER_MOUNT = Mount(x=3.78, y=0.50, theta=0.0)
RANGE_MAX = 80.0  # m, the SICK LMS 200's range in this setting (the released ranges peak at 75.3 m)

#: Bounds the vehicle cannot exceed (the logged speed peaks at 6.6 m/s, the steering at 0.59 rad; a car's wheels
#: turn less than 1 rad): a row beyond them is damaged or mistyped, and would send the filter nowhere.
MAX_SPEED = 40.0  # m/s
MAX_STEERING = 1.0  # rad


def looks_like_victoria(path: Path) -> bool:
    return path.is_dir() and all((path / f).is_file() for f in FILES[:2])


def read_victoria(path: str | Path, *, max_backstep: float = DEFAULT_MAX_BACKSTEP) -> SensorLog:
    path = Path(path)
    if not path.is_dir():
        raise UsageError(f"{path}: expected the Victoria Park folder (with {FILES[0]}, {FILES[1]} and optionally {FILES[2]})")
    for f in FILES[:2]:
        if not (path / f).is_file():
            raise UsageError(f"{path / f}: missing; a Victoria Park folder needs {FILES[0]} and {FILES[1]} ({FILES[2]} is optional)")
    meas = read_table(path / "measurements.dat", 4, "t range bearing diameter")
    what = "t range bearing diameter"
    require_rows(path / "measurements.dat", meas, meas[:, 1] >= 0, what, "negative range")
    require_rows(path / "measurements.dat", meas, meas[:, 1] <= RANGE_MAX, what, f"range beyond the laser's {RANGE_MAX:g} m")
    # the laser's bearings run from 0 to pi (0: to the right); a little slack for rounding
    require_rows(path / "measurements.dat", meas, np.abs(meas[:, 2] - np.pi / 2) <= np.pi / 2 + 1e-3, what, "bearing outside 0..pi rad")
    require_rows(path / "measurements.dat", meas, meas[:, 3] >= 0, what, "negative diameter")
    stamp = table_stamps(meas[:, 0], path / "measurements.dat", "t range bearing diameter")
    perm, moved_m = table_time_order(stamp, path / "measurements.dat", "measurement", max_backstep)
    meas, stamp = meas[perm], stamp[perm]
    frame_stamp, frame = np.unique(stamp, return_inverse=True)
    detections = Detections(
        frame_stamp, frame, meas[:, 1], meas[:, 2] - np.pi / 2, {"diameter": meas[:, 3]}
    )
    inputs = read_table(path / "inputs.dat", 3, "t speed steering")
    ok_speed, ok_steer = np.abs(inputs[:, 1]) <= MAX_SPEED, np.abs(inputs[:, 2]) <= MAX_STEERING
    require_rows(path / "inputs.dat", inputs, ok_speed, "t speed steering", f"speed beyond {MAX_SPEED:g} m/s (the vehicle cannot drive so fast)")
    require_rows(path / "inputs.dat", inputs, ok_steer, "t speed steering", f"steering beyond {MAX_STEERING:g} rad (the vehicle's wheels cannot turn so far)")
    istamp = table_stamps(inputs[:, 0], path / "inputs.dat", "t speed steering")
    perm, moved_i = table_time_order(istamp, path / "inputs.dat", "input", max_backstep)
    odometry = Odometry("ackermann", istamp[perm], inputs[perm, 1:])
    reference = {}
    moved_g = 0
    if (path / "gps.dat").is_file():
        gps = read_table(path / "gps.dat", 3, "t x y")
        gstamp = table_stamps(gps[:, 0], path / "gps.dat", "t x y")
        perm, moved_g = table_time_order(gstamp, path / "gps.dat", "GPS", max_backstep)
        poses = np.column_stack([gps[perm, 1:], np.full(gps.shape[0], np.nan)])
        # the released GPS is compared with the laser's position (see the module docstring)
        reference["gps"] = ReferencePoses("gps", gstamp[perm], poses, point=(LASER_MOUNT.x, LASER_MOUNT.y))
    sensor = SensorModel(kind="detector", range_min=0.0, range_max=RANGE_MAX, fov=np.pi, mount=LASER_MOUNT)
    return SensorLog(
        name="victoria_park",
        sensor=sensor,
        odometry=odometry,
        reference=reference,
        detections=detections,
        vehicle=Vehicle(wheelbase=WHEELBASE, encoder_offset=ENCODER_OFFSET),
        source={
            "reader": "victoria",
            "files": {f: file_digest(path / f) for f in FILES if (path / f).is_file()},
            "reordered": {"detections": moved_m, "odometry": moved_i, "reference:gps": moved_g},
        },
    )
