"""KITTI Velodyne ``.bin`` frames: N x 4 float32 (x, y, z [m], reflectance), sensor frame.

A single ``.bin`` file or a folder of them (sorted by name). KITTI object
frames carry no time: frame ``k`` is stamped ``k * 0.1 s`` (the HDL-64E's
10 Hz), and the log's source says so.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from calib.io.common import file_digest
from detectors.sensor_log import PointClouds, SensorLog, SensorModel
from profiles.errors import DataError, UsageError

PERIOD_NS = 100_000_000


def looks_like_kitti(path: Path) -> bool:
    return path.suffix == ".bin" or (path.is_dir() and any(path.glob("*.bin")))


def read_kitti(path: str | Path) -> SensorLog:
    path = Path(path)
    if not path.exists():
        raise UsageError(f"{path}: no such file or folder")
    files = sorted(path.glob("*.bin")) if path.is_dir() else [path]
    if not files:
        raise UsageError(f"{path}: no .bin frames")
    clouds = []
    for f in files:
        size = f.stat().st_size
        if size == 0:
            raise DataError(f"{f}: empty frame (no points)")
        if size % 16:
            raise DataError(f"{f}: size {size} bytes is not a multiple of 16 (4 float32 per point); truncated?")
        pts = np.fromfile(f, dtype="<f4").reshape(-1, 4)
        bad = np.flatnonzero(~np.isfinite(pts).all(axis=1))
        if bad.size:
            raise DataError(f"{f}: point {int(bad[0])} has a NaN or infinite coordinate")
        clouds.append(pts)
    offsets = np.concatenate([[0], np.cumsum([c.shape[0] for c in clouds])]).astype(np.int64)
    return SensorLog(
        name=path.stem,
        sensor=SensorModel(kind="lidar3d", range_max=120.0),
        clouds=PointClouds(np.arange(len(files), dtype=np.int64) * PERIOD_NS, offsets, np.concatenate(clouds)),
        source={"reader": "kitti", "files": {f.name: file_digest(f) for f in files}, "stamps": "synthetic, 10 Hz by frame order"},
    )
