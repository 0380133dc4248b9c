"""ROS 1 (``.bag``) and ROS 2 (folder, sqlite3 or mcap) bags through ``rosbags``.

Reading a foreign bag: ``sensor_msgs/LaserScan`` on the scan topic becomes the
scan stream (REP 117: NaN, +-inf and readings outside [range_min, range_max]
are no returns, stored as NaN; a negative reading is an error),
``nav_msgs/Odometry`` on the odometry topic becomes ``pose`` odometry (x, y,
yaw) and an optional truth topic (``nav_msgs/Odometry`` or
``geometry_msgs/PoseStamped``) becomes the ``ground_truth`` reference. With one
topic of a type the topic is picked automatically; with several, name it.
Stamps are the message headers'.

Writing (ROS 2, :func:`write_ros2`): standard topics for ROS tools --
``/scan`` (LaserScan), ``/odom`` (nav_msgs/Odometry: pose or velocity odometry
as it is, increments as their running pose from the origin) and ``/ground_truth``
(nav_msgs/Odometry, when the log has ground-truth poses) -- plus exact float64 copies under ``/detcal/...``
(``std_msgs/Float64MultiArray``) and the log's metadata as the bag's
``custom_data["detcal"]``, so that native -> ROS 2 -> native is lossless:
LaserScan angles are float32 and a quaternion does not give back a yaw bit
for bit, so the exact values travel beside them.
"""

from __future__ import annotations

import dataclasses
import errno
import json
import sqlite3
from pathlib import Path

import numpy as np
import yaml
from rosbags.highlevel import AnyReader, AnyReaderError
from rosbags.rosbag2 import Writer
from rosbags.typesys import Stores, get_typestore

from calib.io.atomic import atomic_output
from calib.io.common import DEFAULT_MAX_BACKSTEP, file_digest, time_order
from detectors.geometry import increment_poses
from detectors.sensor_log import (
    BeamGeometry,
    Detections,
    Landmarks,
    Odometry,
    ReferencePoses,
    ScanBatch,
    SensorLog,
    SensorModel,
    Vehicle,
    wrap_angle,
)
from profiles.errors import DataError, UsageError

SCAN_TYPE = "sensor_msgs/msg/LaserScan"
ODOM_TYPE = "nav_msgs/msg/Odometry"
POSE_TYPES = (ODOM_TYPE, "geometry_msgs/msg/PoseStamped")
ARRAY_TYPE = "std_msgs/msg/Float64MultiArray"
CUSTOM_KEY = "detcal"
#: where the writer puts the log's ground-truth poses for ROS tools (nav_msgs/Odometry, frame ``map``)
TRUTH_TOPIC = "/ground_truth"
META_VERSION = 1


def looks_like_bag(path: Path) -> bool:
    return path.suffix in (".bag", ".mcap", ".db3") or (path.is_dir() and (path / "metadata.yaml").is_file())


def _yaw(qz: np.ndarray, qw: np.ndarray, qx: np.ndarray, qy: np.ndarray) -> np.ndarray:
    return wrap_angle(np.arctan2(2.0 * (qw * qz + qx * qy), 1.0 - 2.0 * (qy * qy + qz * qz)))


def _stamp(msg) -> int:
    return int(msg.header.stamp.sec) * 1_000_000_000 + int(msg.header.stamp.nanosec)


def _pick(conns: dict[str, str], want: tuple[str, ...], topic: str | None, what: str, path: Path, required: bool) -> str | None:
    if topic is not None:
        if topic not in conns:
            have = ", ".join(f"{t} ({m})" for t, m in sorted(conns.items())) or "none"
            raise UsageError(f"{path}: unknown {what} topic {topic!r}; the bag has: {have}")
        if conns[topic] not in want:
            raise UsageError(f"{path}: topic {topic!r} is {conns[topic]}, expected {' or '.join(want)} for the {what}")
        return topic
    cands = sorted(t for t, m in conns.items() if m in want and not t.startswith("/detcal/"))
    if len(cands) > 1:
        raise UsageError(f"{path}: several {what} topics ({', '.join(cands)}); choose one with --{what}-topic")
    if not cands and required:
        raise UsageError(f"{path}: no {' or '.join(want)} topic for the {what}")
    return cands[0] if cands else None


