"""The sensor-log model every part of detcal reads.

A :class:`SensorLog` is a bundle of optional, independently timed streams,
each a struct-of-arrays batch:

* :class:`ScanBatch`   -- 2D laser scans, ranges (N, B) float32, NaN = no return;
* :class:`Odometry`    -- pose, pose increments, (v, omega) or Ackermann inputs;
* :class:`ReferencePoses` -- ground truth or GPS, marked as which;
* :class:`Landmarks`   -- reference landmark positions (world frame);
* :class:`Detections`  -- detection-level records for logs without scans;
* :class:`PointClouds` -- 3D point clouds (Velodyne frames);
* :class:`PlaneLandmarks` -- reference planar landmarks with their outlines (world frame);
* :class:`SensorModel` -- beam geometry, range limits and noise, mounting pose;
* :class:`Vehicle`     -- geometry for motion models that need it (Ackermann).

Time is stored as int64 nanoseconds (``stamp``), the resolution of ROS time,
so that conversions between formats are exact; ``t`` gives float64 seconds.
Frames: the vehicle frame has x forward, y left; the sensor frame is the vehicle
frame moved by ``SensorModel.mount``; poses are (x, y, theta) in the world
frame, theta wrapped to (-pi, pi].

The one time-ordered iteration API is :meth:`SensorLog.events` (every record
of every stream, merged by time) and :meth:`SensorLog.frames` (one item per
scan or detection frame with the odometry rows since the previous frame).
"""

from __future__ import annotations

from collections.abc import Iterator, Mapping
from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np

from detectors.geometry import compose
from profiles.errors import DataError
from profiles.schema import BeamGeometry, Mount, SensorModel, Vehicle  # noqa: F401  (re-exported: part of the log model)

NS = 1_000_000_000

#: Odometry kinds and the meaning of their value columns.
ODOMETRY_KINDS: dict[str, tuple[str, ...]] = {
    # cumulative odometry-frame pose, as wheel odometry publishes it
    "pose": ("x", "y", "theta"),
    # motion since the previous row, expressed in the vehicle frame of that row
    "increment": ("dx", "dy", "dtheta"),
    # unicycle velocity commands, held until the next row
    "velocity": ("v", "omega"),
    # encoder speed [m/s] and front-wheel steering angle [rad] (Victoria Park)
    "ackermann": ("speed", "steer"),
}

REFERENCE_SOURCES = ("ground_truth", "gps")


def wrap_angle(a: np.ndarray | float) -> np.ndarray:
    """Wrap angles to (-pi, pi]."""
    w = np.mod(np.asarray(a, dtype=np.float64) + np.pi, 2.0 * np.pi) - np.pi
    return np.where(w == -np.pi, np.pi, w)


#: Largest |time| an int64 nanosecond stamp holds, in seconds (about 292 years).
MAX_SECONDS = 9.2e9


def seconds_to_stamp(t: np.ndarray | float, what: str = "time") -> np.ndarray:
    """Float seconds -> int64 nanoseconds (rounded to the nearest ns); a DataError beyond +-292 years or for NaN."""
    t = np.asarray(t, dtype=np.float64)
    bad = ~(np.abs(t) < MAX_SECONDS)
    if bad.any():
        i = int(np.flatnonzero(bad.ravel())[0])
        raise DataError(f"{what}[{i}]: {t.ravel()[i]!r} s is not a time (finite, within +-{MAX_SECONDS:.3g} s)")
    return np.rint(t * NS).astype(np.int64)


def _check_stamp(stamp: np.ndarray, what: str) -> np.ndarray:
    stamp = np.ascontiguousarray(stamp, dtype=np.int64)
    if stamp.ndim != 1:
        raise DataError(f"{what}.stamp: expected a 1-D array, got shape {stamp.shape}")
    if stamp.size > 1:
        back = np.flatnonzero(np.diff(stamp) < 0)
        if back.size:
            i = int(back[0]) + 1
            raise DataError(
                f"{what}.stamp[{i}]: time goes backwards "
                f"({stamp[i] / NS:.9f} s after {stamp[i - 1] / NS:.9f} s)"
            )
    return stamp


