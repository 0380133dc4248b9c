"""Labelling (Inostroza 2015, ch. 6): detections against the true landmarks, and n_p per pair.

Every scan's detections are put in the world frame with the scan's sensor pose
and associated with the true landmarks within a gate (1 m in the thesis) whose
surface carries at least half of the cluster's returns (see :func:`support`), by an
optimal assignment per scan (``scipy.optimize.linear_sum_assignment``, run only
on the scans where a detection or a landmark has more than one candidate).
For every (scan, landmark) pair with the landmark within the sensor's range,
the ray tracer gives n_p and the number of expected hits.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pandas as pd
from scipy.optimize import linear_sum_assignment
from scipy.spatial import cKDTree

from calib.detect import DetectConfig, detections_table, run_detector
from detectors.geometry import compose
from detectors.sensor_log import SensorLog
from detectors.raytrace import count_unoccluded
from profiles.errors import DataError
from profiles.schema import CircleDetectorParams


@dataclass(frozen=True, eq=False)
class Labelled:
    """detections: one row per detection (before any Hotelling gate), ``landmark`` = -1 when false;
    pairs: one row per (scan, landmark) in range, ``det`` = row in ``detections`` associated with it or -1."""

    detections: pd.DataFrame
    pairs: pd.DataFrame


def associate(
    scan: np.ndarray, det_xy: np.ndarray, lm_xy: np.ndarray, gate: float, admissible=None
) -> tuple[np.ndarray, np.ndarray]:
    """Optimal per-scan assignment of detections (D,) to landmarks within ``gate``.

    scan (D,) scan index of each detection; det_xy (D, 2), lm_xy (L, 2) world frame;
    ``admissible(i, j) -> (K,) bool`` may veto candidate pairs (arrays of detection and
    landmark indices) before the assignment.
    returns (landmark index per detection or -1 (D,), distance (D,) or NaN)
    """
    d = scan.size
    out = np.full(d, -1, dtype=np.int64)
    dist = np.full(d, np.nan)
    if d == 0 or lm_xy.shape[0] == 0:
        return out, dist
    sp = cKDTree(det_xy).sparse_distance_matrix(cKDTree(lm_xy), gate, output_type="ndarray")
    if sp.size == 0:
        return out, dist
    i, j, v = sp["i"].astype(np.int64), sp["j"].astype(np.int64), sp["v"]
    if admissible is not None:
        ok = admissible(i, j)
        i, j, v = i[ok], j[ok], v[ok]
        if i.size == 0:
            return out, dist
    s = scan[i]
    # a (scan, landmark) key claimed by several detections, or a detection with several candidates
    key = s * lm_xy.shape[0] + j
    _, kinv, kcnt = np.unique(key, return_inverse=True, return_counts=True)
    icnt = np.bincount(i, minlength=d)
    clean = (kcnt[kinv] == 1) & (icnt[i] == 1)
    out[i[clean]], dist[i[clean]] = j[clean], v[clean]
    for sc in np.unique(s[~clean]):  # only the ambiguous scans need the Hungarian algorithm
        m = (s == sc) & ~clean
        ii, jj, vv = i[m], j[m], v[m]
        ui, ri = np.unique(ii, return_inverse=True)
        uj, rj = np.unique(jj, return_inverse=True)
        cost = np.full((ui.size, uj.size), 1e9)
        cost[ri, rj] = vv
        r, c = linear_sum_assignment(cost)
        ok = cost[r, c] < 1e9
        out[ui[r[ok]]], dist[ui[r[ok]]] = uj[c[ok]], cost[r[ok], c[ok]]
    return out, dist


#: Share of a cluster's returns that must lie on the landmark for the detection to be of it.
MIN_SUPPORT = 0.5


def support(
    ranges: np.ndarray,
    angles: np.ndarray,
    sensor_poses: np.ndarray,
    scan: np.ndarray,
    first: np.ndarray,
    last: np.ndarray,
    centre: np.ndarray,
    radius: np.ndarray,
    tol: float,
) -> np.ndarray:
    """Share of each candidate cluster's returns lying on the candidate landmark's circle.

    A return supports the landmark when the beam's ray-traced range to the landmark
    is within ``tol`` of the measured range. Without this, a clutter circle whose
    centre happens to fall within the gate of a tree (about 3 % of false
    detections in a park of one tree per 100 m^2 and a 1 m gate) is labelled true.
    Vectorised over all returns of all K candidates: scan/first/last (K,), centre (K, 2), radius (K,);
    angles (B,) shared or (S, B) per scan.
    """
    lens = last - first + 1
    rep = np.repeat(np.arange(scan.size), lens)
    within = np.arange(lens.sum()) - np.repeat(np.cumsum(lens) - lens, lens)
    beam = first[rep] + within
    pose = sensor_poses[scan[rep]]
    a = pose[:, 2] + (angles[scan[rep], beam] if angles.ndim == 2 else angles[beam])
    m = centre[rep] - pose[:, :2]
    proj = np.cos(a) * m[:, 0] + np.sin(a) * m[:, 1]
    d2 = np.einsum("ij,ij->i", m, m) - proj * proj
    r2 = radius[rep] ** 2
    exp = np.where(d2 <= r2, proj - np.sqrt(np.maximum(r2 - d2, 0.0)), np.inf)
    ok = np.abs(ranges[scan[rep], beam] - exp) <= tol
    return np.bincount(rep, weights=ok, minlength=scan.size) / lens


def label_log(
    log: SensorLog,
    sensor_poses: np.ndarray,
    lm_ids: np.ndarray,
    lm_xy: np.ndarray,
    lm_r: np.ndarray,
    params: CircleDetectorParams,
    *,
    gate: float,
    k_sigma: float,
) -> Labelled:
    """Detect, associate and ray-trace one laser log. sensor_poses (S, 3) world frame, one per scan."""
    if log.scans is None or log.sensor is None:
        raise DataError(f"log {log.name!r} has no laser scans")
    if log.sensor.range_sigma is None:
        raise DataError(f"log {log.name!r}: the sensor model has no range_sigma; pass --range-sigma")
    ang = log.scan_angles()  # (B,), or (S, B) for a laser of several beam layouts
    det = run_detector(log, DetectConfig(detector=params), label="detecting circles")
    sp = sensor_poses[det.scan]
    world = compose(sp, np.column_stack([det.x, det.y, np.zeros(len(det))]))
    tol = k_sigma * log.sensor.range_sigma

    def on_landmark(i: np.ndarray, j: np.ndarray) -> np.ndarray:
        return support(log.scans.ranges, ang, sensor_poses, det.scan[i], det.first[i], det.last[i], lm_xy[j], lm_r[j], tol) >= MIN_SUPPORT

    lm_of, dist = associate(det.scan, world[:, :2], lm_xy, gate, on_landmark)
    dets = detections_table(log, det).drop(columns=["frame", "maha2"])
    dets = dets.assign(
        world_x=world[:, 0],
        world_y=world[:, 1],
        landmark=np.where(lm_of >= 0, lm_ids[np.maximum(lm_of, 0)], -1),
        landmark_index=lm_of,
        distance=dist,
    )
    n_p, n_exp = _ray_trace(log, sensor_poses, ang, lm_xy, lm_r, k_sigma)
    rel = lm_xy[None, :, :] - sensor_poses[:, None, :2]
    rng = np.hypot(rel[..., 0], rel[..., 1])
    reach = np.inf if log.sensor.range_max is None else log.sensor.range_max
    s_idx, l_idx = np.nonzero(rng <= reach)
    det_of_pair = np.full(rng.shape, -1, dtype=np.int64)
    hit = lm_of >= 0
    det_of_pair[det.scan[hit], lm_of[hit]] = np.flatnonzero(hit)
    bearing = np.arctan2(rel[..., 1], rel[..., 0]) - sensor_poses[:, None, 2]
    pairs = pd.DataFrame(
        {
            "scan": s_idx,
            "landmark": lm_ids[l_idx],
            "landmark_index": l_idx,
            "n_p": n_p[s_idx, l_idx],
            "n_expected": n_exp[s_idx, l_idx],
            "range": rng[s_idx, l_idx],
            "bearing": np.mod(bearing[s_idx, l_idx] + np.pi, 2 * np.pi) - np.pi,
            "det": det_of_pair[s_idx, l_idx],
        }
    )
    return Labelled(dets, pairs)


def _ray_trace(log: SensorLog, sensor_poses: np.ndarray, ang: np.ndarray, lm_xy: np.ndarray, lm_r: np.ndarray, k_sigma: float):
    """n_p and expected hits (S, L) of every (scan, landmark) pair (:func:`detectors.raytrace.count_unoccluded`), in
    runs of scans so that a terminal shows a bar (each scan is traced on its own: the runs change nothing)."""
    from calib.progress import progress

    n = sensor_poses.shape[0]
    runs = [slice(a, min(a + _TRACE_RUN, n)) for a in range(0, n, _TRACE_RUN)]
    parts = [
        count_unoccluded(
            sensor_poses[r], ang[r] if ang.ndim == 2 else ang, log.scans.ranges[r], lm_xy, lm_r,
            range_sigma=log.sensor.range_sigma, k_sigma=k_sigma, range_max=log.sensor.range_max,
        )  # fmt: skip
        for r in progress(runs, len(runs), "ray tracing")
    ]
    if not parts:
        return count_unoccluded(sensor_poses, ang, log.scans.ranges, lm_xy, lm_r, range_sigma=log.sensor.range_sigma, k_sigma=k_sigma)
    return np.concatenate([p[0] for p in parts]), np.concatenate([p[1] for p in parts])


#: scans traced per step of the ray tracer's progress bar
_TRACE_RUN = 200