def read_rosbag(
    path: str | Path,
    *,
    scan_topic: str | None = None,
    odom_topic: str | None = None,
    truth_topic: str | None = None,
    max_backstep: float = DEFAULT_MAX_BACKSTEP,
) -> SensorLog:
    path = Path(path)
    if not path.exists():
        raise UsageError(f"{path}: no such file or folder")
    default = get_typestore(Stores.ROS1_NOETIC if path.suffix == ".bag" else Stores.ROS2_HUMBLE)
    try:
        reader = AnyReader([path], default_typestore=default)
        reader.open()
    except (AnyReaderError, Exception) as exc:  # rosbags raises several unrelated types for damaged bags
        raise DataError(f"{path}: not a readable ROS bag ({exc})") from None
    reader.detcal_found = {}
    try:
        custom = _custom_data(path)
        conns = {c.topic: c.msgtype for c in reader.connections}
        if CUSTOM_KEY in custom and all(t is None for t in (scan_topic, odom_topic, truth_topic)):
            log = _read_detcal(reader, json.loads(custom[CUSTOM_KEY]), path)
        else:
            log = _read_foreign(reader, conns, path, scan_topic, odom_topic, truth_topic, max_backstep)
        missing = _missing(reader)
        if missing:  # said by the command (detcal.cli.common.warn_missing) and kept with the log
            for topic, m in missing.items():
                stream = log.scans if "scan" in topic else log.odometry if "odom" in topic else None
                if stream is not None:
                    m.update(_gap(stream.stamp))
            log = dataclasses.replace(log, source={**log.source, "missing": missing})
        return log
    except (DataError, UsageError):
        raise
    except Exception as exc:  # a damaged message deep in rosbags' deserialiser
        raise DataError(f"{path}: damaged bag ({type(exc).__name__}: {exc})") from None
    finally:
        reader.close()


def _custom_data(path: Path) -> dict:
    """``custom_data`` of a ROS 2 bag's metadata.yaml (empty for ROS 1 or when absent)."""
    meta = path / "metadata.yaml" if path.is_dir() else path.parent / "metadata.yaml"
    if not meta.is_file():
        return {}
    try:
        info = yaml.safe_load(meta.read_text()) or {}
    except yaml.YAMLError:
        return {}
    return (info.get("rosbag2_bagfile_information") or {}).get("custom_data") or {}


def _raw(reader: AnyReader, topic: str):
    """(connection, bag time, raw bytes) of every message on ``topic``, counted in ``reader.detcal_found`` (see
    :func:`_missing`)."""
    conns = [c for c in reader.connections if c.topic == topic]
    found = reader.detcal_found
    found.setdefault(topic, 0)
    for conn, t, raw in reader.messages(connections=conns):
        found[topic] = found.get(topic, 0) + 1
        yield conn, t, raw


def _messages(reader: AnyReader, topic: str):
    for conn, _t, raw in _raw(reader, topic):
        yield reader.deserialize(raw, conn.msgtype)


def _missing(reader: AnyReader) -> dict[str, dict[str, int]]:
    """Topics read that hold fewer messages than the bag's index declares (a message deleted from the database, a
    damaged chunk): ``{topic: {"declared", "found"}}``; empty for a whole bag."""
    declared: dict[str, int] = {}
    for c in reader.connections:
        declared[c.topic] = declared.get(c.topic, 0) + int(c.msgcount or 0)
    return {
        t: {"declared": declared[t], "found": n} for t, n in sorted(reader.detcal_found.items()) if declared.get(t, 0) > n
    }


def _gap(stamps: np.ndarray) -> dict[str, float]:
    """The longest step between successive stamps [s], where it starts (s after the first) and the median step."""
    st = np.sort(np.asarray(stamps, dtype=np.int64))
    if st.size < 3:
        return {}
    d = np.diff(st)
    k = int(np.argmax(d))
    return {"longest_s": float(d[k]) / 1e9, "after_s": float(st[k] - st[0]) / 1e9, "median_s": float(np.median(d)) / 1e9}


