"""detcal's native log format (``.dlog``), version 1.

One zip file (deflate-compressed), written deterministically (fixed member
order and dates, so the same log gives the same bytes):

* ``meta.json`` -- ``{"format": "detcal-log", "version": 1, "name", "sensor",
  "source", "streams"}``; ``streams`` says which streams are present, their
  lengths, the odometry kind, reference sources and detection descriptors;
* one ``.npy`` member per array, named ``<stream>/<field>.npy``:
  ``scan/{stamp,ranges,intensities,odom_pose}``, ``odometry/{stamp,values}``,
  ``reference/<source>/{stamp,poses}``, ``landmarks/{ids,xy,radius,sigma}``,
  ``detections/{frame_stamp,frame,range,bearing}`` and
  ``detections/descriptors/<name>``, ``clouds/{stamp,offsets,points}``,
  ``planes/{ids,normal,offset,vertices,offsets,kind}``.

Arrays keep their dtypes exactly (stamps int64 ns, ranges float32 with NaN for
no return), so a round trip is lossless bit for bit.
"""

from __future__ import annotations

import io
import json
import zipfile
import zlib
from pathlib import Path

import numpy as np
from pydantic import ValidationError

from calib.io.atomic import atomic_output
from detectors.logs import (
    Detections,
    Landmarks,
    Odometry,
    PlaneLandmarks,
    PointClouds,
    ReferencePoses,
    ScanBatch,
    SensorLog,
    SensorModel,
    Vehicle,
)
from profiles.errors import DataError

FORMAT = "detcal-log"
VERSION = 1
SUFFIX = ".dlog"
_DATE = (1980, 1, 1, 0, 0, 0)


def _arrays(log: SensorLog) -> tuple[dict, dict[str, np.ndarray]]:
    streams: dict = {}
    arrays: dict[str, np.ndarray] = {}
    if log.scans is not None:
        s = log.scans
        streams["scan"] = {"n": len(s), "intensities": s.intensities is not None, "odom_pose": s.odom_pose is not None}
        arrays["scan/stamp"] = s.stamp
        arrays["scan/ranges"] = s.ranges
        if s.intensities is not None:
            arrays["scan/intensities"] = s.intensities
        if s.odom_pose is not None:
            arrays["scan/odom_pose"] = s.odom_pose
    if log.odometry is not None:
        streams["odometry"] = {"n": len(log.odometry), "kind": log.odometry.kind}
        arrays["odometry/stamp"] = log.odometry.stamp
        arrays["odometry/values"] = log.odometry.values
    if log.reference:
        streams["reference"] = {k: {"n": len(r)} for k, r in sorted(log.reference.items())}
        for k, r in sorted(log.reference.items()):
            arrays[f"reference/{k}/stamp"] = r.stamp
            arrays[f"reference/{k}/poses"] = r.poses
    if log.landmarks is not None:
        lm = log.landmarks
        streams["landmarks"] = {"n": len(lm)}
        arrays.update({"landmarks/ids": lm.ids, "landmarks/xy": lm.xy, "landmarks/radius": lm.radius, "landmarks/sigma": lm.sigma})
    if log.detections is not None:
        d = log.detections
        streams["detections"] = {"n": len(d), "n_frames": d.n_frames, "descriptors": sorted(d.descriptors)}
        arrays.update(
            {"detections/frame_stamp": d.frame_stamp, "detections/frame": d.frame, "detections/range": d.range, "detections/bearing": d.bearing}
        )
        for name in sorted(d.descriptors):
            arrays[f"detections/descriptors/{name}"] = d.descriptors[name]
    if log.clouds is not None:
        c = log.clouds
        streams["clouds"] = {"n": len(c), "points": int(c.points.shape[0])}
        arrays.update({"clouds/stamp": c.stamp, "clouds/offsets": c.offsets, "clouds/points": c.points})
    if log.planes is not None:
        pl = log.planes
        streams["planes"] = {"n": len(pl)}
        arrays.update(
            {
                "planes/ids": pl.ids, "planes/normal": pl.normal, "planes/offset": pl.offset,
                "planes/vertices": pl.vertices, "planes/offsets": pl.offsets, "planes/kind": pl.kind,
            }
        )
    return streams, arrays


def _member(zf: zipfile.ZipFile, name: str, data: bytes) -> None:
    info = zipfile.ZipInfo(name, date_time=_DATE)
    info.compress_type = zipfile.ZIP_DEFLATED
    info.external_attr = 0o644 << 16
    zf.writestr(info, data, compresslevel=6)


def write_native(log: SensorLog, path: str | Path, *, overwrite: bool = False) -> Path:
    """Write ``log`` to ``path`` atomically; refuses to replace a file unless ``overwrite``."""
    path = Path(path)
    streams, arrays = _arrays(log)
    meta = {
        "format": FORMAT,
        "version": VERSION,
        "name": log.name,
        "sensor": None if log.sensor is None else log.sensor.model_dump(mode="json"),
        "vehicle": None if log.vehicle is None else log.vehicle.model_dump(mode="json"),
        "source": dict(log.source),
        "streams": streams,
    }
    with atomic_output(path, overwrite=overwrite) as tmp:
        with zipfile.ZipFile(tmp, "w") as zf:
            _member(zf, "meta.json", json.dumps(meta, sort_keys=True, indent=1).encode())
            for key, arr in arrays.items():
                buf = io.BytesIO()
                np.lib.format.write_array(buf, np.ascontiguousarray(arr), allow_pickle=False)
                _member(zf, f"{key}.npy", buf.getvalue())
    return path


