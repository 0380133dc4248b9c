"""Point-to-line ICP in 2D, dead reckoning, and benchmark relations (thesis sec. 5.3.3).

- :func:`odometry_poses`: dead-reckoning vehicle poses at the scan stamps, the start of every registration.
- :func:`scan_points`: a scan's returns and their normals in the sensor frame.
- :func:`align`: point-to-line ICP of a scan to a map (nearest map point by
  ``scipy.spatial.cKDTree``, residual along the map point's normal,
  Cauchy-weighted Gauss-Newton on (x, y, theta) with a prior on the start pose),
  the refinement step after every correlative match (:mod:`calib.raster`).
- :func:`icp_ground_truth`: the ground truth of a log, built by
  :mod:`calib.mapping` (scan-to-map front end, verified loop closures, robust
  pose graph).
- :func:`read_relations`, :func:`relation_errors`: the benchmark relations of
  Kümmerle et al. 2009 and the error of a trajectory against them.

Poses are in the frame of the first scan's vehicle pose (the origin, heading 0)
unless an ``origin`` is given.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from pydantic import BaseModel, ConfigDict, Field
from scipy.spatial import cKDTree

from detectors.geometry import compose, increment_poses, interpolate_poses, relative, rigid_align  # noqa: F401  (re-exported)
from detectors.sensor_log import SensorLog
from profiles.errors import DataError


class IcpConfig(BaseModel):
    """Point-to-line ICP, the refinement step of every registration (sequential and loop closures)."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)
    max_corr: float = Field(default=0.5, gt=0.0, description="largest point-map distance used at the first iteration [m]")
    min_corr: float = Field(default=0.2, gt=0.0, description="the distance it shrinks to [m]")
    cauchy: float = Field(default=0.03, gt=0.0, description="scale of the Cauchy weights, about the laser's range noise [m]")
    iterations: int = Field(default=30, ge=1)
    normal_gap: float = Field(default=0.5, gt=0.0, description="neighbouring returns farther apart give no normal [m]")
    prior_xy: float = Field(
        default=0.1, gt=0.0, description="spread [m] of the prior on the start pose: it holds the directions a scan cannot fix (a corridor's axis)"
    )
    prior_theta: float = Field(default=0.05, gt=0.0, description="the same for the heading [rad]")


@dataclass
class IcpResult:
    """Ground truth of one log: vehicle poses per scan and what the registration saw (:mod:`calib.mapping`)."""

    poses: np.ndarray  # (S, 3) vehicle poses per scan, world frame
    keyframes: np.ndarray  # (K,) scan indices of the keyframes (pose-graph nodes)
    loops: list[tuple[int, int]] = field(default_factory=list)  # accepted loop closures, keyframe index pairs (older, newer)
    odometry: np.ndarray | None = None  # (S, 3) dead-reckoning poses
    details: object | None = None  # calib.mapping.Registration: fitness, loop decisions, residuals (None for a bare result)


def odometry_poses(log: SensorLog) -> np.ndarray:
    """(S, 3) dead-reckoning vehicle poses at the scan stamps, starting at the origin."""
    if log.scans is None:
        raise DataError(f"log {log.name!r} has no scans")
    if log.scans.odom_pose is not None:
        p = log.scans.odom_pose
        return relative(p[0], p)
    o = log.odometry
    if o is None:
        raise DataError(f"log {log.name!r} has no odometry to start ICP from")
    if o.kind == "pose":
        path, stamp = o.values, o.stamp
    elif o.kind == "increment":
        path = np.vstack([np.zeros((1, 3)), increment_poses(o.values)])  # the origin, then after each increment
        stamp = np.concatenate([[o.stamp[0] - 1], o.stamp])
    elif o.kind == "velocity":
        dt = np.diff(o.stamp, prepend=o.stamp[0]) / 1e9
        v, w = o.values[:, 0], o.values[:, 1]
        th = np.concatenate([[0.0], np.cumsum(w[:-1] * dt[1:])])
        x = np.concatenate([[0.0], np.cumsum(v[:-1] * np.cos(th[:-1]) * dt[1:])])
        y = np.concatenate([[0.0], np.cumsum(v[:-1] * np.sin(th[:-1]) * dt[1:])])
        path, stamp = np.column_stack([x, y, th]), o.stamp
    else:
        raise DataError(f"odometry of kind {o.kind!r} is not supported for ICP initialisation")
    p = interpolate_poses(stamp, path, log.scans.stamp)
    return relative(p[0], p)