def _read_foreign(reader, conns, path, scan_topic, odom_topic, truth_topic, max_backstep) -> SensorLog:
    scan_t = _pick(conns, (SCAN_TYPE,), scan_topic, "scan", path, required=False)
    truth_t = _pick(conns, POSE_TYPES, truth_topic, "truth", path, required=False) if truth_topic else None
    # the named truth topic is not an odometry candidate (a bag often carries both as nav_msgs/Odometry)
    odom_t = _pick({t: m for t, m in conns.items() if t != truth_t}, (ODOM_TYPE,), odom_topic, "odom", path, required=False)
    if scan_t is None and odom_t is None:
        have = ", ".join(f"{t} ({m})" for t, m in sorted(conns.items())) or "none"
        raise UsageError(f"{path}: no LaserScan or Odometry topic; the bag has: {have}")
    reordered: dict[str, int] = {}
    scans = sensor = None
    if scan_t is not None:
        stamps, rows, inten, geoms, limits = [], [], [], [], None
        for k, msg in enumerate(_messages(reader, scan_t)):
            g = (len(msg.ranges), float(msg.angle_min), float(msg.angle_increment))
            lim = (float(msg.range_min), float(msg.range_max))
            if not (np.isfinite(g[1:]).all() and np.isfinite(lim[0])) or g[0] == 0:
                raise DataError(f"{path}: {scan_t} message {k}: no beams, or a beam angle or range_min that is not finite")
            limits = lim if limits is None else limits
            r = np.asarray(msg.ranges, dtype=np.float32)
            neg = np.flatnonzero(r < 0)
            if neg.size:
                raise DataError(f"{path}: {scan_t} message {k} beam {int(neg[0])}: negative range {r[neg[0]]}")
            r = np.where(np.isfinite(r) & (r >= lim[0]) & (r <= lim[1]), r, np.float32(np.nan))
            rows.append(r)
            i = np.asarray(msg.intensities, dtype=np.float32)
            inten.append(i if i.size == r.size else None)
            geoms.append(g)
            stamps.append(_stamp(msg))
        if not rows:
            raise DataError(f"{path}: topic {scan_t} has no messages")
        perm, reordered["scan"] = time_order(np.array(stamps), np.arange(len(stamps)), path, f"{scan_t} message", max_backstep)
        has_i = all(i is not None for i in inten)
        layouts, which = np.unique(np.array(geoms, dtype=[("n", "i8"), ("a", "f8"), ("d", "f8")]), return_inverse=True)
        width = int(layouts["n"].max())
        ranges = np.full((len(rows), width), np.nan, dtype=np.float32)
        intens = np.full((len(rows), width), np.nan, dtype=np.float32) if has_i else None
        for k, r in enumerate(rows):
            ranges[k, : r.size] = r
            if intens is not None:
                intens[k, : r.size] = inten[k]
        rmax = limits[1] if np.isfinite(limits[1]) and limits[1] > 0 else None
        common = {"kind": "laser2d", "range_min": max(limits[0], 0.0), "range_max": rmax}
        if layouts.size == 1:
            sensor = SensorModel(n_beams=width, angle_min=float(layouts[0]["a"]), angle_increment=float(layouts[0]["d"]), **common)
            geometry = None
        else:
            sensor = SensorModel(
                n_beams=width,
                geometries=tuple(BeamGeometry(n_beams=int(g["n"]), angle_min=float(g["a"]), angle_increment=float(g["d"])) for g in layouts),
                **common,
            )
            geometry = which.reshape(-1)[perm]
        scans = ScanBatch(np.array(stamps, dtype=np.int64)[perm], ranges[perm], intens[perm] if intens is not None else None, None, geometry)
    odometry = None
    if odom_t is not None:
        stamps, poses = _poses(reader, odom_t)
        perm, reordered["odometry"] = time_order(stamps, np.arange(stamps.size), path, f"{odom_t} message", max_backstep)
        odometry = Odometry("pose", stamps[perm], poses[perm])
    reference = {}
    if truth_t is not None:
        stamps, poses = _poses(reader, truth_t)
        perm, reordered["reference:ground_truth"] = time_order(stamps, np.arange(stamps.size), path, f"{truth_t} message", max_backstep)
        reference["ground_truth"] = ReferencePoses("ground_truth", stamps[perm], poses[perm])
    return SensorLog(
        name=path.stem,
        sensor=sensor,
        scans=scans,
        odometry=odometry,
        reference=reference,
        source={
            "reader": "rosbag",
            "file": path.name,
            "sha256": file_digest(path),
            "topics": {"scan": scan_t, "odometry": odom_t, "truth": truth_t},
            "reordered": reordered,
        },
    )