def is_native(path: Path) -> bool:
    return path.suffix == SUFFIX or (path.is_file() and zipfile.is_zipfile(path) and _has_meta(path))


def _has_meta(path: Path) -> bool:
    try:
        with zipfile.ZipFile(path) as zf:
            return "meta.json" in zf.namelist()
    except (OSError, zipfile.BadZipFile):
        return False


def read_native(path: str | Path) -> SensorLog:
    """Read a ``.dlog`` file; every defect is a :class:`DataError` naming the file and member."""
    path = Path(path)
    try:
        zf = zipfile.ZipFile(path)
    except FileNotFoundError:
        raise DataError(f"{path}: no such file") from None
    except (zipfile.BadZipFile, OSError) as exc:
        raise DataError(f"{path}: not a detcal log or truncated ({exc})") from None
    with zf:
        names = set(zf.namelist())

        def load(key: str) -> np.ndarray:
            member = f"{key}.npy"
            if member not in names:
                raise DataError(f"{path}: member {member} is missing")
            try:
                raw = zf.read(member)
                return np.lib.format.read_array(io.BytesIO(raw), allow_pickle=False)
            except (zipfile.BadZipFile, zlib.error, EOFError, ValueError, OSError) as exc:
                raise DataError(f"{path}: member {member} is truncated or corrupt ({exc})") from None

        if "meta.json" not in names:
            raise DataError(f"{path}: member meta.json is missing; not a detcal log")
        try:
            meta = json.loads(zf.read("meta.json"))
        except (zipfile.BadZipFile, zlib.error, ValueError) as exc:
            raise DataError(f"{path}: meta.json is unreadable ({exc})") from None
        if meta.get("format") != FORMAT:
            raise DataError(f"{path}: meta.json format is {meta.get('format')!r}, expected {FORMAT!r}")
        if meta.get("version") != VERSION:
            raise DataError(
                f"{path}: log format version {meta.get('version')!r} is not supported "
                f"(this detcal reads version {VERSION})"
            )
        models = {}
        for key, model in (("sensor", SensorModel), ("vehicle", Vehicle)):
            try:
                models[key] = None if meta.get(key) is None else model.model_validate(meta[key])
            except ValidationError as exc:
                err = exc.errors()[0]
                loc = ".".join(str(p) for p in err["loc"])
                raise DataError(f"{path}: meta.json {key}.{loc}: {err['msg']}") from None
        streams = meta.get("streams", {})
        try:
            return _build(meta, models["sensor"], models["vehicle"], streams, load)
        except DataError as exc:
            if str(exc).startswith(str(path)):
                raise
            raise DataError(f"{path}: {exc}") from None


def _build(meta: dict, sensor: SensorModel | None, vehicle: Vehicle | None, streams: dict, load) -> SensorLog:
    scans = odometry = landmarks = detections = clouds = planes = None
    if "scan" in streams:
        s = streams["scan"]
        scans = ScanBatch(
            load("scan/stamp"),
            load("scan/ranges"),
            load("scan/intensities") if s.get("intensities") else None,
            load("scan/odom_pose") if s.get("odom_pose") else None,
        )
    if "odometry" in streams:
        odometry = Odometry(streams["odometry"]["kind"], load("odometry/stamp"), load("odometry/values"))
    reference = {
        k: ReferencePoses(k, load(f"reference/{k}/stamp"), load(f"reference/{k}/poses"))
        for k in streams.get("reference", {})
    }
    if "landmarks" in streams:
        landmarks = Landmarks(load("landmarks/ids"), load("landmarks/xy"), load("landmarks/radius"), load("landmarks/sigma"))
    if "detections" in streams:
        d = streams["detections"]
        detections = Detections(
            load("detections/frame_stamp"),
            load("detections/frame"),
            load("detections/range"),
            load("detections/bearing"),
            {name: load(f"detections/descriptors/{name}") for name in d.get("descriptors", [])},
        )
    if "clouds" in streams:
        clouds = PointClouds(load("clouds/stamp"), load("clouds/offsets"), load("clouds/points"))
    if "planes" in streams:
        planes = PlaneLandmarks(
            load("planes/ids"), load("planes/normal"), load("planes/offset"), load("planes/vertices"), load("planes/offsets"), load("planes/kind")
        )
    return SensorLog(
        name=str(meta.get("name", "")),
        sensor=sensor,
        vehicle=vehicle,
        clouds=clouds,
        scans=scans,
        odometry=odometry,
        reference=reference,
        landmarks=landmarks,
        detections=detections,
        source=meta.get("source", {}),
        planes=planes,
    )