def _check_rows(a: np.ndarray, n: int, cols: int | None, what: str, dtype=np.float64) -> np.ndarray:
    a = np.ascontiguousarray(a, dtype=dtype)
    if a.shape[0] != n or (cols is not None and (a.ndim != 2 or a.shape[1] != cols)):
        want = f"({n}, {cols})" if cols is not None else f"({n}, ...)"
        raise DataError(f"{what}: expected shape {want}, got {a.shape}")
    return a


@dataclass(frozen=True, eq=False)
class ScanBatch:
    """Scans of one 2D laser.

    stamp:       (N,) int64 ns
    ranges:      (N, B) float32 metres, sensor frame; NaN = no return
    intensities: (N, B) float32 or None
    odom_pose:   (N, 3) float64 or None -- the odometry pose logged with each
                 scan (CARMEN ``FLASER``), odometry frame
    geometry:    (N,) int32 or None -- for a laser with several beam layouts
                 (``SensorModel.geometries``), the layout of each scan; B is
                 then the widest count and a scan's ranges past its own count
                 are NaN. Use :meth:`SensorLog.scan_angles` for the angles.
    """

    stamp: np.ndarray
    ranges: np.ndarray
    intensities: np.ndarray | None = None
    odom_pose: np.ndarray | None = None
    geometry: np.ndarray | None = None

    def __post_init__(self) -> None:
        stamp = _check_stamp(self.stamp, "scans")
        ranges = np.ascontiguousarray(self.ranges, dtype=np.float32)
        if ranges.ndim != 2 or ranges.shape[0] != stamp.size:
            raise DataError(f"scans.ranges: expected shape ({stamp.size}, B), got {ranges.shape}")
        neg = np.flatnonzero((ranges < 0).any(axis=1))
        if neg.size:
            raise DataError(f"scans.ranges[{int(neg[0])}]: negative range (use NaN for no return)")
        if np.isinf(ranges).any():
            raise DataError("scans.ranges: infinite range (use NaN for no return)")
        object.__setattr__(self, "stamp", stamp)
        object.__setattr__(self, "ranges", ranges)
        if self.intensities is not None:
            inten = np.ascontiguousarray(self.intensities, dtype=np.float32)
            if inten.shape != ranges.shape:
                raise DataError(f"scans.intensities: expected shape {ranges.shape}, got {inten.shape}")
            object.__setattr__(self, "intensities", inten)
        if self.odom_pose is not None:
            object.__setattr__(self, "odom_pose", _check_rows(self.odom_pose, stamp.size, 3, "scans.odom_pose"))
        if self.geometry is not None:
            g = np.asarray(self.geometry)
            if g.shape != (stamp.size,) or (g.size and (g.dtype.kind not in "iu" or g.min() < 0)):
                raise DataError(f"scans.geometry: expected ({stamp.size},) non-negative integers, got shape {g.shape} of {g.dtype}")
            object.__setattr__(self, "geometry", np.ascontiguousarray(g, dtype=np.int32))

    def __len__(self) -> int:
        return int(self.stamp.size)

    @property
    def n_beams(self) -> int:
        return int(self.ranges.shape[1])

    @property
    def t(self) -> np.ndarray:
        """(N,) float64 seconds."""
        return self.stamp / NS