def _poses(reader: AnyReader, topic: str) -> tuple[np.ndarray, np.ndarray]:
    stamps, rows = [], []
    for msg in _messages(reader, topic):
        pose = msg.pose.pose if hasattr(msg.pose, "pose") else msg.pose
        p, q = pose.position, pose.orientation
        rows.append((p.x, p.y, q.z, q.w, q.x, q.y))
        stamps.append(_stamp(msg))
    a = np.array(rows, dtype=np.float64).reshape(-1, 6)
    poses = np.column_stack([a[:, 0], a[:, 1], _yaw(a[:, 2], a[:, 3], a[:, 4], a[:, 5])])
    return np.array(stamps, dtype=np.int64), poses


# --------------------------------------------------------------------------- detcal-written bags


def _topics(log: SensorLog) -> dict[str, str]:
    t = {}
    if log.scans is not None:
        t["/scan"] = SCAN_TYPE
        t["/detcal/scan/ranges"] = ARRAY_TYPE
        if log.scans.intensities is not None:
            t["/detcal/scan/intensities"] = ARRAY_TYPE
        if log.scans.odom_pose is not None:
            t["/detcal/scan/odom_pose"] = ARRAY_TYPE
        if log.scans.geometry is not None:
            t["/detcal/scan/geometry"] = ARRAY_TYPE
    if log.odometry is not None:
        t["/detcal/odometry"] = ARRAY_TYPE
        if log.odometry.kind in ("pose", "velocity", "increment"):  # increments go out as their running pose
            t["/odom"] = ODOM_TYPE
    for k in log.reference:
        t[f"/detcal/reference/{k}"] = ARRAY_TYPE
    if _truth_poses(log) is not None:
        t[TRUTH_TOPIC] = ODOM_TYPE
    if log.detections is not None:
        t["/detcal/detections"] = ARRAY_TYPE
    return t


