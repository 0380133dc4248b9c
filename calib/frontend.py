"""Scan-to-map registration: the front end of the ground truth (:mod:`calib.mapping`).

Every scan is placed on a local map made of the last ``local_keyframes``
keyframes, in two steps:

1. a **correlative search** (:func:`calib.raster.correlative_match`) over a
   window around the odometry prediction on the local map's likelihood field,
   with a mild motion prior so that, where the scan cannot tell poses apart (a
   corridor's axis), the one nearest the prediction wins;
2. **ICP refinement** (:func:`calib.icp.align`) point-to-line against the
   local map's points, which resolves the raster's cell to millimetres; it
   starts from the correlative pose when that scores clearly better
   (``search_gain``) than the prediction, else from the prediction.

A scan whose best score stays below ``min_score`` is searched again in a wide
window without the prior (``recovery_*``): odometry that jumped (a wheel slip,
a kidnapped robot, a gap in the log) puts the prediction outside the small
window, and the wide search finds the scan's place on the map again.

A new keyframe is made after ``keyframe_dist`` metres or ``keyframe_turn``
radians; the local map is rebuilt then. Keyframes are the nodes of the pose
graph; the scans between them keep their pose relative to the keyframe before.

Frames: scan points are in the vehicle frame (the sensor mount applied);
poses are vehicle poses in the world frame, which is the first scan's
dead-reckoning frame.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from pydantic import BaseModel, ConfigDict, Field
from scipy.spatial import cKDTree

from calib.icp import Fit, IcpConfig, _to_world, align, scan_points
from calib.raster import LikelihoodField, correlative_match, voxel_filter
from detectors.geometry import compose, relative
from detectors.sensor_log import SensorLog


class FrontEndConfig(BaseModel):
    """Scan-to-map registration settings (see the module docstring)."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)
    resolution: float = Field(default=0.05, gt=0.0, description="raster cell of the likelihood field [m]")
    sigma: float = Field(default=0.05, gt=0.0, description="spread of the likelihood field around a map point [m]")
    max_range: float | None = Field(default=30.0, gt=0.0, description="returns beyond this are not matched [m]")
    voxel: float = Field(default=0.1, gt=0.0, description="the correlative search uses one point per square of this side [m]")
    linear_window: float = Field(default=0.3, gt=0.0, description="half-width of the translations searched around the prediction [m]")
    angular_window: float = Field(default=0.2, gt=0.0, description="half-width of the headings searched [rad]")
    translation_cost: float = Field(default=0.5, ge=0.0, description="motion prior of the search, score per m^2 from the prediction")
    rotation_cost: float = Field(default=0.5, ge=0.0, description="the same per rad^2")
    min_score: float = Field(default=0.45, gt=0.0, lt=1.0, description="a scan scoring less is searched again in the recovery window")
    recovery_linear_window: float = Field(default=3.0, gt=0.0, description="half-width of the recovery search [m]")
    recovery_angular_window: float = Field(default=0.8, gt=0.0, description="half-width of the recovery search's headings [rad]")
    recovery_gain: float = Field(default=0.1, gt=0.0, description="score a recovered pose must gain over the small window's best")
    search_gain: float = Field(
        default=0.05, ge=0.0, description="score the search's pose must gain over the prediction's to be where ICP starts"
    )
    min_fitness: float = Field(default=0.5, gt=0.0, le=1.0, description="ICP fitness (overlap x agreement) below which ICP's pose is not used")
    keyframe_dist: float = Field(default=0.5, ge=0.0, description="travel that makes a new keyframe [m]")
    keyframe_turn: float = Field(default=0.1, gt=0.0, description="turn that makes a new keyframe [rad]")
    local_keyframes: int = Field(default=40, ge=1, description="keyframes in the local map")
    min_points: int = Field(default=20, ge=6, description="a scan with fewer returns is placed by odometry alone")


@dataclass
class ScanGeometry:
    """Points (vehicle frame) and normals of every scan, computed once (the cheap part of a registration)."""

    points: list[np.ndarray]  # per scan (N_k, 2) [m], vehicle frame
    normals: list[np.ndarray]  # per scan (N_k, 2) unit normals, NaN where the neighbours are too far
    origin: np.ndarray  # (2,) the sensor's position in the vehicle frame [m]: where every beam starts

    @classmethod
    def of(cls, log: SensorLog, icp: IcpConfig, max_range: float | None) -> ScanGeometry:
        mount = np.array([log.sensor.mount.x, log.sensor.mount.y, log.sensor.mount.theta])
        ang = log.scan_angles()  # (B,), or (S, B) for a laser of several beam layouts
        pts, nrm = [], []
        for k in range(len(log.scans)):
            p, q = scan_points(log.scans.ranges[k], ang[k] if ang.ndim == 2 else ang, icp.normal_gap, max_range)
            pv, nv = _to_world(mount, p, q)
            pts.append(pv)
            nrm.append(nv)
        return cls(pts, nrm, mount[:2].copy())


@dataclass
class FrontEnd:
    """What the front end made of a log.

    poses: (S, 3) vehicle poses, world frame; keyframes: (K,) scan indices (first scan included).
    Per scan (S,): ``score`` the correlative score (NaN where no search ran), ``fitness`` and ``rms`` of the
    ICP refinement (0 and inf where none), ``recovered`` placed by the recovery search, ``registered``
    placed on the map at all (False: dead reckoning).
    """

    poses: np.ndarray
    keyframes: np.ndarray
    score: np.ndarray
    fitness: np.ndarray
    rms: np.ndarray
    recovered: np.ndarray
    registered: np.ndarray