def scan_points(ranges: np.ndarray, angles: np.ndarray, normal_gap: float, max_range: float | None):
    """Points (N, 2) of one scan in the sensor frame and their normals (N, 2) (NaN where none).

    ranges (B,), angles (B,) (a NaN angle, past the scan's own beams, is no return).
    """
    r = ranges.astype(np.float64)
    if max_range is not None:
        r = np.where(r <= max_range, r, np.nan)
    x, y = r * np.cos(angles), r * np.sin(angles)
    p = np.column_stack([x, y])
    prev, nxt = np.roll(p, 1, axis=0), np.roll(p, -1, axis=0)
    prev[0], nxt[-1] = np.nan, np.nan
    t = nxt - prev
    ok = (np.hypot(*(p - prev).T) < normal_gap) & (np.hypot(*(nxt - p).T) < normal_gap)
    n = np.column_stack([-t[:, 1], t[:, 0]])
    n /= np.maximum(np.hypot(n[:, 0], n[:, 1]), 1e-12)[:, None]
    n[~ok] = np.nan
    valid = np.isfinite(p[:, 0])
    return p[valid], n[valid]


def _to_world(pose: np.ndarray, p: np.ndarray, n: np.ndarray | None = None):
    c, s = np.cos(pose[2]), np.sin(pose[2])
    rot = np.array([[c, -s], [s, c]])
    w = p @ rot.T + pose[:2]
    return w if n is None else (w, n @ rot.T)


@dataclass(frozen=True)
class Fit:
    """How well a scan sits on a map after ICP.

    overlap: share of the scan's points with a map point within ``max_corr``;
    agreement: share of those within 3 x ``cauchy``; rms [m]: point-to-line residual of the agreeing points;
    information: (3, 3) Gauss-Newton information of (x, y, theta), sum of w J^T J / cauchy^2 (no prior).
    """

    overlap: float
    agreement: float
    rms: float
    information: np.ndarray

    @property
    def fitness(self) -> float:
        """overlap x agreement, 0..1: the share of the scan that lies on the map."""
        return self.overlap * self.agreement


_NO_FIT = Fit(0.0, 0.0, float("inf"), np.zeros((3, 3)))


def align(
    src: np.ndarray,
    tree: cKDTree,
    mp: np.ndarray,
    mn: np.ndarray,
    init: np.ndarray,
    cfg: IcpConfig,
    prior: bool = True,
    prior_at: np.ndarray | None = None,
) -> tuple[np.ndarray, Fit]:
    """Point-to-line ICP of vehicle-frame points ``src`` (N, 2) to a world map (points ``mp``, normals ``mn``, (M, 2)).

    Residual r_i = n_q . (R p_i + t - q), nearest map point q; Gauss-Newton on (x, y, theta) with Cauchy
    weights w_i = 1 / (1 + (r_i / c)^2), started at ``init``. With ``prior`` the pose ``prior_at`` (default
    ``init``) is a Gaussian prior (``prior_xy``, ``prior_theta``): it decides the directions the scan leaves
    free (a corridor's axis), where plain Gauss-Newton would wander. Returns (pose (3,), :class:`Fit`).
    """
    pose = init.astype(np.float64).copy()
    centre = init if prior_at is None else np.asarray(prior_at, dtype=np.float64)
    lam = np.diag([cfg.prior_xy**-2, cfg.prior_xy**-2, cfg.prior_theta**-2]) if prior else np.zeros((3, 3))
    corr = cfg.max_corr
    for it in range(cfg.iterations):
        w = _to_world(pose, src)
        d, idx = tree.query(w, distance_upper_bound=corr)
        ok = np.isfinite(d)
        if ok.sum() < 6:
            return pose, _NO_FIT
        q, n, pw, ps = mp[idx[ok]], mn[idx[ok]], w[ok], src[ok]
        # map points without a normal (isolated far returns) act point-to-point: the
        # residual's own direction serves as the normal
        diff = pw - q
        free = ~np.isfinite(n[:, 0])
        if free.any():
            n = n.copy()
            n[free] = diff[free] / np.maximum(np.hypot(diff[free, 0], diff[free, 1]), 1e-9)[:, None]
        r = np.einsum("ij,ij->i", diff, n)
        wt = 1.0 / (1.0 + (r / cfg.cauchy) ** 2) / cfg.cauchy**2
        c, s = np.cos(pose[2]), np.sin(pose[2])
        dth = np.column_stack([-s * ps[:, 0] - c * ps[:, 1], c * ps[:, 0] - s * ps[:, 1]])
        j = np.column_stack([n[:, 0], n[:, 1], np.einsum("ij,ij->i", n, dth)])
        h = (j * wt[:, None]).T @ j
        off = pose - centre
        off[2] = np.mod(off[2] + np.pi, 2 * np.pi) - np.pi
        g = (j * wt[:, None]).T @ r + lam @ off
        try:
            step = -np.linalg.solve(h + lam + 1e-9 * np.eye(3), g)
        except np.linalg.LinAlgError:
            return pose, _NO_FIT
        pose += step
        corr = max(cfg.min_corr, corr * 0.7)
        if np.abs(step[:2]).max() < 1e-4 and abs(step[2]) < 1e-5 and corr <= cfg.min_corr:
            break
    pose[2] = np.mod(pose[2] + np.pi, 2 * np.pi) - np.pi
    return pose, fit_of(src, pose, tree, mp, mn, cfg)


