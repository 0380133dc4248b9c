"""Map metrics of planar landmarks against a log's plane truth.

The truth a plane map is scored against is the set of landmark planes the
sensor saw well during the run: every true plane (the log's ``planes``
stream) steep enough to be a landmark (|elevation of its normal| <= ``max
elevation``) that had at least ``min_points`` (200: where the calibrated
P_D passes 0.9) unoccluded lidar returns
(ray-traced from the true sensor pose against the measured cloud,
:func:`detectors.raytrace3d.visible_planes`) in at least one of the sampled
frames; coplanar truth planes (two facades on one line) are one map landmark,
since a map of infinite planes cannot tell them apart.

Distance between planes: the embedding (L n, d) of
:class:`slam_runtime.plane_features.PlaneFeature` with the two orientations
of a plane identified (:func:`slam_runtime.plane_features.plane_distance`).
Reported: OSPA and GOSPA with cut-off c, and for the pairs GOSPA assigns
(closer than c) the normal angle [deg] and offset error [m].
"""

from __future__ import annotations

import weakref

import numpy as np
from scipy.optimize import linear_sum_assignment

from detectors.geometry import compose, interpolate_poses
from detectors.sensor_log import SensorLog
from detectors.raytrace3d import BeamGrid, polygon_scene, range_image, visible_planes
from slam_runtime.metrics import gospa, ospa
from slam_runtime.plane_features import embed, plane_distance

_CACHE: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()


def visible_counts(log: SensorLog, every: int = 5) -> np.ndarray:
    """(F', L) unoccluded returns n_p of every true plane in every ``every``-th cloud frame, from the true poses."""
    sensor = log.sensor
    grid = BeamGrid.of(sensor.lidar)
    ref = log.reference["ground_truth"]
    scene = polygon_scene(log.planes)
    mount = np.array([sensor.mount.x, sensor.mount.y, sensor.mount.theta])
    frames = range(0, len(log.clouds), max(1, every))
    sp = compose(interpolate_poses(ref.stamp, ref.poses, log.clouds.stamp[list(frames)]), mount)
    out = np.zeros((len(frames), len(log.planes)), dtype=np.int64)
    for i, f in enumerate(frames):  # one compiled ray trace per frame
        meas = range_image(log.clouds.frame(f), grid)
        out[i], _, _ = visible_planes(
            scene, grid, sp[i], sensor.lidar.height, meas, range_sigma=float(sensor.range_sigma or 0.02), range_max=float(sensor.range_max or 120.0)
        )
    return out


def landmark_truth(
    log: SensorLog, *, min_points: int = 200, max_elevation_deg: float = 45.0, length: float = 10.0, every: int = 5, merge: float = 0.05
) -> tuple[np.ndarray, np.ndarray]:
    """(embeddings (K, 4), ids (K,)) of the planes that were landmarks during the run (module docstring)."""
    key = (min_points, max_elevation_deg, length, every, merge)
    cached = _CACHE.get(log, {})
    if key in cached:
        return cached[key]
    pl = log.planes
    seen = (visible_counts(log, every) >= min_points).any(axis=0)
    steep = np.abs(pl.normal[:, 2]) <= np.sin(np.radians(max_elevation_deg))
    idx = np.flatnonzero(seen & steep)
    e = embed(pl.normal[idx], pl.offset[idx], length)
    keep: list[int] = []
    for i in range(e.shape[0]):  # greedy de-duplication of coplanar truth planes (tens of planes)
        if not keep or plane_distance(e[i : i + 1], e[keep]).min() > merge:
            keep.append(i)
    res = (e[keep], pl.ids[idx[keep]])
    cached[key] = res
    _CACHE[log] = cached
    return res


def plane_map_metrics(log: SensorLog, est: np.ndarray, c: float = 1.0, p: float = 1.0, length: float = 10.0) -> dict:
    """Map OSPA / GOSPA of embedded plane estimates (K, 4) against the landmark truth, and the errors of matched pairs."""
    truth, _ = landmark_truth(log, length=length)
    est = np.asarray(est, dtype=np.float64).reshape(-1, 4)
    out = {
        "map_ospa": ospa(est, truth, c, p, plane_distance),
        "map_gospa": gospa(est, truth, c, p, plane_distance)["gospa"],
        "map_features": int(est.shape[0]),
        "landmarks_true": int(truth.shape[0]),
        "ospa_c_m": c,
        "ospa_p": p,
        "plane_metric": f"sqrt(({length:g} m)^2 |n1 - n2|^2 + (d1 - d2)^2), either orientation",
    }
    ang, off = np.zeros(0), np.zeros(0)
    if est.shape[0] and truth.shape[0]:
        d = plane_distance(est, truth)
        r, k = linear_sum_assignment(np.minimum(d, c))
        ok = d[r, k] < c
        r, k = r[ok], k[ok]
        ne, nt = est[r, :3] / length, truth[k, :3] / length
        sgn = np.where((ne * nt).sum(1) < 0, -1.0, 1.0)
        ang = np.degrees(np.arccos(np.clip(np.abs((ne * nt).sum(1)), 0.0, 1.0)))
        off = np.abs(est[r, 3] - sgn * truth[k, 3])
    out["landmarks_mapped"] = int(ang.size)
    out["map_normal_angle_median_deg"] = float(np.median(ang)) if ang.size else float("nan")
    out["map_offset_error_median_m"] = float(np.median(off)) if off.size else float("nan")
    return out