class LocalMap:
    """World points, normals, k-d tree and likelihood field of a set of keyframes."""

    def __init__(self, pts: np.ndarray, nrm: np.ndarray, resolution: float, sigma: float, depth: int):
        self.p, self.n = pts, nrm
        self.tree = cKDTree(pts)
        self.field = LikelihoodField.from_points(pts, resolution, sigma, depth=depth)

    @classmethod
    def of(
        cls, geo: ScanGeometry, scans, poses: np.ndarray, resolution: float, sigma: float, depth: int, centre=None, radius=None
    ) -> LocalMap | None:
        """The map of scans ``scans`` at vehicle poses (n, 3), points within ``radius`` of ``centre`` only (when given)."""
        ps, ns = [], []
        for k, pose in zip(scans, poses, strict=True):
            w, n = _to_world(pose, geo.points[k], geo.normals[k])
            ps.append(w)
            ns.append(n)
        if not ps:
            return None
        p, n = np.vstack(ps), np.vstack(ns)
        if centre is not None and radius is not None:
            near = np.hypot(p[:, 0] - centre[0], p[:, 1] - centre[1]) <= radius
            p, n = p[near], n[near]
        return cls(p, n, resolution, sigma, depth) if p.shape[0] >= 6 else None


def depth_for(window: float, resolution: float) -> int:
    """Levels the branch and bound needs for a window of +-``window`` metres."""
    w = int(np.ceil(window / resolution))
    return int(np.ceil(np.log2(2 * w + 1))) if w > 0 else 0


def register_scan(
    geo: ScanGeometry, k: int, guess: np.ndarray, local: LocalMap, cfg: FrontEndConfig, icp: IcpConfig
) -> tuple[np.ndarray, float, Fit | None, bool]:
    """Pose of scan ``k`` on ``local`` from the prediction ``guess``: (pose, correlative score, ICP fit, recovered)."""
    pts = geo.points[k]
    cp = voxel_filter(pts, cfg.voxel)
    m = correlative_match(
        local.field, cp, guess, cfg.linear_window, cfg.angular_window,
        translation_cost=cfg.translation_cost, rotation_cost=cfg.rotation_cost,
    )  # fmt: skip
    recovered = False
    if m is None or m.score < cfg.min_score:
        deep = local.field.deepened(depth_for(cfg.recovery_linear_window, cfg.resolution))
        wide = correlative_match(deep, cp, guess, cfg.recovery_linear_window, cfg.recovery_angular_window, min_score=cfg.min_score)
        if wide is not None and (m is None or wide.score >= m.score + cfg.recovery_gain):
            m, recovered = wide, True
    if m is None:
        return guess, float("nan"), None, False
    # ICP starts at the search's pose when it is clearly better than the prediction, and its prior stays at
    # the prediction unless the prediction was wrong: a scan matched to a sparse map (one or two scans) scores
    # best where the map's own scans were, which is not where the vehicle went
    start = m.pose if recovered or m.score >= local.field.score(_to_world(guess, cp)) + cfg.search_gain else guess
    pose, fit = align(pts, local.tree, local.p, local.n, start, icp, prior_at=m.pose if recovered else guess)
    if fit.fitness < cfg.min_fitness:
        return (m.pose if m.score >= cfg.min_score else guess), m.score, fit, recovered and m.score >= cfg.min_score
    return pose, m.score, fit, recovered


def run_front_end(
    log: SensorLog, odo: np.ndarray, geo: ScanGeometry, cfg: FrontEndConfig, icp: IcpConfig, progress: Callable | None = None
) -> FrontEnd:
    """Register every scan of ``log`` in turn (see the module docstring); ``odo`` (S, 3) dead reckoning."""
    n = odo.shape[0]
    est = np.zeros((n, 3))
    est[0] = odo[0]
    score = np.full(n, np.nan)
    fitness = np.zeros(n)
    rms = np.full(n, np.inf)
    recovered = np.zeros(n, dtype=bool)
    registered = np.zeros(n, dtype=bool)
    registered[0] = True
    keys = [0]
    depth = depth_for(cfg.linear_window, cfg.resolution)
    radius = (cfg.max_range or 80.0) + cfg.recovery_linear_window + 1.0

    def rebuild() -> LocalMap | None:
        recent = keys[-cfg.local_keyframes :]
        return LocalMap.of(geo, recent, est[recent], cfg.resolution, cfg.sigma, depth, centre=est[keys[-1]], radius=radius)

    local = rebuild()
    it = range(1, n) if progress is None else progress(range(1, n), n - 1, "registering scans")
    for k in it:
        guess = compose(est[k - 1], relative(odo[k - 1], odo[k]))
        if local is None or geo.points[k].shape[0] < cfg.min_points:
            est[k] = guess
        else:
            est[k], score[k], fit, recovered[k] = register_scan(geo, k, guess, local, cfg, icp)
            registered[k] = not np.isnan(score[k]) and score[k] >= cfg.min_score
            if fit is not None:
                fitness[k], rms[k] = fit.fitness, fit.rms
        moved = relative(est[keys[-1]], est[k])
        if np.hypot(moved[0], moved[1]) >= cfg.keyframe_dist or abs(moved[2]) >= cfg.keyframe_turn or k == n - 1:
            keys.append(k)
            local = rebuild()
    return FrontEnd(est, np.array(keys), score, fitness, rms, recovered, registered)
