"""Ground truth from the scans themselves: 2D point-to-line ICP and a pose graph (thesis sec. 5.3.3).

1. **Dead reckoning** gives every scan an initial pose (:func:`odometry_poses`).
2. **Sequential registration**: each scan is aligned to a local map made of
   the last ``window`` registered keyframes, by point-to-line ICP (nearest map
   point by ``scipy.spatial.cKDTree``, residual along the map point's normal,
   Cauchy-weighted Gauss-Newton on (x, y, theta)), started from the previous
   registered pose composed with the odometry increment.
3. **Loop closures**: every ``loop_every`` keyframes, the keyframe nearest in
   space among those at least ``loop_gap`` keyframes older is looked up; the
   scan is aligned to that older neighbourhood and the match is accepted when
   enough points agree closely.
4. **Pose graph**: keyframe poses are optimised over sequential and loop edges
   with ``scipy.optimize.least_squares`` (sparse Jacobian); the scans between
   keyframes follow their keyframe.

Poses are in the frame of the first scan's vehicle pose (the origin, heading 0)
unless an ``origin`` is given.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from pydantic import BaseModel, ConfigDict, Field
from scipy.optimize import least_squares
from scipy.sparse import lil_matrix
from scipy.spatial import cKDTree

from detectors.geometry import compose, interpolate_poses, relative, rigid_align  # noqa: F401  (re-exported)
from detectors.sensor_log import SensorLog
from profiles.errors import DataError


class IcpConfig(BaseModel):
    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)
    max_corr: float = Field(default=1.0, gt=0.0, description="largest point-map distance used at the first iteration [m]")
    min_corr: float = Field(default=0.3, gt=0.0, description="the distance it shrinks to [m]")
    cauchy: float = Field(default=0.05, gt=0.0, description="scale of the Cauchy weights [m]")
    iterations: int = Field(default=25, ge=1)
    window: int = Field(default=80, ge=1, description="keyframes in the local map")
    keyframe_dist: float = Field(default=1.0, ge=0.0, description="travel [m] (or 0.1 rad of turn) that makes a new keyframe")
    normal_gap: float = Field(default=0.5, gt=0.0, description="neighbouring returns farther apart give no normal [m]")
    max_range: float | None = Field(default=None, gt=0.0, description="ignore returns beyond this [m]")
    loop_radius: float = Field(default=4.0, gt=0.0, description="search radius for loop closures [m]")
    loop_gap: int = Field(default=50, ge=1, description="keyframes between the two ends of a loop, at least")
    loop_every: int = Field(default=3, ge=1)
    loop_max_corr: float = Field(default=2.0, gt=0.0, description="first correspondence distance of a loop alignment [m]")
    loop_headings: list[float] = Field(default=[0.0, -0.2, 0.2, -0.4, 0.4], description="heading offsets tried for a loop [rad]")
    loop_min_overlap: float = Field(default=0.3, gt=0.0, le=1.0, description="share of the scan's points with a map point within max_corr")
    loop_min_agreement: float = Field(default=0.8, gt=0.0, le=1.0, description="share of those within 3 x cauchy after alignment")
    rounds: int = Field(default=2, ge=1, description="loop search + graph optimisation rounds")


@dataclass
class IcpResult:
    poses: np.ndarray  # (S, 3) vehicle poses per scan
    keyframes: np.ndarray  # (K,) scan indices
    loops: list[tuple[int, int]] = field(default_factory=list)  # keyframe index pairs
    odometry: np.ndarray | None = None  # (S, 3) dead-reckoning poses


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
        # compose all increments at once: heading is their running sum, and each
        # translation is rotated by the heading before it
        inc = o.values
        th = np.concatenate([[0.0], np.cumsum(inc[:, 2])])
        c, s = np.cos(th[:-1]), np.sin(th[:-1])
        x = np.concatenate([[0.0], np.cumsum(c * inc[:, 0] - s * inc[:, 1])])
        y = np.concatenate([[0.0], np.cumsum(s * inc[:, 0] + c * inc[:, 1])])
        path = np.column_stack([x, y, np.mod(th + np.pi, 2 * np.pi) - np.pi])
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


def align(src: np.ndarray, tree: cKDTree, mp: np.ndarray, mn: np.ndarray, init: np.ndarray, cfg: IcpConfig):
    """Point-to-line ICP of sensor-frame points ``src`` to a world map.

    returns (pose, overlap, agreement, H): overlap is the share of points with a map
    point within ``max_corr``, agreement the share of those within 3 x ``cauchy``.

    Residual r_i = n_q . (R p_i + t - q); Gauss-Newton on (x, y, theta) with Cauchy weights.
    """
    pose = init.astype(np.float64).copy()
    h = np.zeros((3, 3))
    corr = cfg.max_corr
    for it in range(cfg.iterations):
        w = _to_world(pose, src)
        d, idx = tree.query(w, distance_upper_bound=corr)
        ok = np.isfinite(d)
        if ok.sum() < 6:
            return pose, 0.0, 0.0, h
        q, n, pw, ps = mp[idx[ok]], mn[idx[ok]], w[ok], src[ok]
        # map points without a normal (isolated far returns) act point-to-point: the
        # residual's own direction serves as the normal
        diff = pw - q
        free = ~np.isfinite(n[:, 0])
        if free.any():
            n = n.copy()
            n[free] = diff[free] / np.maximum(np.hypot(diff[free, 0], diff[free, 1]), 1e-9)[:, None]
        r = np.einsum("ij,ij->i", diff, n)
        wt = 1.0 / (1.0 + (r / cfg.cauchy) ** 2)
        c, s = np.cos(pose[2]), np.sin(pose[2])
        dth = np.column_stack([-s * ps[:, 0] - c * ps[:, 1], c * ps[:, 0] - s * ps[:, 1]])
        j = np.column_stack([n[:, 0], n[:, 1], np.einsum("ij,ij->i", n, dth)])
        h = (j * wt[:, None]).T @ j
        g = (j * wt[:, None]).T @ r
        try:
            step = -np.linalg.solve(h + 1e-9 * np.eye(3), g)
        except np.linalg.LinAlgError:
            return pose, 0.0, 0.0, h
        pose += step
        corr = max(cfg.min_corr, corr * 0.7)
        if np.abs(step[:2]).max() < 1e-5 and abs(step[2]) < 1e-6 and it > 2:
            break
    w = _to_world(pose, src)
    d, _ = tree.query(w, distance_upper_bound=cfg.max_corr)
    near = np.isfinite(d)
    overlap = float(near.mean())
    agreement = float(np.mean(d[near] < 3 * cfg.cauchy)) if near.any() else 0.0
    pose[2] = np.mod(pose[2] + np.pi, 2 * np.pi) - np.pi
    return pose, overlap, agreement, h


class _Map:
    """World-frame points with normals of a set of keyframes."""

    def __init__(self, pts: list[np.ndarray], nrm: list[np.ndarray]):
        self.p = np.vstack(pts) if pts else np.zeros((0, 2))
        self.n = np.vstack(nrm) if nrm else np.zeros((0, 2))
        self.tree = cKDTree(self.p) if self.p.shape[0] else None


def icp_ground_truth(
    log: SensorLog, cfg: IcpConfig | None = None, origin: np.ndarray | None = None, progress=None
) -> IcpResult:
    """Vehicle poses (S, 3) for every scan of ``log`` from sequential ICP, loop closures and a pose graph."""
    cfg = cfg or IcpConfig()
    if log.scans is None or log.sensor is None:
        raise DataError(f"log {log.name!r} has no laser scans to align")
    mount = np.array([log.sensor.mount.x, log.sensor.mount.y, log.sensor.mount.theta])
    odo = odometry_poses(log)
    n = len(log.scans)
    pts, nrm = [], []
    ang = log.scan_angles()  # (B,), or (S, B) for a laser of several beam layouts
    for k in range(n):  # per-scan geometry, cheap; kept for the loop search
        p, q = scan_points(log.scans.ranges[k], ang[k] if ang.ndim == 2 else ang, cfg.normal_gap, cfg.max_range)
        # points and normals in the vehicle frame
        pv = _to_world(mount, p, q)
        pts.append(pv[0])
        nrm.append(pv[1])
    est = np.zeros((n, 3))
    est[0] = odo[0]
    keys: list[int] = [0]
    edges: list[tuple[int, int, np.ndarray, np.ndarray]] = []  # (keyframe a, keyframe b, measured rel, information)
    world_p = {0: _to_world(est[0], pts[0], nrm[0])}
    loc = _Map([world_p[0][0]], [world_p[0][1]])
    it = range(1, n) if progress is None else progress(range(1, n), n - 1, "aligning scans")
    for k in it:
        guess = compose(est[k - 1], relative(odo[k - 1], odo[k]))
        if loc.tree is not None and pts[k].shape[0] >= 6:
            pose, overlap, agree, h = align(pts[k], loc.tree, loc.p, loc.n, guess, cfg)
            est[k] = pose if overlap * agree > 0.3 else guess
        else:
            est[k] = guess
        last = keys[-1]
        moved = relative(est[last], est[k])
        if np.hypot(moved[0], moved[1]) >= cfg.keyframe_dist or abs(moved[2]) >= 0.1 or k == n - 1:
            info = _information(h if loc.tree is not None else None, cfg.cauchy)
            edges.append((len(keys) - 1, len(keys), moved, info))
            keys.append(k)
            world_p[k] = _to_world(est[k], pts[k], nrm[k])
            recent = keys[-cfg.window :]
            loc = _Map([world_p[j][0] for j in recent], [world_p[j][1] for j in recent])
    kf = np.array(keys)
    kpose = est[kf].copy()
    loops: list[tuple[int, int]] = []
    for _ in range(cfg.rounds):
        new = _find_loops(kf, kpose, pts, nrm, cfg, {(a, b) for a, b in loops})
        for a, b, rel_ab, info in new:
            edges.append((a, b, rel_ab, info))
            loops.append((a, b))
        if not new:
            break
        kpose = _optimise(kpose, edges)
    # scans between keyframes keep their pose relative to the previous keyframe
    owner = np.searchsorted(kf, np.arange(n), side="right") - 1
    poses = compose(kpose[owner], relative(est[kf][owner], est))
    if origin is not None:
        poses = compose(np.asarray(origin, dtype=np.float64), poses)
    return IcpResult(poses, kf, loops, odo)


def _information(h: np.ndarray | None, sigma: float) -> np.ndarray:
    """Information of a registration, H / sigma^2 (Gauss-Newton, residual scale sigma).

    Optimistic in absolute terms (map errors are correlated), but the same for
    every edge, so the pose graph weighs sequential and loop edges consistently.
    """
    if h is None or not np.isfinite(h).all() or np.linalg.eigvalsh(h).min() <= 0:
        return np.diag([1.0, 1.0, 10.0]) / sigma**2
    return h / sigma**2


def _find_loops(kf, kpose, pts, nrm, cfg: IcpConfig, known: set):
    found = []
    tree = cKDTree(kpose[:, :2])
    for a in range(0, kf.size, cfg.loop_every):
        cands = [b for b in tree.query_ball_point(kpose[a, :2], cfg.loop_radius) if a - b >= cfg.loop_gap]
        if not cands:
            continue
        b = min(cands, key=lambda j: np.hypot(*(kpose[j, :2] - kpose[a, :2])))
        if (b, a) in known:
            continue
        lo, hi = max(0, b - cfg.window // 2), min(kf.size, b + cfg.window // 2 + 1)
        sub = [_to_world(kpose[j], pts[kf[j]], nrm[kf[j]]) for j in range(lo, hi)]
        m = _Map([s[0] for s in sub], [s[1] for s in sub])
        if m.tree is None or pts[kf[a]].shape[0] < 6:
            continue
        wide = cfg.model_copy(update={"max_corr": cfg.loop_max_corr})
        best = None
        for dth in cfg.loop_headings:  # drift may have turned the scan: try a few headings, keep the best fit
            cand = align(pts[kf[a]], m.tree, m.p, m.n, kpose[a] + np.array([0.0, 0.0, dth]), wide)
            if best is None or cand[1] * cand[2] > best[1] * best[2]:
                best = cand
        pose, overlap, agree, h = best
        if overlap >= cfg.loop_min_overlap and agree >= cfg.loop_min_agreement:
            found.append((b, a, relative(kpose[b], pose), _information(h, cfg.cauchy)))
    return found


def _optimise(x0: np.ndarray, edges) -> np.ndarray:
    """Least-squares pose graph over keyframes; the first keyframe is held fixed."""
    k = x0.shape[0]
    a = np.array([e[0] for e in edges])
    b = np.array([e[1] for e in edges])
    z = np.array([e[2] for e in edges])
    sq = np.array([np.linalg.cholesky(e[3] + 1e-9 * np.eye(3)).T for e in edges])  # L^T with L L^T = info

    def resid(flat):
        x = np.vstack([x0[:1], flat.reshape(-1, 3)])
        e = relative(x[a], x[b]) - z
        e[:, 2] = np.mod(e[:, 2] + np.pi, 2 * np.pi) - np.pi
        return np.einsum("kij,kj->ki", sq, e).ravel()

    sparsity = lil_matrix((3 * len(edges), 3 * (k - 1)), dtype=np.int8)
    for r, (i, j) in enumerate(zip(a, b, strict=True)):  # the Jacobian's pattern: one 3x3 block per end
        for node in (i, j):
            if node > 0:
                sparsity[3 * r : 3 * r + 3, 3 * (node - 1) : 3 * node] = 1
    sol = least_squares(resid, x0[1:].ravel(), jac_sparsity=sparsity.tocsr(), method="trf", x_scale="jac", max_nfev=50)
    x = np.vstack([x0[:1], sol.x.reshape(-1, 3)])
    x[:, 2] = np.mod(x[:, 2] + np.pi, 2 * np.pi) - np.pi
    return x


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
