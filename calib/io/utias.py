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

from calib.io.common import DEFAULT_MAX_BACKSTEP, file_digest, index_of, read_table, require_rows, table_stamps, table_time_order
from detectors.sensor_log import Detections, Landmarks, Odometry, ReferencePoses, SensorLog, SensorModel
from profiles.errors import DataError, UsageError

N_ROBOTS = 5
TARGET_UNKNOWN, TARGET_LANDMARK, TARGET_ROBOT = 0, 1, 2


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
    lm = read_table(path / "Landmark_Groundtruth.dat", 5, "subject x y sx sy")
    landmark_ids = set(lm[:, 0].astype(np.int64).tolist())

    odo = read_table(files["Odometry"], 3, "t v omega")
    ostamp = table_stamps(odo[:, 0], files["Odometry"], "t v omega")
    perm, moved_o = table_time_order(ostamp, files["Odometry"], "odometry", max_backstep)
    odometry = Odometry("velocity", ostamp[perm], odo[perm, 1:])

    meas = read_table(files["Measurement"], 4, "t barcode range bearing")
    require_rows(files["Measurement"], meas, meas[:, 2] >= 0, "t barcode range bearing", "negative range")
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
