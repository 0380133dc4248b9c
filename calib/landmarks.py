"""Landmark truth from the registered cloud (thesis sec. 5.3.3, automated).

The thesis picked tree trunks by hand out of an ICP-registered park cloud. Here
the circle detections of every scan are put in the world frame with the
ground-truth poses; detections of a convex, plausibly sized circle that recur
at the same place (within ``merge`` metres) in at least ``min_scans`` scans
become a landmark, whose centre and radius are the medians over its detections,
provided its centres agree from every viewpoint (a bush's fitted circle moves
with the viewpoint, a trunk's does not).

A caveat a user must weigh: landmarks found this way exist only where the
detector fired often enough, so trees it (almost) never detects are missing
and P_D is biased upwards for them. A surveyed or hand-checked CSV
(``--landmarks``) is better when there is one.
"""

from __future__ import annotations

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from calib.detect import DetectConfig, run_detector
from detectors.geometry import compose
from detectors.sensor_log import SensorLog
from profiles.errors import DataError
from profiles.parameters import CloudLandmarkConfig
from profiles.schema import CircleDetectorParams


def landmarks_from_cloud(
    log: SensorLog, sensor_poses: np.ndarray, params: CircleDetectorParams, cfg: CloudLandmarkConfig | None = None
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(ids (L,), xy (L, 2), radius (L,)) of the circles that recur across the scans."""
    cfg = cfg or CloudLandmarkConfig()
    det = run_detector(log, DetectConfig(detector=params), label="detecting circles for the cloud's landmarks")
    keep = (det.convexity > 0) & (det.radius >= cfg.min_radius) & (det.radius <= cfg.max_radius) & (det.n_points >= cfg.min_points)
    det = det.select(keep)
    if len(det) == 0:
        raise DataError(f"log {log.name!r}: no convex circles to build landmarks from")
    world = compose(sensor_poses[det.scan], np.column_stack([det.x, det.y, np.zeros(len(det))]))[:, :2]
    pairs = cKDTree(world).query_pairs(cfg.merge, output_type="ndarray")
    n = world.shape[0]
    graph = coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(n, n)) if len(pairs) else coo_matrix((n, n))
    _, comp = connected_components(graph, directed=False)
    scans_per = np.array([np.unique(det.scan[comp == c]).size for c in range(comp.max() + 1)])
    good = np.flatnonzero(scans_per >= cfg.min_scans)
    if good.size == 0:
        raise DataError(f"log {log.name!r}: no circle recurs in {cfg.min_scans} scans; lower min_scans")
    order = np.argsort(comp, kind="stable")
    bounds = np.searchsorted(comp[order], np.arange(comp.max() + 2))
    members = [order[bounds[c] : bounds[c + 1]] for c in good]
    xy = np.array([np.median(world[m], axis=0) for m in members])
    rad = np.array([np.median(det.radius[m]) for m in members])
    spread = np.array([np.median(np.hypot(*(world[m] - c).T)) for m, c in zip(members, xy, strict=True)])
    tight = spread <= cfg.max_spread
    if not tight.any():
        raise DataError(f"log {log.name!r}: no recurring circle is consistent across viewpoints")
    return np.arange(int(tight.sum()), dtype=np.int64), xy[tight], rad[tight]