def write_ros2(log: SensorLog, path: str | Path, *, overwrite: bool = False) -> Path:
    """Write ``log`` as a ROS 2 bag folder (sqlite3, format version 9), atomically."""
    path = Path(path)
    if log.clouds is not None:
        raise UsageError(f"{path}: writing point clouds to a ROS 2 bag is not supported; convert to .dlog instead")
    ts = get_typestore(Stores.ROS2_HUMBLE)
    T = ts.types
    det = log.detections
    meta = {
        "version": META_VERSION,
        "name": log.name,
        "sensor": None if log.sensor is None else log.sensor.model_dump(mode="json"),
        "vehicle": None if log.vehicle is None else log.vehicle.model_dump(mode="json"),
        "source": dict(log.source),
        "odometry_kind": None if log.odometry is None else log.odometry.kind,
        "references": sorted(log.reference),
        # the point of the vehicle each reference locates, where it is not the vehicle's own (other bags keep their bytes)
        **({"reference_points": pts} if (pts := {k: list(r.point) for k, r in sorted(log.reference.items()) if not r.on_vehicle_point}) else {}),
        "scan": None if log.scans is None else _scan_meta(log.scans),
        "detections": None
        if det is None
        else {"n_frames": det.n_frames, "descriptors": {k: str(v.dtype) for k, v in sorted(det.descriptors.items())}},
        "landmarks": None
        if log.landmarks is None
        else {k: getattr(log.landmarks, k).tolist() for k in ("ids", "xy", "radius", "sigma")},
    }

    def header(stamp: int, frame: str):
        return T["std_msgs/msg/Header"](
            stamp=T["builtin_interfaces/msg/Time"](sec=stamp // 1_000_000_000, nanosec=stamp % 1_000_000_000), frame_id=frame
        )

    def array(values: np.ndarray, labels: tuple[str, ...]):
        values = np.ascontiguousarray(values, dtype=np.float64)
        shape = values.shape if values.ndim == 2 else (1, values.size)
        dims = [
            T["std_msgs/msg/MultiArrayDimension"](label=labels[0], size=shape[0], stride=shape[0] * shape[1]),
            T["std_msgs/msg/MultiArrayDimension"](label=labels[1], size=shape[1], stride=shape[1]),
        ]
        return T[ARRAY_TYPE](layout=T["std_msgs/msg/MultiArrayLayout"](dim=dims, data_offset=0), data=values.ravel())

    with atomic_output(path, overwrite=overwrite, directory=True) as tmp:
        try:
            writer = Writer(tmp, version=9)
            writer.set_custom_data(CUSTOM_KEY, json.dumps(meta, sort_keys=True))
            with writer:
                conn = {topic: writer.add_connection(topic, mt, typestore=ts) for topic, mt in _topics(log).items()}

                def put(topic: str, stamp: int, msg) -> None:
                    writer.write(conn[topic], stamp, ts.serialize_cdr(msg, msg.__msgtype__))

                det_off = det.frame_slices() if det is not None else None
                odom = log.odometry
                odom_poses = increment_poses(odom.values) if odom is not None and odom.kind == "increment" else None
                truth = _truth_poses(log)
                sensor = log.sensor
                layouts = sensor.layouts() if sensor is not None else ()
                for ev in log.events():
                    i = ev.index
                    if ev.stream == "scan":
                        s = log.scans
                        assert sensor is not None and s is not None
                        ranges = s.ranges[i]
                        g = layouts[0] if s.geometry is None else layouts[int(s.geometry[i])]  # each scan with its own beam layout
                        put(
                            "/scan",
                            ev.stamp,
                            T[SCAN_TYPE](
                                header=header(ev.stamp, "laser"),
                                angle_min=float(g.angle_min),
                                angle_max=float(g.angle_min + g.angle_increment * (g.n_beams - 1)),
                                angle_increment=float(g.angle_increment),
                                time_increment=0.0,
                                scan_time=0.0,
                                range_min=float(sensor.range_min),
                                range_max=float(sensor.range_max or np.inf),
                                ranges=ranges[: g.n_beams],
                                intensities=s.intensities[i, : g.n_beams] if s.intensities is not None else np.zeros(0, np.float32),
                            ),
                        )
                        put("/detcal/scan/ranges", ev.stamp, array(ranges.astype(np.float64), ("scan", "beam")))
                        if s.geometry is not None:
                            put("/detcal/scan/geometry", ev.stamp, array(np.array([float(s.geometry[i])]), ("row", "layout")))
                        if s.intensities is not None:
                            put("/detcal/scan/intensities", ev.stamp, array(s.intensities[i].astype(np.float64), ("scan", "beam")))
                        if s.odom_pose is not None:
                            put("/detcal/scan/odom_pose", ev.stamp, array(s.odom_pose[i], ("row", "x_y_theta")))
                    elif ev.stream == "odometry":
                        put("/detcal/odometry", ev.stamp, array(odom.values[i], ("row", "_".join(odom.columns))))
                        if "/odom" in conn:  # standard odometry for ROS tools (see _topics); increments as their poses
                            vals, kind = (odom.values, odom.kind) if odom_poses is None else (odom_poses, "pose")
                            put("/odom", ev.stamp, _odom_msg(T, header(ev.stamp, "odom"), vals, kind, i))
                    elif ev.stream.startswith("reference:"):
                        k = ev.stream.split(":", 1)[1]
                        put(f"/detcal/reference/{k}", ev.stamp, array(log.reference[k].poses[i], ("row", "x_y_theta")))
                        if k == "ground_truth" and truth is not None:
                            put(TRUTH_TOPIC, ev.stamp, _odom_msg(T, header(ev.stamp, "map"), truth, "pose", i))
                    elif ev.stream == "detections":
                        a, b = int(det_off[i]), int(det_off[i + 1])
                        cols = [det.range[a:b], det.bearing[a:b]] + [det.descriptors[k][a:b].astype(np.float64) for k in sorted(det.descriptors)]
                        put("/detcal/detections", ev.stamp, array(np.column_stack(cols).reshape(b - a, len(cols)), ("detection", "field")))
        except sqlite3.Error as exc:  # the bag's database refused a write: a full disk, a quota, a lost mount
            full = "full" in str(exc).lower()
            raise OSError(errno.ENOSPC if full else errno.EIO, f"the bag's sqlite3 database: {exc}") from None
    return path


def _scan_meta(s: ScanBatch) -> dict:
    meta = {"intensities": s.intensities is not None, "odom_pose": s.odom_pose is not None}
    if s.geometry is not None:  # only for a laser of several beam layouts: other bags keep their metadata
        meta["geometry"] = True
    return meta


def _truth_poses(log: SensorLog) -> np.ndarray | None:
    """The ground-truth poses (N, 3) written on the standard truth topic, when the log has them with a heading."""
    ref = log.reference.get("ground_truth")
    if ref is None or not np.isfinite(ref.poses).all():
        return None
    return ref.poses


def _odom_msg(T, hdr, values: np.ndarray, kind: str, i: int):
    pose = T["geometry_msgs/msg/Pose"](
        position=T["geometry_msgs/msg/Point"](x=0.0, y=0.0, z=0.0),
        orientation=T["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=0.0, w=1.0),
    )
    twist = T["geometry_msgs/msg/Twist"](
        linear=T["geometry_msgs/msg/Vector3"](x=0.0, y=0.0, z=0.0), angular=T["geometry_msgs/msg/Vector3"](x=0.0, y=0.0, z=0.0)
    )
    if kind == "pose":
        x, y, th = (float(v) for v in values[i])
        pose.position.x, pose.position.y = x, y
        pose.orientation.z, pose.orientation.w = float(np.sin(th / 2)), float(np.cos(th / 2))
    else:
        twist.linear.x, twist.angular.z = float(values[i, 0]), float(values[i, 1])
    cov = np.zeros(36)
    return T[ODOM_TYPE](
        header=hdr,
        child_frame_id="base_link",
        pose=T["geometry_msgs/msg/PoseWithCovariance"](pose=pose, covariance=cov),
        twist=T["geometry_msgs/msg/TwistWithCovariance"](twist=twist, covariance=cov),
    )


def _read_detcal(reader: AnyReader, meta: dict, path: Path) -> SensorLog:
    if meta.get("version") != META_VERSION:
        raise DataError(f"{path}: detcal bag metadata version {meta.get('version')!r} is not supported (expected {META_VERSION})")

    def table(topic: str) -> tuple[np.ndarray, list[np.ndarray]]:
        stamps, rows = [], []
        for conn, t, raw in _raw(reader, topic):
            msg = reader.deserialize(raw, conn.msgtype)
            dims = msg.layout.dim
            rows.append(np.asarray(msg.data, dtype=np.float64).reshape(dims[0].size, dims[1].size))
            stamps.append(t)
        return np.array(stamps, dtype=np.int64), rows

    sensor = None if meta["sensor"] is None else SensorModel.model_validate(meta["sensor"])
    vehicle = None if meta.get("vehicle") is None else Vehicle.model_validate(meta["vehicle"])
    scans = odometry = detections = landmarks = None
    if meta["scan"] is not None:
        st, rows = table("/detcal/scan/ranges")
        inten = np.concatenate(table("/detcal/scan/intensities")[1]) if meta["scan"]["intensities"] else None
        odom = np.concatenate(table("/detcal/scan/odom_pose")[1]) if meta["scan"]["odom_pose"] else None
        geom = np.concatenate(table("/detcal/scan/geometry")[1]).ravel().astype(np.int32) if meta["scan"].get("geometry") else None
        scans = ScanBatch(st, np.concatenate(rows).astype(np.float32), None if inten is None else inten.astype(np.float32), odom, geom)
    if meta["odometry_kind"] is not None:
        st, rows = table("/detcal/odometry")
        odometry = Odometry(meta["odometry_kind"], st, np.concatenate(rows))
    reference = {}
    for k in meta["references"]:
        st, rows = table(f"/detcal/reference/{k}")
        point = (meta.get("reference_points") or {}).get(k, (0.0, 0.0))
        reference[k] = ReferencePoses(k, st, np.concatenate(rows), point=tuple(point))
    if meta["detections"] is not None:
        st, rows = table("/detcal/detections")
        names = list(meta["detections"]["descriptors"])
        counts = np.array([r.shape[0] for r in rows], dtype=np.int64)
        allrows = np.concatenate(rows) if rows else np.zeros((0, 2 + len(names)))
        allrows = allrows.reshape(-1, 2 + len(names))
        desc = {n: allrows[:, 2 + j].astype(meta["detections"]["descriptors"][n]) for j, n in enumerate(names)}
        detections = Detections(st, np.repeat(np.arange(st.size), counts), allrows[:, 0], allrows[:, 1], desc)
    if meta["landmarks"] is not None:
        lm = meta["landmarks"]
        landmarks = Landmarks(
            np.array(lm["ids"], dtype=np.int64),
            np.array(lm["xy"], dtype=np.float64).reshape(-1, 2),
            np.array(lm["radius"], dtype=np.float64),
            np.array(lm["sigma"], dtype=np.float64).reshape(-1, 2),
        )
    return SensorLog(
        name=meta["name"],
        sensor=sensor,
        vehicle=vehicle,
        scans=scans,
        odometry=odometry,
        reference=reference,
        landmarks=landmarks,
        detections=detections,
        source=meta["source"],
    )