@dataclass(frozen=True, eq=False)
class Odometry:
    """Odometry rows; the meaning of ``values`` columns is ``ODOMETRY_KINDS[kind]``.

    stamp:  (M,) int64 ns
    values: (M, k) float64
    sigma:  (k,) the white noise of each column that the log's source states (a simulator's setting, a data set's
            documentation), as the standard deviation a random walk of it reaches in one second (the column's unit
            times s^-1/2 for increments: a per-row std s0 over rows of dt seconds is s0 / sqrt(dt)); None: not stated.
            The SLAM settings derive the vehicle model's noise from it when they give none
            (:func:`slam_runtime.defaults.derived`).
    """

    kind: str
    stamp: np.ndarray
    values: np.ndarray
    sigma: tuple[float, ...] | None = None

    def __post_init__(self) -> None:
        if self.kind not in ODOMETRY_KINDS:
            raise DataError(f"odometry.kind: expected one of {sorted(ODOMETRY_KINDS)}, got {self.kind!r}")
        stamp = _check_stamp(self.stamp, "odometry")
        values = _check_rows(self.values, stamp.size, len(ODOMETRY_KINDS[self.kind]), "odometry.values")
        bad = np.flatnonzero(~np.isfinite(values).all(axis=1))
        if bad.size:
            raise DataError(f"odometry.values[{int(bad[0])}]: not a finite number")
        if self.sigma is not None:
            k = len(ODOMETRY_KINDS[self.kind])
            sig = tuple(float(v) for v in np.asarray(self.sigma, dtype=np.float64).ravel())
            if len(sig) != k or not all(np.isfinite(v) and v >= 0.0 for v in sig):
                raise DataError(f"odometry.sigma: expected {k} finite standard deviations >= 0 (one per column), got {self.sigma!r}")
            object.__setattr__(self, "sigma", sig)
        object.__setattr__(self, "stamp", stamp)
        object.__setattr__(self, "values", values)

    def __len__(self) -> int:
        return int(self.stamp.size)

    @property
    def t(self) -> np.ndarray:
        return self.stamp / NS

    @property
    def columns(self) -> tuple[str, ...]:
        return ODOMETRY_KINDS[self.kind]


@dataclass(frozen=True, eq=False)
class ReferencePoses:
    """Reference trajectory of the vehicle, world frame.

    source: ``"ground_truth"`` (e.g. Vicon, simulator) or ``"gps"`` (partial truth)
    stamp:  (M,) int64 ns
    poses:  (M, 3) float64 (x, y, theta); theta is NaN when not measured (GPS)
    point:  (x, y) [m], vehicle frame: the point of the vehicle whose positions ``poses`` give. (0, 0)
            is the vehicle's own reference point, the one the filters estimate (the rear-axle centre of an
            Ackermann vehicle); a GPS antenna elsewhere on the vehicle, or a data set whose published
            reference follows another point, gives that point's offset. An estimate is compared with the
            reference at this point (``pose (+) point``): a lever arm of metres turns with the heading, and
            no rigid fit of the whole trajectory takes it out.
    """

    source: str
    stamp: np.ndarray
    poses: np.ndarray
    point: tuple[float, float] = (0.0, 0.0)

    def __post_init__(self) -> None:
        if self.source not in REFERENCE_SOURCES:
            raise DataError(f"reference.source: expected one of {REFERENCE_SOURCES}, got {self.source!r}")
        stamp = _check_stamp(self.stamp, f"reference[{self.source}]")
        poses = _check_rows(self.poses, stamp.size, 3, f"reference[{self.source}].poses")
        bad = np.flatnonzero(~np.isfinite(poses[:, :2]).all(axis=1))
        if bad.size:
            raise DataError(f"reference[{self.source}].poses[{int(bad[0])}]: position is not finite")
        try:
            point = tuple(float(v) for v in np.asarray(self.point, dtype=np.float64).reshape(-1))
        except (TypeError, ValueError):
            point = ()
        if len(point) != 2 or not all(np.isfinite(point)):
            raise DataError(f"reference[{self.source}].point: expected (x, y) in metres, finite, got {self.point!r}")
        object.__setattr__(self, "stamp", stamp)
        object.__setattr__(self, "poses", poses)
        object.__setattr__(self, "point", point)

    @property
    def on_vehicle_point(self) -> bool:
        """True when the reference locates the vehicle's own reference point (point (0, 0))."""
        return self.point == (0.0, 0.0)

    def at_point(self, poses: np.ndarray) -> np.ndarray:
        """Vehicle poses (N, 3) [world frame] moved to the point this reference locates: (N, 3), heading kept."""
        poses = np.asarray(poses, dtype=np.float64)
        if self.on_vehicle_point:
            return poses
        out = poses.copy()
        out[:, :2] = compose(poses, np.array([self.point[0], self.point[1], 0.0]))[:, :2]
        return out

    def __len__(self) -> int:
        return int(self.stamp.size)

    @property
    def t(self) -> np.ndarray:
        return self.stamp / NS


