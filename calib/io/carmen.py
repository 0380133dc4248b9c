"""CARMEN log reader (``FLASER``, ``RLASER``, ``ROBOTLASER1``, ``ODOM``, ``TRUEPOS``).

Plain, ``.gz``, ``.bz2`` or ``.xz``. Line formats (``../shared/data/README.md``)::

    FLASER n r1..rn x y theta odom_x odom_y odom_theta ipc_timestamp hostname logger_timestamp
    ODOM x y theta tv rv accel ipc_timestamp hostname logger_timestamp
    TRUEPOS true_x true_y true_theta odom_x odom_y odom_theta ipc_timestamp hostname logger_timestamp
    ROBOTLASER1 type start_angle fov resolution max_range accuracy remission_mode
                n r1..rn m i1..im laser_x laser_y laser_theta robot_x robot_y robot_theta
                tv rv fwd_safety side_safety turn_axis ipc_timestamp hostname logger_timestamp

Timestamps are the ``ipc_timestamp`` field. Beam geometry of ``FLASER``/``RLASER``
(which carry none): the beams span pi radians starting at -pi/2; with an odd
count (181, 361) the last beam is at +pi/2 (increment pi/(n-1)), with an even
count (180) at +pi/2 - pi/n (increment pi/n), the SICK LMS convention.
No return is encoded by CARMEN as a saturated reading: when the largest
reading of the log makes up at least 0.05 % of all readings it is taken as the
sensor's maximum and such readings become NaN (Intel: 81.83 m, ACES: 50.00 m);
``range_max`` overrides this.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from pydantic import ValidationError

from calib.io.common import DEFAULT_MAX_BACKSTEP, file_digest, iter_lines, parse_floats, parse_stamp, time_order
from detectors.sensor_log import BeamGeometry, Mount, Odometry, ReferencePoses, ScanBatch, SensorLog, SensorModel
from profiles.errors import DataError, UsageError

LASER_TYPES = ("FLASER", "RLASER", "ROBOTLASER1")
_SATURATION_SHARE = 5e-4


def looks_like_carmen(path: Path) -> bool:
    name = path.name.lower()
    return any(name.endswith(s + z) for s in (".clf", ".log", ".carmen") for z in ("", ".gz", ".bz2", ".xz"))


def read_carmen(
    path: str | Path,
    *,
    laser: str = "front",
    range_max: float | None = None,
    max_backstep: float = DEFAULT_MAX_BACKSTEP,
) -> SensorLog:
    """Read one laser and the odometry of a CARMEN log.

    laser: ``front`` (FLASER, or ROBOTLASER1 when the log has no FLASER) or ``rear`` (RLASER).

    Beam geometry per scan: a laser whose lines do not all share one layout
    (interlaced SICK scanners alternating 180 and 181 beams or start angles;
    ROBOTLASER1 lines with their own) gives a sensor with several
    ``geometries`` and each scan's layout (:meth:`SensorLog.scan_angles`).

    ODOM lines stamped 0 (written so by some SLAM tools) have no time: each
    is placed by its order in the file, its time interpolated by line number
    between the timed lines around it; ``source["untimed"]`` counts them.
    A stream whose stamps collapse to few distinct values (a "corrected" log
    stamped at the time of its rewrite) is reported in
    ``source["collapsed_stamps"]`` (distinct values, records): its span is no
    duration (:func:`collapsed_stamps`).
    """
    path = Path(path)
    if laser not in ("front", "rear"):
        raise UsageError(f"--laser: expected 'front' or 'rear', got {laser!r}")
    scan_rows: list[np.ndarray] = []
    scan_geom: list[tuple[int, float, float]] = []
    scan_stamp: list[int] = []
    scan_line: list[int] = []
    scan_odom: list[np.ndarray] = []
    scan_kind: str | None = None
    odom_rows: list[np.ndarray] = []
    odom_stamp: list[int] = []
    odom_line: list[int] = []
    true_rows: list[np.ndarray] = []
    true_stamp: list[int] = []
    true_line: list[int] = []
    params: dict[str, str] = {}
    wanted = {"front": ("FLASER", "ROBOTLASER1"), "rear": ("RLASER",)}[laser]

    for lineno, line in iter_lines(path):
        if not line or line.startswith("#"):
            continue
        tok = line.split()
        kind = tok[0]
        if kind == "PARAM" and len(tok) >= 3:
            params[tok[1]] = tok[2]
        elif kind in wanted:
            if scan_kind is None:
                scan_kind = kind
            elif kind != scan_kind:
                continue  # a log with FLASER and ROBOTLASER1 for the same laser: keep the first kind
            if kind == "ROBOTLASER1":
                ranges, odom, stamp, geom = _robotlaser(tok, path, lineno)
            else:
                ranges, odom, stamp = _flaser(tok, path, lineno)
                geom = _sick_geometry(ranges.size)
            scan_rows.append(ranges)
            scan_geom.append(geom)
            scan_odom.append(odom)
            scan_stamp.append(stamp)
            scan_line.append(lineno)
        elif kind == "ODOM":
            if len(tok) != 10:
                raise DataError(f"{path}:{lineno}: ODOM has {len(tok)} fields, expected 10")
            odom_rows.append(parse_floats(tok[1:4], path, lineno, "ODOM pose"))
            odom_stamp.append(parse_stamp(tok[7], path, lineno))
            odom_line.append(lineno)
        elif kind == "TRUEPOS":
            if len(tok) != 10:
                raise DataError(f"{path}:{lineno}: TRUEPOS has {len(tok)} fields, expected 10")
            true_rows.append(parse_floats(tok[1:4], path, lineno, "TRUEPOS pose"))
            true_stamp.append(parse_stamp(tok[7], path, lineno))
            true_line.append(lineno)

    if not scan_rows and not odom_rows:
        raise DataError(f"{path}: no {'/'.join(wanted)} or ODOM lines; is this a CARMEN log?")

    untimed = {}
    if odom_rows:
        odom_stamp, untimed["odometry"] = _place_untimed(
            np.array(odom_stamp, dtype=np.int64), np.array(odom_line), np.array(scan_stamp + true_stamp, dtype=np.int64), np.array(scan_line + true_line), path
        )
    reordered = {}
    scans = sensor = None
    if scan_rows:
        perm, reordered["scan"] = time_order(np.array(scan_stamp), np.array(scan_line), path, str(scan_kind), max_backstep)
        width = max(r.size for r in scan_rows)
        raw = np.full((len(scan_rows), width), np.nan)
        for k, r in enumerate(scan_rows):
            raw[k, : r.size] = r
        raw = raw[perm]
        if range_max is None:
            range_max = _param_range_max(params, laser)
        if range_max is None:
            top = float(np.nanmax(raw))
            range_max = top if np.count_nonzero(raw >= top) >= _SATURATION_SHARE * np.count_nonzero(np.isfinite(raw)) else np.nextafter(top, np.inf)
        ranges = raw.astype(np.float32)
        ranges[raw >= range_max] = np.nan
        layouts, which = np.unique(np.array(scan_geom, dtype=[("n", "i8"), ("a", "f8"), ("d", "f8")]), return_inverse=True)
        offset = float(params.get(f"robot_{laser}laser_offset", 0.0) or 0.0)
        common = {"kind": "laser2d", "range_min": 0.0, "range_max": float(range_max), "mount": Mount(x=offset, theta=np.pi if laser == "rear" else 0.0)}
        try:
            if layouts.size == 1:
                sensor = SensorModel(n_beams=width, angle_min=float(layouts[0]["a"]), angle_increment=float(layouts[0]["d"]), **common)
                geometry = None
            else:
                geoms = tuple(BeamGeometry(n_beams=int(g["n"]), angle_min=float(g["a"]), angle_increment=float(g["d"])) for g in layouts)
                sensor = SensorModel(n_beams=width, geometries=geoms, **common)
                geometry = which.reshape(-1)[perm]
        except ValidationError as exc:
            raise DataError(f"{path}: {scan_kind!s} beam geometry: {exc.errors()[0]['msg']}") from None
        scans = ScanBatch(np.array(scan_stamp, dtype=np.int64)[perm], ranges, None, np.stack(scan_odom)[perm], geometry)
    odometry = None
    if odom_rows:
        perm, reordered["odometry"] = time_order(odom_stamp, np.array(odom_line), path, "ODOM", max_backstep)
        odometry = Odometry("pose", odom_stamp[perm], np.stack(odom_rows)[perm])
    reference = {}
    if true_rows:
        perm, reordered["reference:ground_truth"] = time_order(np.array(true_stamp), np.array(true_line), path, "TRUEPOS", max_backstep)
        reference["ground_truth"] = ReferencePoses("ground_truth", np.array(true_stamp, dtype=np.int64)[perm], np.stack(true_rows)[perm])
    source = {"reader": "carmen", "file": path.name, "sha256": file_digest(path), "laser": laser, "reordered": reordered}
    if any(untimed.values()):
        source["untimed"] = {k: v for k, v in untimed.items() if v}
    collapsed = {
        k: v
        for k, v in (("scan", collapsed_stamps(scans.stamp if scans is not None else None)), ("odometry", collapsed_stamps(odometry.stamp if odometry else None)))
        if v
    }
    if collapsed:
        source["collapsed_stamps"] = collapsed
    return SensorLog(name=path.name.split(".")[0], sensor=sensor, scans=scans, odometry=odometry, reference=reference, source=source)


#: A stream whose records share fewer distinct stamps than this share of their number has no usable time.
COLLAPSED_SHARE = 0.1


def collapsed_stamps(stamps: np.ndarray | None) -> dict | None:
    """{distinct, records} when a stream's stamps collapse to few distinct values, else None.

    Logs rewritten by SLAM tools ("corrected" logs) may stamp every line with the time of the rewrite or
    with a handful of values: the span between the first and last value is then no duration, and nothing
    that pairs records by time (benchmark relations, odometry interpolation) can hold.
    """
    if stamps is None or stamps.size < 10:
        return None
    distinct = int(np.unique(stamps).size)
    return {"distinct": distinct, "records": int(stamps.size)} if distinct < COLLAPSED_SHARE * stamps.size else None


def _sick_geometry(n: int) -> tuple[int, float, float]:
    """FLASER/RLASER carry no geometry: pi radians from -pi/2, SICK LMS convention (see the module docstring)."""
    return n, -np.pi / 2, (np.pi / (n - 1) if n % 2 and n > 1 else np.pi / n)


#: A log whose clock starts at 0 has its first real stamps within this [ns]; CARMEN logs carry Unix time.
_CLOCK_FROM_ZERO = 86_400 * 1_000_000_000


def _place_untimed(stamps: np.ndarray, lines: np.ndarray, timed: np.ndarray, timed_lines: np.ndarray, path: Path) -> tuple[np.ndarray, int]:
    """Stamps of records stamped 0 that have no time, from their place in the file.

    A stamp of 0 is "no time" unless the log's clock really starts at 0 (every
    zero-stamped line comes before the first timed line, and that line's time
    is within a day). Such a record's time is interpolated by line number
    between the timed lines around it (clamped to the first and last).
    Returns (stamps, how many were placed).
    """
    zero = stamps == 0
    if not zero.any():
        return stamps, 0
    known_lines = np.concatenate([timed_lines[timed != 0], lines[~zero]])
    known = np.concatenate([timed[timed != 0], stamps[~zero]])
    if known.size == 0:
        if stamps.size == 1:
            return stamps, 0  # one record at time 0: nothing to place it against
        raise DataError(f"{path}: every line is stamped 0; the log carries no time")
    order = np.argsort(known_lines, kind="stable")
    known_lines, known = known_lines[order], known[order]
    if lines[zero].max() < known_lines[0] and known[0] <= _CLOCK_FROM_ZERO:
        return stamps, 0
    base = int(known[0])
    est = np.interp(lines[zero], known_lines, (known - base).astype(np.float64))
    out = stamps.copy()
    out[zero] = base + np.rint(est).astype(np.int64)
    return out, int(zero.sum())


def _param_range_max(params: dict[str, str], laser: str) -> float | None:
    for key in (f"laser_{laser}_laser_max_range", f"robot_{laser}_laser_max", f"{laser}_laser_max_range"):
        if key in params:
            try:
                return float(params[key])
            except ValueError:
                return None
    return None


def _count(tok: list[str], i: int, path: Path, lineno: int) -> int:
    try:
        n = int(tok[i])
    except (IndexError, ValueError):
        raise DataError(f"{path}:{lineno}: {tok[0]} beam count missing or not an integer") from None
    if n <= 0:
        raise DataError(f"{path}:{lineno}: {tok[0]} beam count {n} must be positive")
    return n


def _ranges(tok: list[str], path: Path, lineno: int) -> np.ndarray:
    r = parse_floats(tok, path, lineno, "range reading")
    neg = np.flatnonzero(r < 0)
    if neg.size:
        raise DataError(f"{path}:{lineno}: range reading {int(neg[0]) + 1} is negative ({r[neg[0]]})")
    if np.isinf(r).any():
        raise DataError(f"{path}:{lineno}: infinite range reading")
    return r


def _flaser(tok: list[str], path: Path, lineno: int) -> tuple[np.ndarray, np.ndarray, int]:
    n = _count(tok, 1, path, lineno)
    if len(tok) != n + 11:
        raise DataError(f"{path}:{lineno}: {tok[0]} declares {n} beams but has {len(tok)} fields (expected {n + 11})")
    ranges = _ranges(tok[2 : 2 + n], path, lineno)
    odom = parse_floats(tok[2 + n + 3 : 2 + n + 6], path, lineno, "odometry pose")
    return ranges, odom, parse_stamp(tok[2 + n + 6], path, lineno)


def _robotlaser(tok: list[str], path: Path, lineno: int) -> tuple[np.ndarray, np.ndarray, int, tuple[int, float, float]]:
    n = _count(tok, 8, path, lineno)
    if len(tok) < 9 + n + 1:
        raise DataError(f"{path}:{lineno}: ROBOTLASER1 is truncated")
    m = _count(tok, 9 + n, path, lineno) if tok[9 + n] != "0" else 0
    expected = 9 + n + 1 + m + 14
    if len(tok) != expected:
        raise DataError(f"{path}:{lineno}: ROBOTLASER1 has {len(tok)} fields, expected {expected}")
    head = parse_floats(tok[2:5], path, lineno, "ROBOTLASER1 geometry")
    ranges = _ranges(tok[9 : 9 + n], path, lineno)
    rest = 9 + n + 1 + m
    odom = parse_floats(tok[rest + 3 : rest + 6], path, lineno, "robot pose")
    if not np.isfinite(head).all():
        raise DataError(f"{path}:{lineno}: ROBOTLASER1 geometry: start angle, field of view and resolution must be finite")
    return ranges, odom, parse_stamp(tok[rest + 11], path, lineno), (n, float(head[0]), float(head[2]))
