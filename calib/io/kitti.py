"""KITTI Velodyne ``.bin`` frames: N x 4 float32 (x, y, z [m], reflectance), sensor frame.

Read: a single ``.bin`` file or a folder of them (sorted by name). KITTI object
frames carry no time: frame ``k`` is stamped ``k * 0.1 s`` (the HDL-64E's
10 Hz), and the log's source says so.

Write (:func:`write_kitti`): a log's point clouds as a folder of ``000000.bin``,
``000001.bin``, ... in the same layout, so that a simulated street can stand in
for KITTI frames (the how-to runs on two such frames). Only the points travel:
KITTI's layout has no room for stamps, poses, odometry or plane truth.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from calib.io.atomic import atomic_output
from calib.io.common import file_digest
from detectors.sensor_log import PointClouds, SensorLog, SensorModel
from profiles.errors import DataError, UsageError

PERIOD_NS = 100_000_000

#: Most points one frame may hold. A spinning lidar's frame holds far fewer (an HDL-64E at 10 Hz about 130 000, a
#: 128-ring Ouster about 260 000); a larger file is not one lidar frame, and reading it would only fill the memory.
MAX_POINTS = 4_000_000


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
        if size // 16 > MAX_POINTS:
            raise DataError(
                f"{f}: {size // 16} points in one frame ({size / 1e9:.3g} GB); a lidar frame holds far fewer "
                f"(at most {MAX_POINTS} accepted; an HDL-64E frame about 130000): not one KITTI Velodyne frame"
            )
        try:
            pts = np.fromfile(f, dtype="<f4").reshape(-1, 4)
        except MemoryError:
            read = sum(c.nbytes for c in clouds)
            raise DataError(f"{path}: the frames need more than {(read + size) / 1e9:.3g} GB of memory, more than this machine can give; "
                            "the log is too large for memory (not damaged): give fewer frames") from None
        bad = np.flatnonzero(~np.isfinite(pts).all(axis=1))
        if bad.size:
            raise DataError(f"{f}: point {int(bad[0])} has a NaN or infinite coordinate")
        clouds.append(pts)
    offsets = np.concatenate([[0], np.cumsum([c.shape[0] for c in clouds])]).astype(np.int64)
    try:
        points = np.concatenate(clouds)
    except MemoryError:
        raise DataError(f"{path}: {len(files)} frames of {int(offsets[-1])} points need {2 * offsets[-1] * 16 / 1e9:.3g} GB of memory, more "
                        "than this machine can give; the log is too large for memory (not damaged): give fewer frames") from None
    return SensorLog(
        name=path.stem,
        sensor=SensorModel(kind="lidar3d", range_max=120.0),
        clouds=PointClouds(np.arange(len(files), dtype=np.int64) * PERIOD_NS, offsets, points),
        source={"reader": "kitti", "files": {f.name: file_digest(f) for f in files}, "stamps": "synthetic, 10 Hz by frame order"},
    )


def write_kitti(log: SensorLog, path: str | Path, *, overwrite: bool = False) -> Path:
    """Write the point clouds of ``log`` to the folder ``path`` as KITTI Velodyne frames, atomically.

    Frame ``k`` becomes ``{k:06d}.bin``: its (P_k, 4) float32 points (x, y, z [m], reflectance; sensor frame),
    little-endian, as :func:`read_kitti` reads them. A log without point clouds, or with an empty frame (which
    KITTI's reader refuses), is refused before anything is written.
    """
    path = Path(path)
    clouds = log.clouds
    if clouds is None:
        raise UsageError(f"{path}: the log {log.name!r} has no point clouds to write as KITTI frames")
    empty = np.flatnonzero(np.diff(clouds.offsets) == 0)
    if empty.size:
        raise DataError(f"{path}: frame {int(empty[0])} of {log.name!r} has no points; a KITTI frame cannot be empty")
    with atomic_output(path, overwrite=overwrite, directory=True) as tmp:
        tmp.mkdir()
        for k in range(len(clouds)):
            clouds.frame(k).astype("<f4", copy=False).tofile(tmp / f"{k:06d}.bin")
    return path