@dataclass(frozen=True, eq=False)
class Landmarks:
    """Reference landmarks, world frame.

    ids:    (L,) int64 identifiers (unique)
    xy:     (L, 2) float64 metres
    radius: (L,) float64 metres, NaN when unknown
    sigma:  (L, 2) float64 standard deviation of xy, NaN when unknown
    """

    ids: np.ndarray
    xy: np.ndarray
    radius: np.ndarray | None = None
    sigma: np.ndarray | None = None

    def __post_init__(self) -> None:
        ids = np.ascontiguousarray(self.ids, dtype=np.int64)
        if ids.ndim != 1:
            raise DataError(f"landmarks.ids: expected a 1-D array, got shape {ids.shape}")
        if np.unique(ids).size != ids.size:
            raise DataError("landmarks.ids: identifiers are not unique")
        n = ids.size
        object.__setattr__(self, "ids", ids)
        object.__setattr__(self, "xy", _check_rows(self.xy, n, 2, "landmarks.xy"))
        radius = np.full(n, np.nan) if self.radius is None else self.radius
        object.__setattr__(self, "radius", _check_rows(np.reshape(radius, (-1,)), n, None, "landmarks.radius"))
        sigma = np.full((n, 2), np.nan) if self.sigma is None else self.sigma
        object.__setattr__(self, "sigma", _check_rows(sigma, n, 2, "landmarks.sigma"))
        bad = np.flatnonzero(~np.isfinite(self.xy).all(axis=1))
        if bad.size:
            raise DataError(f"landmarks.xy[{int(bad[0])}]: position is not finite")
        bad = np.flatnonzero(np.isinf(self.radius) | (self.radius <= 0))  # NaN: unknown
        if bad.size:
            raise DataError(f"landmarks.radius[{int(bad[0])}]: expected a positive finite radius or NaN (unknown), got {self.radius[bad[0]]}")

    def __len__(self) -> int:
        return int(self.ids.size)


@dataclass(frozen=True, eq=False)
class Detections:
    """Detection-level records for logs that carry detections, not raw scans.

    frame_stamp: (F,) int64 ns, one per detection frame (scan or image), sorted
    frame:       (D,) int64 index into ``frame_stamp``, non-decreasing
    range:       (D,) float64 metres, sensor frame
    bearing:     (D,) float64 radians, sensor frame (0 = straight ahead)
    descriptors: name -> (D,) array (e.g. ``diameter`` [m], ``barcode``, ``subject``)
    """

    frame_stamp: np.ndarray
    frame: np.ndarray
    range: np.ndarray
    bearing: np.ndarray
    descriptors: Mapping[str, np.ndarray] = field(default_factory=dict)

    def __post_init__(self) -> None:
        fs = _check_stamp(self.frame_stamp, "detections.frame")
        frame = np.ascontiguousarray(self.frame, dtype=np.int64)
        n = frame.size
        if frame.ndim != 1:
            raise DataError(f"detections.frame: expected a 1-D array, got shape {frame.shape}")
        if n and (frame.min() < 0 or frame.max() >= fs.size or (np.diff(frame) < 0).any()):
            raise DataError("detections.frame: indices must be sorted and within the frames")
        rng = _check_rows(self.range, n, None, "detections.range")
        brg = _check_rows(self.bearing, n, None, "detections.bearing")
        bad = np.flatnonzero(~np.isfinite(rng) | (rng < 0) | ~np.isfinite(brg))
        if bad.size:
            raise DataError(f"detections[{int(bad[0])}]: range must be finite and >= 0, bearing finite")
        desc = {}
        for name, arr in self.descriptors.items():
            a = np.ascontiguousarray(arr)
            if a.shape != (n,):
                raise DataError(f"detections.descriptors[{name!r}]: expected shape ({n},), got {a.shape}")
            desc[str(name)] = a
        object.__setattr__(self, "frame_stamp", fs)
        object.__setattr__(self, "frame", frame)
        object.__setattr__(self, "range", rng)
        object.__setattr__(self, "bearing", brg)
        object.__setattr__(self, "descriptors", desc)

    def __len__(self) -> int:
        return int(self.frame.size)

    @property
    def n_frames(self) -> int:
        return int(self.frame_stamp.size)

    def frame_slices(self) -> np.ndarray:
        """(F + 1,) int64 offsets: detections of frame f are ``[off[f], off[f+1])``."""
        return np.searchsorted(self.frame, np.arange(self.n_frames + 1), side="left").astype(np.int64)


