"""Pick a reader from the path (or an explicit format) and read a log; pick a writer from the output path.

Every log format is found through :data:`READERS` (its name -> a
:class:`LogReader`: how a path is recognised and how it is read with the
reader options) and every output format through :data:`WRITERS`; the command
line's ``--format`` and ``--to`` choices are their names. A new format is a
module with its reader function and one registration line here (or in that
module: ``READERS.add(name, LogReader(...))``), as kiss-icp finds its datasets
through a table.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from pathlib import Path

from pydantic import BaseModel, ConfigDict, Field

from calib.io.carmen import looks_like_carmen, read_carmen
from calib.io.common import DEFAULT_MAX_BACKSTEP
from calib.io.kitti import looks_like_kitti, read_kitti, write_kitti
from calib.io.native import SUFFIX, is_native, read_native, write_native
from calib.io.rfsslam import looks_like_rfsslam, read_rfsslam
from calib.io.rosbag import looks_like_bag, read_rosbag, write_ros2
from calib.io.utias import looks_like_utias, read_utias
from calib.io.victoria import looks_like_victoria, read_victoria
from detectors.sensor_log import SensorLog
from profiles.errors import UsageError
from profiles.registry import Registry


class ReadOptions(BaseModel):
    """Reader options; each reader uses the ones that concern it."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)
    max_backstep: float = Field(default=DEFAULT_MAX_BACKSTEP, ge=0.0, allow_inf_nan=False)
    laser: str = "front"
    range_max: float | None = Field(default=None, gt=0.0, allow_inf_nan=False)
    range_sigma: float | None = Field(default=None, gt=0.0, allow_inf_nan=False)
    robot: int = 1
    scan_topic: str | None = None
    odom_topic: str | None = None
    truth_topic: str | None = None


@dataclasses.dataclass(frozen=True)
class LogReader:
    """One log format: ``looks_like(path)`` tells it from the path, ``read(path, options)`` reads it.

    ``fallback``: its test is loose (any text file), so it is tried after the others; ``robots``: a dataset folder
    holds one log per robot (:attr:`ReadOptions.robot` chooses which).
    """

    looks_like: Callable[[Path], bool]
    read: Callable[[Path, ReadOptions], SensorLog]
    fallback: bool = False
    robots: bool = False


@dataclasses.dataclass(frozen=True)
class LogWriter:
    """One output format: ``write(log, path, overwrite)``; chosen from a path whose suffix is ``suffix`` ("" : a folder;
    ``None``: only when named, ``--to``)."""

    write: Callable[[SensorLog, Path, bool], Path]
    suffix: str | None


READERS: Registry[LogReader] = Registry("log format")
READERS.add("native", LogReader(lambda p: p.is_file() and (p.suffix == SUFFIX or is_native(p)), lambda p, o: read_native(p)))
READERS.add("carmen", LogReader(looks_like_carmen, lambda p, o: read_carmen(p, laser=o.laser, range_max=o.range_max, max_backstep=o.max_backstep), fallback=True))
READERS.add("rosbag", LogReader(looks_like_bag, lambda p, o: read_rosbag(
    p, scan_topic=o.scan_topic, odom_topic=o.odom_topic, truth_topic=o.truth_topic, max_backstep=o.max_backstep)))  # fmt: skip
READERS.add("victoria", LogReader(looks_like_victoria, lambda p, o: read_victoria(p, max_backstep=o.max_backstep)))
READERS.add("utias", LogReader(looks_like_utias, lambda p, o: read_utias(p, robot=o.robot, max_backstep=o.max_backstep), robots=True))
READERS.add("kitti", LogReader(looks_like_kitti, lambda p, o: read_kitti(p)))
READERS.add("rfsslam", LogReader(looks_like_rfsslam, lambda p, o: read_rfsslam(p)))

WRITERS: Registry[LogWriter] = Registry("output format")
WRITERS.add("native", LogWriter(lambda log, p, overwrite: write_native(log, p, overwrite=overwrite), SUFFIX))
WRITERS.add("ros2", LogWriter(lambda log, p, overwrite: write_ros2(log, p, overwrite=overwrite), ""))
WRITERS.add("kitti", LogWriter(lambda log, p, overwrite: write_kitti(log, p, overwrite=overwrite), None))


def detect_format(path: Path) -> str:
    """The format a path most likely holds; a UsageError when none fits."""
    if not path.exists():
        raise UsageError(f"{path}: no such file or folder")
    items = READERS.items()
    for name, reader in [i for i in items if not i[1].fallback] + [i for i in items if i[1].fallback]:
        if reader.looks_like(path):
            return name
    raise UsageError(f"{path}: cannot tell the log format from the path; pass --format ({', '.join(READERS.names())})")


def read_log(path: str | Path, fmt: str | None = None, options: ReadOptions | None = None) -> SensorLog:
    """The log at ``path`` in format ``fmt`` (default: from the path); ``options.range_sigma`` replaces the sensor's."""
    opt = options or ReadOptions()
    path = Path(path)
    fmt = fmt or detect_format(path)
    if fmt not in READERS:
        raise UsageError(f"--format: expected one of {', '.join(READERS.names())}, got {fmt!r}")
    log = READERS.get(fmt).read(path, opt)
    if opt.range_sigma is not None:
        if log.sensor is None or log.sensor.kind != "laser2d":
            raise UsageError(f"--range-sigma: {path} has no 2D laser")
        log = dataclasses.replace(log, sensor=type(log.sensor).model_validate({**log.sensor.model_dump(), "range_sigma": opt.range_sigma}))
    return log


def input_refs(path: Path, log: SensorLog) -> list:
    """The input files of a log read from ``path``, with their sha256, for provenance.

    A native log is identified by its content (:func:`calib.io.native.content_digest`:
    the same on every machine, whatever zlib compressed it); a folder by each
    file its reader read; any other file by its bytes.
    """
    from calib.io.common import file_digest
    from calib.io.native import content_digest
    from profiles.profile import InputRef

    path = Path(path)
    if path.is_file() and is_native(path):
        return [InputRef(name=path.name, sha256=content_digest(path))]
    files = log.source.get("files")
    if isinstance(files, dict) and files:
        return [InputRef(name=str(k), sha256=str(v)) for k, v in files.items()]
    if isinstance(log.source.get("sha256"), str) and path.is_file():
        return [InputRef(name=path.name, sha256=str(log.source["sha256"]))]
    return [InputRef(name=path.name, sha256=file_digest(path))] if path.exists() else []


def output_format(path: Path, fmt: str | None) -> str:
    if fmt is not None:
        if fmt not in WRITERS:
            raise UsageError(f"--to: expected one of {', '.join(WRITERS.names())}, got {fmt!r}")
        return fmt
    for name, writer in WRITERS.items():
        if path.suffix == writer.suffix:
            return name
    raise UsageError(f"{path}: cannot tell the output format; use a {SUFFIX} name, a folder name for a ROS 2 bag, or --to")


def write_log(log: SensorLog, path: str | Path, fmt: str | None = None, *, overwrite: bool = False) -> Path:
    path = Path(path)
    return WRITERS.get(output_format(path, fmt)).write(log, path, overwrite)
