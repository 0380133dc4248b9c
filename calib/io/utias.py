"""UTIAS Multi-Robot Cooperative Localization and Mapping (MRCLAM) dataset, one robot.

Leung, Halpern, Barfoot, Liu (IJRR 2011). A dataset folder holds
``Barcodes.dat`` (subject -> barcode), ``Landmark_Groundtruth.dat``
(subjects 6..20: x, y and their std-devs) and per robot
``RobotN_{Odometry,Measurement,Groundtruth}.dat``. The log carries:

* velocity odometry (v, omega commands);
* detections (monocular camera), one frame per distinct timestamp, with the
  descriptors ``barcode``, ``subject`` (-1 for a barcode not in the map) and
  ``target``: 1 for a landmark, 2 for another robot, 0 for an unknown barcode;
* Vicon poses as the ``ground_truth`` reference; landmark truth with ids = subjects.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from calib.io.common import DEFAULT_MAX_BACKSTEP, data_line, file_digest, index_of, read_table, require_rows, table_stamps, table_time_order
from detectors.sensor_log import Detections, Landmarks, Odometry, ReferencePoses, SensorLog, SensorModel
from profiles.errors import DataError, UsageError

N_ROBOTS = 5
TARGET_UNKNOWN, TARGET_LANDMARK, TARGET_ROBOT = 0, 1, 2

#: Bounds no MRCLAM robot reaches (iRobot Creates: at most 0.5 m/s; the logs peak at 0.09 m/s and 0.6 rad/s); a
#: command beyond them is a damaged or mistyped row, refused with its line.
MAX_SPEED = 2.0  # m/s
MAX_TURN_RATE = 2 * np.pi  # rad/s


def looks_like_utias(path: Path) -> bool:
    return path.is_dir() and (path / "Barcodes.dat").is_file() and (path / "Landmark_Groundtruth.dat").is_file()


def read_utias(path: str | Path, *, robot: int = 1, max_backstep: float = DEFAULT_MAX_BACKSTEP) -> SensorLog:
    path = Path(path)
    if not looks_like_utias(path):
        raise UsageError(f"{path}: expected a UTIAS MRCLAM dataset folder (with Barcodes.dat, Landmark_Groundtruth.dat)")
    if not 1 <= robot <= N_ROBOTS:
        raise UsageError(f"--robot: expected 1..{N_ROBOTS}, got {robot}")
    files = {k: path / f"Robot{robot}_{k}.dat" for k in ("Odometry", "Measurement", "Groundtruth")}
    for f in files.values():
        if not f.is_file():
            raise UsageError(f"{f}: missing")
    barcodes = read_table(path / "Barcodes.dat", 2, "subject barcode").astype(np.int64)
    _unique_column(path / "Barcodes.dat", barcodes[:, 1], "subject barcode", "barcode", barcodes[:, 0], "subject")
    _unique_column(path / "Barcodes.dat", barcodes[:, 0], "subject barcode", "subject", barcodes[:, 1], "barcode")
    lm = read_table(path / "Landmark_Groundtruth.dat", 5, "subject x y sx sy")
    _unique_column(path / "Landmark_Groundtruth.dat", lm[:, 0], "subject x y sx sy", "subject", lm[:, 1], "x")
    landmark_ids = set(lm[:, 0].astype(np.int64).tolist())

    odo = read_table(files["Odometry"], 3, "t v omega")
    what = "t v omega"
    require_rows(files["Odometry"], odo, np.abs(odo[:, 1]) <= MAX_SPEED, what, f"speed beyond {MAX_SPEED:g} m/s (no MRCLAM robot drives so fast)")
    require_rows(files["Odometry"], odo, np.abs(odo[:, 2]) <= MAX_TURN_RATE, what, "turn rate beyond 2 pi rad/s (no MRCLAM robot turns so fast)")
    ostamp = table_stamps(odo[:, 0], files["Odometry"], "t v omega")
    if ostamp.size > 1 and ostamp.min() == ostamp.max():
        raise DataError(
            f"{files['Odometry']}: every one of the {ostamp.size} odometry records is stamped {float(odo[0, 0])!r} s; "
            "the odometry carries no time (velocities cannot be integrated)"
        )
    perm, moved_o = table_time_order(ostamp, files["Odometry"], "odometry", max_backstep)
    odometry = Odometry("velocity", ostamp[perm], odo[perm, 1:])

    meas = read_table(files["Measurement"], 4, "t barcode range bearing")
    require_rows(files["Measurement"], meas, meas[:, 2] >= 0, "t barcode range bearing", "negative range")
    require_rows(files["Measurement"], meas, np.abs(meas[:, 3]) <= np.pi, "t barcode range bearing", "bearing outside -pi..pi rad")
    mstamp = table_stamps(meas[:, 0], files["Measurement"], "t barcode range bearing")
    perm, moved_m = table_time_order(mstamp, files["Measurement"], "measurement", max_backstep)
    meas, mstamp = meas[perm], mstamp[perm]
    code = meas[:, 1]
    if not np.array_equal(code, np.round(code)):
        raise DataError(f"{files['Measurement']}: barcode column holds non-integers")
    code = code.astype(np.int64)
    row = index_of(code, barcodes[:, 1])
    subject = np.where(row >= 0, barcodes[np.maximum(row, 0), 0], -1).astype(np.int64)
    target = np.where(
        np.isin(subject, list(landmark_ids)), TARGET_LANDMARK, np.where((subject >= 1) & (subject <= N_ROBOTS), TARGET_ROBOT, TARGET_UNKNOWN)
    ).astype(np.int64)
    frame_stamp, frame = np.unique(mstamp, return_inverse=True)
    detections = Detections(frame_stamp, frame, meas[:, 2], meas[:, 3], {"barcode": code, "subject": subject, "target": target})

    gt = read_table(files["Groundtruth"], 4, "t x y theta")
    gstamp = table_stamps(gt[:, 0], files["Groundtruth"], "t x y theta")
    perm, moved_g = table_time_order(gstamp, files["Groundtruth"], "ground truth", max_backstep)
    reference = {"ground_truth": ReferencePoses("ground_truth", gstamp[perm], gt[perm, 1:])}

    landmarks = Landmarks(lm[:, 0].astype(np.int64), lm[:, 1:3], None, lm[:, 3:5])
    names = ["Barcodes.dat", "Landmark_Groundtruth.dat", *(f.name for f in files.values())]
    return SensorLog(
        name=f"utias_{path.name}_robot{robot}",
        sensor=SensorModel(kind="camera"),
        odometry=odometry,
        reference=reference,
        landmarks=landmarks,
        detections=detections,
        source={
            "reader": "utias",
            "robot": robot,
            "files": {n: file_digest(path / n) for n in names},
            "reordered": {"odometry": moved_o, "detections": moved_m, "reference:ground_truth": moved_g},
        },
    )


def _unique_column(path: Path, column: np.ndarray, what: str, name: str, other: np.ndarray, other_name: str) -> None:
    """Refuse a ``name`` listed on two rows (a barcode for two subjects, a subject twice), naming both lines."""
    values, first, counts = np.unique(column, return_index=True, return_counts=True)
    if not (counts > 1).any():
        return
    dup = values[counts > 1][0]
    rows = np.flatnonzero(column == dup)
    a, b = int(rows[0]), int(rows[1])
    raise DataError(
        f"{path}:{data_line(path, b)}: {what}: {name} {dup:g} is listed twice (line {data_line(path, a)} with {other_name} {other[a]:g}, "
        f"this line with {other_name} {other[b]:g}); each {name} must be listed once"
    )