@dataclass(frozen=True, eq=False)
class PointClouds:
    """3D point clouds (e.g. Velodyne frames), sensor frame.

    stamp:   (F,) int64 ns
    offsets: (F + 1,) int64; points of frame f are ``points[offsets[f]:offsets[f+1]]``
    points:  (P, 4) float32 (x, y, z [m], reflectance)
    """

    stamp: np.ndarray
    offsets: np.ndarray
    points: np.ndarray

    def __post_init__(self) -> None:
        stamp = _check_stamp(self.stamp, "clouds")
        off = np.ascontiguousarray(self.offsets, dtype=np.int64)
        pts = np.ascontiguousarray(self.points, dtype=np.float32)
        if pts.ndim != 2 or pts.shape[1] != 4:
            raise DataError(f"clouds.points: expected shape (P, 4), got {pts.shape}")
        if off.shape != (stamp.size + 1,) or off[0] != 0 or off[-1] != pts.shape[0] or (np.diff(off) < 0).any():
            raise DataError("clouds.offsets: expected F + 1 non-decreasing offsets from 0 to the number of points")
        object.__setattr__(self, "stamp", stamp)
        object.__setattr__(self, "offsets", off)
        object.__setattr__(self, "points", pts)

    def __len__(self) -> int:
        return int(self.stamp.size)

    def frame(self, i: int) -> np.ndarray:
        """(P_i, 4) float32 points of frame ``i``."""
        return self.points[self.offsets[i] : self.offsets[i + 1]]


@dataclass(frozen=True, eq=False)
class PlaneLandmarks:
    """Reference planar landmarks (facades, walls, boards, car faces, the ground), world frame.

    ids:      (L,) int64 identifiers (unique)
    normal:   (L, 3) float64 unit normals; offset (L,) float64 [m]: the plane n . p = d
    vertices: (V, 3) float64 outline vertices in order; plane l's are ``vertices[offsets[l]:offsets[l+1]]``
    offsets:  (L + 1,) int64
    kind:     (L,) str what each plane is (``facade``, ``wall``, ``board``, ``car``, ``ground``, ...)
    """

    ids: np.ndarray
    normal: np.ndarray
    offset: np.ndarray
    vertices: np.ndarray
    offsets: np.ndarray
    kind: np.ndarray

    def __post_init__(self) -> None:
        ids = np.ascontiguousarray(self.ids, dtype=np.int64)
        if ids.ndim != 1:
            raise DataError(f"planes.ids: expected a 1-D array, got shape {ids.shape}")
        if np.unique(ids).size != ids.size:
            raise DataError("planes.ids: identifiers are not unique")
        n = ids.size
        normal = _check_rows(self.normal, n, 3, "planes.normal")
        norm = np.linalg.norm(normal, axis=1)
        bad = np.flatnonzero(~np.isfinite(norm) | (np.abs(norm - 1.0) > 1e-6))
        if bad.size:
            raise DataError(f"planes.normal[{int(bad[0])}]: not a unit vector")
        off = np.ascontiguousarray(self.offsets, dtype=np.int64)
        verts = np.ascontiguousarray(self.vertices, dtype=np.float64).reshape(-1, 3)
        if off.shape != (n + 1,) or off[0] != 0 or off[-1] != verts.shape[0] or (np.diff(off) < 3).any():
            raise DataError("planes.offsets: expected L + 1 offsets from 0 to the number of vertices, at least 3 vertices per plane")
        kind = np.asarray(self.kind, dtype=str)
        if kind.shape != (n,):
            raise DataError(f"planes.kind: expected shape ({n},), got {kind.shape}")
        object.__setattr__(self, "ids", ids)
        object.__setattr__(self, "normal", normal)
        object.__setattr__(self, "offset", _check_rows(np.reshape(self.offset, (-1,)), n, None, "planes.offset"))
        object.__setattr__(self, "vertices", verts)
        object.__setattr__(self, "offsets", off)
        object.__setattr__(self, "kind", kind)

    def __len__(self) -> int:
        return int(self.ids.size)

    def polygon(self, i: int) -> np.ndarray:
        """(V_i, 3) outline of plane ``i``."""
        return self.vertices[self.offsets[i] : self.offsets[i + 1]]

    def take(self, idx: np.ndarray) -> PlaneLandmarks:
        idx = np.asarray(idx, dtype=np.int64)
        polys = [self.polygon(int(i)) for i in idx]
        off = np.concatenate([[0], np.cumsum([p.shape[0] for p in polys])]).astype(np.int64)
        return PlaneLandmarks(self.ids[idx], self.normal[idx], self.offset[idx], np.vstack(polys) if polys else np.zeros((0, 3)), off, self.kind[idx])


