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

import hashlib
import io
import json
import zipfile
import zlib
from pathlib import Path
from typing import Annotated

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, ValidationError

from calib.io.atomic import atomic_output
from detectors.sensor_log import (
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
from profiles.errors import DataError, UsageError

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
        if s.geometry is not None:  # written only for a laser of several beam layouts: other logs keep their bytes
            streams["scan"]["geometry"] = True
            arrays["scan/geometry"] = s.geometry
    if log.odometry is not None:
        streams["odometry"] = {"n": len(log.odometry), "kind": log.odometry.kind}
        if log.odometry.sigma is not None:  # written only where the source states it: other logs keep their bytes
            streams["odometry"]["sigma"] = list(log.odometry.sigma)
        arrays["odometry/stamp"] = log.odometry.stamp
        arrays["odometry/values"] = log.odometry.values
    if log.reference:
        # the point is written only where it is not the vehicle's own (other logs keep their bytes)
        streams["reference"] = {
            k: {"n": len(r), **({} if r.on_vehicle_point else {"point": list(r.point)})} for k, r in sorted(log.reference.items())
        }
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


class _Meta(BaseModel):
    model_config = ConfigDict(extra="forbid", strict=True)


class _ScanMeta(_Meta):
    n: int = Field(ge=0)
    intensities: bool = False
    odom_pose: bool = False
    geometry: bool = False


class _OdometryMeta(_Meta):
    n: int = Field(ge=0)
    kind: str
    sigma: list[Annotated[float, Field(ge=0.0, allow_inf_nan=False)]] | None = None


class _CountMeta(_Meta):
    n: int = Field(ge=0)


class _ReferenceMeta(_CountMeta):
    point: Annotated[list[Annotated[float, Field(allow_inf_nan=False)]], Field(min_length=2, max_length=2)] = [0.0, 0.0]


class _DetectionsMeta(_Meta):
    n: int = Field(ge=0)
    n_frames: int = Field(ge=0)
    descriptors: list[str] = []


class _CloudsMeta(_Meta):
    n: int = Field(ge=0)
    points: int = Field(ge=0)


class _Streams(_Meta):
    """What ``meta.json`` says about the streams: which are present and how long they are."""

    scan: _ScanMeta | None = None
    odometry: _OdometryMeta | None = None
    reference: dict[str, _ReferenceMeta] | None = None
    landmarks: _CountMeta | None = None
    detections: _DetectionsMeta | None = None
    clouds: _CloudsMeta | None = None
    planes: _CountMeta | None = None


#: dtype of every array member, exactly as the writer writes it (descriptors: any number type).
DTYPES = {
    "scan/stamp": "int64", "scan/ranges": "float32", "scan/intensities": "float32", "scan/odom_pose": "float64", "scan/geometry": "int32",
    "odometry/stamp": "int64", "odometry/values": "float64",
    "reference/stamp": "int64", "reference/poses": "float64",
    "landmarks/ids": "int64", "landmarks/xy": "float64", "landmarks/radius": "float64", "landmarks/sigma": "float64",
    "detections/frame_stamp": "int64", "detections/frame": "int64", "detections/range": "float64", "detections/bearing": "float64",
    "clouds/stamp": "int64", "clouds/offsets": "int64", "clouds/points": "float32",
    "planes/ids": "int64", "planes/normal": "float64", "planes/offset": "float64", "planes/vertices": "float64",
    "planes/offsets": "int64", "planes/kind": "str",
}  # fmt: skip


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
    with atomic_output(path, overwrite=overwrite, owned=is_detcal_log) as tmp:
        with zipfile.ZipFile(tmp, "w") as zf:
            _member(zf, "meta.json", json.dumps(meta, sort_keys=True, indent=1).encode())
            for key, arr in arrays.items():
                buf = io.BytesIO()
                np.lib.format.write_array(buf, np.ascontiguousarray(arr), allow_pickle=False)
                _member(zf, f"{key}.npy", buf.getvalue())
    return path


def is_native(path: Path) -> bool:
    return path.suffix == SUFFIX or (path.is_file() and zipfile.is_zipfile(path) and _has_meta(path))


def is_detcal_log(path: Path) -> bool:
    """True for a file detcal wrote as a native log (a zip whose meta.json names the format); ``--force`` may replace it."""
    try:
        with zipfile.ZipFile(path) as zf:
            meta = json.loads(zf.read("meta.json"))
    except (OSError, KeyError, ValueError, zipfile.BadZipFile, zlib.error, RuntimeError, NotImplementedError):
        return False  # unreadable (RuntimeError: encrypted; NotImplementedError: an unknown compression)
    return isinstance(meta, dict) and meta.get("format") == FORMAT


is_detcal_log.kind = "native log"  # named when --force is refused (profiles.atomic.check_replaceable)


def content_digest(path: Path) -> str:
    """sha256 of a native log's content: every member's name and uncompressed bytes, in the file's order.

    Unlike the file's own hash it does not depend on the zlib that compressed
    it, so the same log has the same digest on every machine (the embedded
    default log is simulated and written anew on each one).
    """
    h = hashlib.sha256()
    try:
        with zipfile.ZipFile(path) as zf:
            _check_members(zf, path)
            for info in zf.infolist():
                h.update(info.filename.encode() + b"\0")
                with zf.open(info) as fh:
                    for chunk in iter(lambda fh=fh: fh.read(1 << 20), b""):
                        h.update(chunk)
    except (OSError, zipfile.BadZipFile, zlib.error, EOFError) as exc:
        raise DataError(f"{path}: not a detcal log or truncated ({exc})") from None
    return h.hexdigest()


def _has_meta(path: Path) -> bool:
    try:
        with zipfile.ZipFile(path) as zf:
            return "meta.json" in zf.namelist()
    except (OSError, zipfile.BadZipFile):
        return False


#: Zip compression methods detcal reads: stored and deflate (the writer uses deflate).
_METHODS = {zipfile.ZIP_STORED: "stored", zipfile.ZIP_DEFLATED: "deflate"}


def _check_members(zf: zipfile.ZipFile, path: Path) -> None:
    """Refuse members that cannot be read without a password or with a compression detcal does not read, before
    any is opened (zipfile raises RuntimeError or NotImplementedError for them, deep inside a read)."""
    for info in zf.infolist():
        if info.flag_bits & 0x1:
            raise DataError(f"{path}: member {info.filename} is encrypted (zip flag bit 0); a detcal log is never encrypted")
        if info.compress_type not in _METHODS:
            raise DataError(
                f"{path}: member {info.filename} uses zip compression method {info.compress_type}; "
                f"a detcal log uses {' or '.join(_METHODS.values())} (damaged, or written by another tool)"
            )


def _where(exc: ValidationError) -> str:
    """``.field.path: what was wrong`` of the first error (no path for a check of the whole section)."""
    e = exc.errors()[0]
    loc = "".join(f".{p}" for p in e["loc"])
    return f"{loc}: {'unknown key' if e['type'] == 'extra_forbidden' else e['msg']}"


def read_native(path: str | Path) -> SensorLog:
    """Read a ``.dlog`` file; every defect is a :class:`DataError` naming the file and member.

    Checked before any array is built: meta.json is an object of the known
    format and version, its ``streams`` section is complete, every member has
    the dtype the writer writes and a header that fits the member's size, and
    the lengths agree with the counts in meta.json.
    """
    path = Path(path)
    try:
        zf = zipfile.ZipFile(path)
    except FileNotFoundError:
        raise UsageError(f"{path}: no such file") from None
    except IsADirectoryError:
        raise UsageError(f"{path}: is a folder, expected a .dlog file") from None
    except (zipfile.BadZipFile, OSError, ValueError, EOFError) as exc:
        raise DataError(f"{path}: not a detcal log or truncated ({exc})") from None
    with zf:
        names = set(zf.namelist())
        _check_members(zf, path)

        def load(key: str, dtype: str | None = None) -> np.ndarray:
            member = f"{key}.npy"
            if member not in names:
                raise DataError(f"{path}: member {member} is missing")
            want = dtype or DTYPES.get(key) or DTYPES.get("reference/" + key.rsplit("/", 1)[-1])
            nbytes = zf.getinfo(member).file_size  # the claimed size once the header is read
            try:
                info = zf.getinfo(member)
                with zf.open(member) as fh:
                    version = np.lib.format.read_magic(fh)
                    if version not in ((1, 0), (2, 0)):
                        raise DataError(f"{path}: member {member} is an .npy file of version {version}, expected 1.0 or 2.0")
                    reader = np.lib.format.read_array_header_1_0 if version == (1, 0) else np.lib.format.read_array_header_2_0
                    shape, _fortran, dt = reader(fh)
                    if dt.hasobject:
                        raise DataError(f"{path}: member {member} holds Python objects; refused")
                    nbytes = int(np.prod(shape, dtype=object)) * dt.itemsize
                    if nbytes > info.file_size:
                        raise DataError(f"{path}: member {member} claims shape {shape} ({nbytes} bytes) but holds {info.file_size} bytes")
                raw = zf.read(member)
                arr = np.lib.format.read_array(io.BytesIO(raw), allow_pickle=False)
            except DataError:
                raise
            except MemoryError:
                raise DataError(
                    f"{path}: member {member} needs {nbytes / 1e9:.3g} GB of memory, more than this machine can give; "
                    "the log is too large for memory (not damaged)"
                ) from None
            except Exception as exc:  # noqa: BLE001  (numpy's header parser raises SyntaxError, TokenError, ValueError...)
                raise DataError(f"{path}: member {member} is truncated or corrupt ({type(exc).__name__}: {exc})") from None
            if want == "number":
                if arr.dtype.kind not in "biuf":
                    raise DataError(f"{path}: member {member} has dtype {arr.dtype}, expected numbers")
            elif want == "str":
                if arr.dtype.kind != "U":
                    raise DataError(f"{path}: member {member} has dtype {arr.dtype}, expected text")
            elif want is not None and arr.dtype != np.dtype(want):
                raise DataError(f"{path}: member {member} has dtype {arr.dtype}, expected {want}")
            return arr

        if "meta.json" not in names:
            raise DataError(f"{path}: member meta.json is missing; not a detcal log")
        try:
            meta = json.loads(zf.read("meta.json"))
        except (zipfile.BadZipFile, zlib.error, ValueError, EOFError, OSError) as exc:
            raise DataError(f"{path}: meta.json is unreadable ({exc})") from None
        if not isinstance(meta, dict):
            raise DataError(f"{path}: meta.json is a {type(meta).__name__}, expected an object")
        if meta.get("format") != FORMAT:
            raise DataError(f"{path}: meta.json format is {meta.get('format')!r}, expected {FORMAT!r}")
        if meta.get("version") != VERSION:
            raise DataError(
                f"{path}: log format version {meta.get('version')!r} is not supported "
                f"(this detcal reads version {VERSION})"
            )
        unknown = sorted(set(meta) - {"format", "version", "name", "sensor", "vehicle", "source", "streams"})
        if unknown:
            raise DataError(f"{path}: meta.json {unknown[0]}: unknown key")
        if not isinstance(meta.get("name", ""), str) or not isinstance(meta.get("source", {}), dict):
            raise DataError(f"{path}: meta.json name must be a string and source an object")
        if "streams" not in meta:
            raise DataError(f"{path}: meta.json has no streams section")
        models = {}
        for key, model in (("sensor", SensorModel), ("vehicle", Vehicle)):
            try:
                models[key] = None if meta.get(key) is None else model.model_validate(meta[key])
            except ValidationError as exc:
                raise DataError(f"{path}: meta.json {key}{_where(exc)}") from None
        try:
            streams = _Streams.model_validate(meta["streams"])
        except ValidationError as exc:
            raise DataError(f"{path}: meta.json streams{_where(exc)}") from None
        try:
            log = _build(meta, models["sensor"], models["vehicle"], streams, load)
            _check_counts(log, streams)
            return log
        except DataError as exc:
            if str(exc).startswith(str(path)):
                raise
            raise DataError(f"{path}: {exc}") from None


def _check_counts(log: SensorLog, st: _Streams) -> None:
    """The lengths in meta.json must match the arrays (a forged or damaged meta.json is refused)."""
    got = {
        "scan.n": (st.scan, lambda m: len(log.scans)),
        "odometry.n": (st.odometry, lambda m: len(log.odometry)),
        "landmarks.n": (st.landmarks, lambda m: len(log.landmarks)),
        "detections.n": (st.detections, lambda m: len(log.detections)),
        "detections.n_frames": (st.detections, lambda m: log.detections.n_frames),
        "clouds.n": (st.clouds, lambda m: len(log.clouds)),
        "clouds.points": (st.clouds, lambda m: int(log.clouds.points.shape[0])),
        "planes.n": (st.planes, lambda m: len(log.planes)),
    }
    for key, (section, actual) in got.items():
        if section is None:
            continue
        declared = getattr(section, key.split(".")[1])
        if declared != actual(section):
            raise DataError(f"meta.json streams.{key} is {declared} but the arrays hold {actual(section)}")
    for k, m in (st.reference or {}).items():
        if m.n != len(log.reference[k]):
            raise DataError(f"meta.json streams.reference.{k}.n is {m.n} but the arrays hold {len(log.reference[k])}")


def _build(meta: dict, sensor: SensorModel | None, vehicle: Vehicle | None, streams: _Streams, load) -> SensorLog:
    scans = odometry = landmarks = detections = clouds = planes = None
    if streams.scan is not None:
        s = streams.scan
        scans = ScanBatch(
            load("scan/stamp"),
            load("scan/ranges"),
            load("scan/intensities") if s.intensities else None,
            load("scan/odom_pose") if s.odom_pose else None,
            load("scan/geometry") if s.geometry else None,
        )
    if streams.odometry is not None:
        odometry = Odometry(streams.odometry.kind, load("odometry/stamp"), load("odometry/values"), streams.odometry.sigma)
    reference = {
        k: ReferencePoses(k, load(f"reference/{k}/stamp"), load(f"reference/{k}/poses"), point=tuple(m.point)) for k, m in (streams.reference or {}).items()
    }
    if streams.landmarks is not None:
        landmarks = Landmarks(load("landmarks/ids"), load("landmarks/xy"), load("landmarks/radius"), load("landmarks/sigma"))
    if streams.detections is not None:
        detections = Detections(
            load("detections/frame_stamp"),
            load("detections/frame"),
            load("detections/range"),
            load("detections/bearing"),
            {name: load(f"detections/descriptors/{name}", "number") for name in streams.detections.descriptors},
        )
    if streams.clouds is not None:
        clouds = PointClouds(load("clouds/stamp"), load("clouds/offsets"), load("clouds/points"))
    if streams.planes is not None:
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
