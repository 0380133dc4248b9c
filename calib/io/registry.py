"""Pick a reader from the path (or an explicit format) and read a log."""

from __future__ import annotations

import dataclasses
from pathlib import Path

from pydantic import BaseModel, ConfigDict, Field

from calib.io.carmen import looks_like_carmen, read_carmen
from calib.io.common import DEFAULT_MAX_BACKSTEP
from calib.io.kitti import looks_like_kitti, read_kitti
from calib.io.native import SUFFIX, is_native, read_native, write_native
from calib.io.rosbag import looks_like_bag, read_rosbag, write_ros2
from calib.io.utias import looks_like_utias, read_utias
from calib.io.victoria import looks_like_victoria, read_victoria
from detectors.logs import SensorLog
from profiles.errors import UsageError

FORMATS = ("native", "carmen", "rosbag", "victoria", "utias", "kitti")
OUTPUT_FORMATS = ("native", "ros2")


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


def detect_format(path: Path) -> str:
    """The format a path most likely holds; a UsageError when none fits."""
    if not path.exists():
        raise UsageError(f"{path}: no such file or folder")
    if path.is_file() and (path.suffix == SUFFIX or is_native(path)):
        return "native"
    if looks_like_bag(path):
        return "rosbag"
    if looks_like_victoria(path):
        return "victoria"
    if looks_like_utias(path):
        return "utias"
    if looks_like_kitti(path):
        return "kitti"
    if looks_like_carmen(path):
        return "carmen"
    raise UsageError(f"{path}: cannot tell the log format from the path; pass --format ({', '.join(FORMATS)})")


def read_log(path: str | Path, fmt: str | None = None, options: ReadOptions | None = None) -> SensorLog:
    """The log at ``path`` in format ``fmt`` (default: from the path); ``options.range_sigma`` replaces the sensor's."""
    opt = options or ReadOptions()
    log = _read(Path(path), fmt, opt)
    if opt.range_sigma is not None:
        if log.sensor is None or log.sensor.kind != "laser2d":
            raise UsageError(f"--range-sigma: {path} has no 2D laser")
        log = dataclasses.replace(log, sensor=type(log.sensor).model_validate({**log.sensor.model_dump(), "range_sigma": opt.range_sigma}))
    return log


def _read(path: Path, fmt: str | None, opt: ReadOptions) -> SensorLog:
    fmt = fmt or detect_format(path)
    if fmt == "native":
        return read_native(path)
    if fmt == "carmen":
        return read_carmen(path, laser=opt.laser, range_max=opt.range_max, max_backstep=opt.max_backstep)
    if fmt == "rosbag":
        return read_rosbag(
            path, scan_topic=opt.scan_topic, odom_topic=opt.odom_topic, truth_topic=opt.truth_topic, max_backstep=opt.max_backstep
        )
    if fmt == "victoria":
        return read_victoria(path, max_backstep=opt.max_backstep)
    if fmt == "utias":
        return read_utias(path, robot=opt.robot, max_backstep=opt.max_backstep)
    if fmt == "kitti":
        return read_kitti(path)
    raise UsageError(f"--format: expected one of {', '.join(FORMATS)}, got {fmt!r}")


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
        if fmt not in OUTPUT_FORMATS:
            raise UsageError(f"--to: expected one of {', '.join(OUTPUT_FORMATS)}, got {fmt!r}")
        return fmt
    if path.suffix == SUFFIX:
        return "native"
    if path.suffix == "":
        return "ros2"
    raise UsageError(f"{path}: cannot tell the output format; use a {SUFFIX} name, a folder name for a ROS 2 bag, or --to")


def write_log(log: SensorLog, path: str | Path, fmt: str | None = None, *, overwrite: bool = False) -> Path:
    path = Path(path)
    if output_format(path, fmt) == "native":
        return write_native(log, path, overwrite=overwrite)
    return write_ros2(log, path, overwrite=overwrite)