class Event(NamedTuple):
    """One record of one stream: ``stream`` in {scan, odometry, reference:<source>, detections, clouds}."""

    stamp: int
    stream: str
    index: int


class Frame(NamedTuple):
    """One scan or detection frame with the odometry rows that led to it.

    index: frame number; stamp: int64 ns; kind: "scan", "detections" or "cloud";
    rows: the scan row, the slice into ``log.detections`` arrays, or the cloud's index;
    odometry: slice into ``log.odometry`` rows with stamp in (previous frame, this frame].
    """

    index: int
    stamp: int
    kind: str
    rows: int | slice
    odometry: slice


@dataclass(frozen=True, eq=False)
class SensorLog:
    """A log: metadata plus optional streams; see the module docstring.

    ``source`` records where the log came from (reader, file names, hashes);
    ``reordered`` counts records a reader had to sort back into time order.
    """

    name: str
    sensor: SensorModel | None = None
    scans: ScanBatch | None = None
    odometry: Odometry | None = None
    reference: Mapping[str, ReferencePoses] = field(default_factory=dict)
    landmarks: Landmarks | None = None
    detections: Detections | None = None
    clouds: PointClouds | None = None
    vehicle: Vehicle | None = None
    source: Mapping[str, object] = field(default_factory=dict)
    planes: PlaneLandmarks | None = None

    def __post_init__(self) -> None:
        object.__setattr__(self, "reference", {k: self.reference[k] for k in sorted(self.reference)})
        for key, ref in self.reference.items():
            if key != ref.source:
                raise DataError(f"reference[{key!r}]: keyed under a different source ({ref.source!r})")
        if self.scans is not None:
            if self.sensor is None or self.sensor.n_beams is None:
                raise DataError("scans need a sensor model with a beam geometry")
            if self.scans.n_beams != self.sensor.n_beams:
                raise DataError(
                    f"scans.ranges: {self.scans.n_beams} beams per scan but the sensor model "
                    f"declares n_beams={self.sensor.n_beams}"
                )
            self._check_geometry()

    def _check_geometry(self) -> None:
        """Per-scan layouts: present exactly when the sensor lists several; ranges NaN past each scan's count."""
        geoms, idx = self.sensor.geometries, self.scans.geometry
        if geoms is None:
            if idx is not None:
                raise DataError("scans.geometry: the sensor model has one beam geometry, so scans carry none")
            return
        if idx is None:
            raise DataError(f"scans.geometry: the sensor model lists {len(geoms)} beam geometries; each scan must say which it used")
        if idx.size and idx.max() >= len(geoms):
            raise DataError(f"scans.geometry[{int(np.argmax(idx))}]: layout {int(idx.max())} but the sensor lists {len(geoms)}")
        counts = np.array([g.n_beams for g in geoms], dtype=np.int64)[idx]
        past = np.arange(self.scans.n_beams)[None, :] >= counts[:, None]
        bad = np.flatnonzero((past & ~np.isnan(self.scans.ranges)).any(axis=1))
        if bad.size:
            i = int(bad[0])
            raise DataError(f"scans.ranges[{i}]: readings past the scan's {int(counts[i])} beams (pad with NaN)")

    def scan_angles(self, rows: int | slice | np.ndarray | None = None) -> np.ndarray:
        """Beam angles of scans, sensor frame [rad]; the one accessor for per-scan beam geometry.

        rows: an int -> (B,) that scan's angles; a slice, an index array or None
        (every scan) -> (B,) shared by all rows when the laser has one layout,
        else (R, B) one row per scan. Past a scan's own beam count the angle is
        NaN (its ranges are NaN there too), which every consumer (detector, ray
        tracer) treats as no beam.
        """
        if self.scans is None or self.sensor is None:
            raise DataError(f"log {self.name!r} has no laser scans")
        if self.sensor.geometries is None:
            return self.sensor.angles()
        table = np.full((len(self.sensor.geometries), self.scans.n_beams), np.nan)
        for k, g in enumerate(self.sensor.geometries):
            table[k, : g.n_beams] = g.angles()
        if isinstance(rows, int | np.integer):
            return table[self.scans.geometry[rows]]
        return table[self.scans.geometry if rows is None else self.scans.geometry[rows]]

    def streams(self) -> list[str]:
        out = []
        if self.scans is not None:
            out.append("scan")
        if self.odometry is not None:
            out.append("odometry")
        out += [f"reference:{k}" for k in self.reference]
        if self.landmarks is not None:
            out.append("landmarks")
        if self.detections is not None:
            out.append("detections")
        if self.clouds is not None:
            out.append("clouds")
        if self.planes is not None:
            out.append("planes")
        return out

    def time_span(self) -> tuple[int, int] | None:
        """(first, last) stamp over all timed streams, ns; None if there is none."""
        stamps = [s for s in self._timed() if s[1].size]
        if not stamps:
            return None
        return int(min(s[1][0] for s in stamps)), int(max(s[1][-1] for s in stamps))

    def _timed(self) -> list[tuple[str, np.ndarray]]:
        out: list[tuple[str, np.ndarray]] = []
        if self.scans is not None:
            out.append(("scan", self.scans.stamp))
        if self.odometry is not None:
            out.append(("odometry", self.odometry.stamp))
        out += [(f"reference:{k}", r.stamp) for k, r in self.reference.items()]
        if self.detections is not None:
            out.append(("detections", self.detections.frame_stamp))
        if self.clouds is not None:
            out.append(("clouds", self.clouds.stamp))
        return out

    def events(self) -> Iterator[Event]:
        """Every record of every timed stream in time order.

        Ties are broken by stream order (odometry before references before
        scans/detections), so the motion up to a frame is known when it arrives.
        """
        order = {"odometry": 0, "scan": 2, "detections": 2, "clouds": 2}
        timed = self._timed()
        if not timed:
            return
        stamps = np.concatenate([s for _, s in timed])
        which = np.concatenate([np.full(s.size, k, dtype=np.int64) for k, (_, s) in enumerate(timed)])
        index = np.concatenate([np.arange(s.size, dtype=np.int64) for _, s in timed])
        prio = np.array([order.get(name, 1) for name, _ in timed], dtype=np.int64)[which]
        perm = np.lexsort((index, which, prio, stamps))
        names = [name for name, _ in timed]
        for st, w, i in zip(stamps[perm].tolist(), which[perm].tolist(), index[perm].tolist(), strict=True):
            yield Event(st, names[w], i)

    def _frame_stamp(self) -> tuple[np.ndarray, str] | None:
        """The stamps (F,) of the frames and their kind: scans, else detection frames, else point clouds."""
        if self.scans is not None:
            return self.scans.stamp, "scan"
        if self.detections is not None:
            return self.detections.frame_stamp, "detections"
        if self.clouds is not None:
            return self.clouds.stamp, "cloud"
        return None

    def frame_stamps(self) -> np.ndarray:
        """(F,) int64 ns: the stamps of :meth:`frames`, in order, without building the frames."""
        src = self._frame_stamp()
        return np.zeros(0, dtype=np.int64) if src is None else np.asarray(src[0], dtype=np.int64)

    def frames(self) -> Iterator[Frame]:
        """Scan frames, or detection frames when the log has no scans, or point-cloud frames when it has
        neither, in time order."""
        src = self._frame_stamp()
        if src is None:
            return
        fstamp, kind = src
        if kind == "detections":
            off = self.detections.frame_slices()
            rows: list[int | slice] = [slice(int(a), int(b)) for a, b in zip(off[:-1], off[1:], strict=True)]
        else:
            rows = list(range(fstamp.size))
        if self.odometry is not None:
            cut = np.searchsorted(self.odometry.stamp, fstamp, side="right")
        else:
            cut = np.zeros(fstamp.size, dtype=np.int64)
        prev = 0
        for i in range(fstamp.size):
            c = int(cut[i])
            yield Frame(i, int(fstamp[i]), kind, rows[i], slice(prev, c))
            prev = c