def fit_of(src: np.ndarray, pose: np.ndarray, tree: cKDTree, mp: np.ndarray, mn: np.ndarray, cfg: IcpConfig) -> Fit:
    """:class:`Fit` of vehicle-frame points ``src`` placed at ``pose`` on the map (``max_corr`` gate)."""
    w = _to_world(pose, src)
    d, idx = tree.query(w, distance_upper_bound=cfg.max_corr)
    near = np.isfinite(d)
    if near.sum() < 6:
        return _NO_FIT
    n = mn[idx[near]]
    diff = w[near] - mp[idx[near]]
    free = ~np.isfinite(n[:, 0])
    n = np.where(free[:, None], diff / np.maximum(np.hypot(diff[:, 0], diff[:, 1]), 1e-9)[:, None], n)
    r = np.abs(np.einsum("ij,ij->i", diff, n))
    good = r < 3 * cfg.cauchy
    ps = src[near]
    c, s = np.cos(pose[2]), np.sin(pose[2])
    dth = np.column_stack([-s * ps[:, 0] - c * ps[:, 1], c * ps[:, 0] - s * ps[:, 1]])
    j = np.column_stack([n[:, 0], n[:, 1], np.einsum("ij,ij->i", n, dth)])[good]
    info = j.T @ j / cfg.cauchy**2
    return Fit(float(near.mean()), float(good.mean()), float(np.sqrt(np.mean(r[good] ** 2))) if good.any() else float("inf"), info)


def icp_ground_truth(
    log: SensorLog, cfg=None, origin: np.ndarray | None = None, progress=None
) -> IcpResult:
    """Vehicle poses (S, 3) for every scan of ``log``: scan-to-map registration, verified loop closures and a
    robust pose graph (:func:`calib.mapping.build_ground_truth`; ``cfg`` a :class:`calib.mapping.GroundTruthConfig`)."""
    from calib.mapping import build_ground_truth

    return build_ground_truth(log, cfg, origin=origin, progress=progress)


def read_relations(path) -> np.ndarray:
    """Benchmark relations (Kuemmerle et al. 2009): rows of t1, t2 [s] and the relative pose (x, y, yaw)."""
    from pathlib import Path

    from calib.io.common import read_table

    t = read_table(Path(path), 8, "t1 t2 x y z roll pitch yaw")
    if t.shape[0] == 0:
        raise DataError(f"{path}: holds no relations")
    return np.column_stack([t[:, 0], t[:, 1], t[:, 2], t[:, 3], t[:, 7]])


def relation_errors(stamps: np.ndarray, poses: np.ndarray, relations: np.ndarray, tol: float = 1e-3) -> tuple[np.ndarray, np.ndarray]:
    """Translational [m] and rotational [rad] error of every relation whose two stamps match a scan (within tol s).

    error = (relative(pose(t1), pose(t2))) (-) reference relation, as in Kuemmerle et al.
    """
    t = stamps / 1e9
    i1 = np.clip(np.searchsorted(t, relations[:, 0]), 1, t.size - 1)
    i1 = np.where(np.abs(t[i1 - 1] - relations[:, 0]) < np.abs(t[i1] - relations[:, 0]), i1 - 1, i1)
    i2 = np.clip(np.searchsorted(t, relations[:, 1]), 1, t.size - 1)
    i2 = np.where(np.abs(t[i2 - 1] - relations[:, 1]) < np.abs(t[i2] - relations[:, 1]), i2 - 1, i2)
    ok = (np.abs(t[i1] - relations[:, 0]) <= tol) & (np.abs(t[i2] - relations[:, 1]) <= tol)
    if not ok.any():
        raise DataError("no relation matches the scan stamps; are the relations for this log?")
    est = relative(poses[i1[ok]], poses[i2[ok]])
    err = relative(relations[ok, 2:5], est)
    return np.hypot(err[:, 0], err[:, 1]), np.abs(err[:, 2])
