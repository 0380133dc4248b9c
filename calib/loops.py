"""Loop closures: candidates found near the current estimate, each verified geometrically.

For every ``every``-th keyframe (the *query*), the older keyframes within
``search_radius`` metres in the current estimate and at least ``min_gap``
keyframes back are looked up. They fall in *submaps*: runs of ``submap_step``
consecutive keyframes, each drawn with its neighbours (``map_keyframes`` on
either side) in the frame of its middle keyframe (the *anchor*). For the
nearest ``max_candidates`` submaps:

1. **correlative search** of the query scan on the submap's likelihood field
   by branch and bound (:func:`calib.raster.correlative_match`) over
   +-``linear_window`` and +-``angular_window`` around the estimate; a best
   score under ``min_score`` rejects (the place looks different);
2. **ICP refinement** (:func:`calib.icp.align`) from the correlative pose;
3. **checks**: overlap (share of the query's points near the submap) at least
   ``min_overlap``, agreement (share of those within 3 ICP sigmas) at least
   ``min_agreement``, residual rms at most ``max_rms``; and the match must
   fix every direction: the smallest eigenvalue of the translation block of
   the ICP information, relative to the largest, at least
   ``min_information_ratio`` (a corridor seen without its ends fixes no
   position along its axis, whatever the score); and at most
   ``max_see_through`` of the query's beams may pass through the submap's
   surfaces (:func:`calib.raster.see_through`). The likelihood field scores
   only where returns land, so a look-alike place (another room with the
   same furniture, a corridor shifted by one door) can score well; the free
   space the scan saw cannot be laid over the other place's walls.

A candidate that passes becomes a loop edge of the pose graph, whose robust
cost (:mod:`calib.posegraph`) still neutralises a wrong one that looked right
(a corridor like another). Each decision, accepted or not, is kept with its
figures and the reason.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from pydantic import BaseModel, ConfigDict, Field
from scipy.spatial import cKDTree

from calib.frontend import LocalMap, ScanGeometry, depth_for
from calib.icp import IcpConfig, _to_world, align
from calib.raster import correlative_match, see_through, voxel_filter
from detectors.geometry import relative


class LoopConfig(BaseModel):
    """Loop-closure search and verification settings (see the module docstring)."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)
    every: int = Field(default=2, ge=1, description="keyframes between two loop queries")
    min_gap: int = Field(default=40, ge=1, description="keyframes between the two ends of a loop, at least")
    search_radius: float = Field(default=10.0, gt=0.0, description="older keyframes within this of the query are candidates [m]")
    linear_window: float = Field(default=4.0, gt=0.0, description="half-width of the correlative search's translations [m]")
    angular_window: float = Field(default=0.6, gt=0.0, description="half-width of its headings [rad]")
    resolution: float = Field(default=0.1, gt=0.0, description="raster cell of the submaps' likelihood fields [m]")
    sigma: float = Field(default=0.1, gt=0.0, description="spread of those fields [m]")
    voxel: float = Field(default=0.1, gt=0.0, description="the search uses one query point per square of this side [m]")
    map_range: float = Field(default=20.0, gt=0.0, description="submap points farther than this from their anchor are left out [m]")
    submap_step: int = Field(default=10, ge=1, description="keyframes per submap")
    map_keyframes: int = Field(default=15, ge=0, description="keyframes drawn on either side of a submap's own")
    max_candidates: int = Field(default=2, ge=1, description="submaps tried per query, nearest first")
    min_score: float = Field(default=0.55, gt=0.0, lt=1.0, description="correlative score a loop needs")
    min_overlap: float = Field(default=0.6, gt=0.0, le=1.0, description="share of the query's points near the submap after ICP")
    min_agreement: float = Field(default=0.75, gt=0.0, le=1.0, description="share of those within 3 ICP sigmas")
    max_rms: float = Field(default=0.05, gt=0.0, description="rms point-to-line residual of the agreeing points [m]")
    min_information_ratio: float = Field(
        default=0.02, ge=0.0, le=1.0, description="smallest / largest eigenvalue of the match's translation information"
    )
    max_see_through: float = Field(
        default=0.3, ge=0.0, le=1.0, description="share of the query's beams that may pass through the submap's surfaces"
    )
    rounds: int = Field(default=3, ge=1, description="loop search + graph solve rounds")


@dataclass
class LoopDecision:
    """One verified (or refused) loop candidate: query keyframe, submap anchor keyframe, figures, verdict."""

    query: int
    anchor: int
    accepted: bool
    reason: str  # why it was refused ("" when accepted; the back end may still reject it: see calib.mapping)
    score: float = float("nan")
    overlap: float = float("nan")
    agreement: float = float("nan")
    rms: float = float("nan")
    information_ratio: float = float("nan")
    see_through: float = float("nan")
    rel: np.ndarray | None = None  # (3,) measured pose of the query in the anchor's frame


class SubmapCache:
    """Submaps drawn from the current keyframe poses, built when first asked for (cleared after each solve)."""

    def __init__(self, geo: ScanGeometry, kf: np.ndarray, cfg: LoopConfig):
        self.geo, self.kf, self.cfg = geo, kf, cfg
        self.depth = depth_for(cfg.linear_window, cfg.resolution)
        self._maps: dict[int, LocalMap | None] = {}
        self.poses: np.ndarray | None = None

    def reset(self, poses: np.ndarray) -> None:
        self.poses = poses
        self._maps.clear()

    def anchor(self, sid: int) -> int:
        return min(sid * self.cfg.submap_step + self.cfg.submap_step // 2, self.kf.size - 1)

    def span(self, sid: int) -> tuple[int, int]:
        lo = sid * self.cfg.submap_step - self.cfg.map_keyframes
        hi = (sid + 1) * self.cfg.submap_step + self.cfg.map_keyframes
        return max(0, lo), min(self.kf.size, hi)

    def get(self, sid: int) -> LocalMap | None:
        if sid not in self._maps:
            if len(self._maps) >= 16:  # the queries walk along the trajectory: keep the recent few
                self._maps.pop(next(iter(self._maps)))
            a = self.anchor(sid)
            lo, hi = self.span(sid)
            rel = relative(self.poses[a], self.poses[lo:hi])
            self._maps[sid] = LocalMap.of(
                self.geo, self.kf[lo:hi], rel, self.cfg.resolution, self.cfg.sigma, self.depth, centre=np.zeros(2), radius=self.cfg.map_range
            )
        return self._maps[sid]


def find_loops(
    geo: ScanGeometry,
    kf: np.ndarray,
    poses: np.ndarray,
    cfg: LoopConfig,
    icp: IcpConfig,
    known: set[tuple[int, int]],
    progress: Callable | None = None,
) -> list[LoopDecision]:
    """Loop decisions for keyframes ``kf`` (K,) (scan indices) at poses (K, 3); pairs (query, anchor) in ``known`` are skipped."""
    cache = SubmapCache(geo, kf, cfg)
    cache.reset(poses)
    tree = cKDTree(poses[:, :2])
    out: list[LoopDecision] = []
    queries = range(cfg.min_gap, kf.size, cfg.every)
    it = queries if progress is None else progress(queries, len(queries), "searching loops")
    for a in it:
        near = np.array(tree.query_ball_point(poses[a, :2], cfg.search_radius), dtype=int)
        near = near[near <= a - cfg.min_gap]
        if near.size == 0:
            continue
        d = np.hypot(*(poses[near, :2] - poses[a, :2]).T)
        sids: list[int] = []
        for b in near[np.argsort(d, kind="stable")]:
            sid = int(b) // cfg.submap_step
            lo, hi = cache.span(sid)
            if sid not in sids and hi <= a - cfg.min_gap // 2:
                sids.append(sid)
            if len(sids) >= cfg.max_candidates:
                break
        for sid in sids:
            anchor = cache.anchor(sid)
            if (a, anchor) in known:
                continue
            out.append(verify(geo, kf, a, anchor, cache.get(sid), relative(poses[anchor], poses[a]), cfg, icp))
    return out


def verify(geo, kf, a: int, anchor: int, sub: LocalMap | None, guess: np.ndarray, cfg: LoopConfig, icp: IcpConfig) -> LoopDecision:
    """Match query keyframe ``a`` on the submap of ``anchor`` from ``guess`` (the query in the anchor's frame) and check it."""
    pts = geo.points[kf[a]]
    if sub is None or pts.shape[0] < 6:
        return LoopDecision(a, anchor, False, "empty submap or scan")
    m = correlative_match(sub.field, voxel_filter(pts, cfg.voxel), guess, cfg.linear_window, cfg.angular_window, min_score=cfg.min_score)
    if m is None:
        return LoopDecision(a, anchor, False, f"score below {cfg.min_score:g}")
    pose, fit = align(pts, sub.tree, sub.p, sub.n, m.pose, icp)
    ev = np.linalg.eigvalsh(fit.information[:2, :2]) if np.isfinite(fit.information).all() else np.zeros(2)
    ratio = float(ev[0] / ev[1]) if ev[1] > 0 else 0.0
    ends, nrm = _to_world(pose, pts, geo.normals[kf[a]])
    start = _to_world(pose, geo.origin[None, :])[0]
    beam = ends - start
    beam /= np.maximum(np.hypot(beam[:, 0], beam[:, 1]), 1e-9)[:, None]
    # a beam runs within a sigma of the surface it ends on for sigma / cos(incidence) before its return
    cos_inc = np.abs(np.einsum("ij,ij->i", beam, np.nan_to_num(nrm, nan=1.0 / np.sqrt(2))))
    seen = float(see_through(sub.field, start, ends, np.minimum(3 * cfg.sigma / np.maximum(cos_inc, 1e-3), 2.0)).mean())
    dec = LoopDecision(a, anchor, False, "", m.score, fit.overlap, fit.agreement, fit.rms, ratio, seen, pose)
    if fit.overlap < cfg.min_overlap:
        dec.reason = f"overlap {fit.overlap:.2f} < {cfg.min_overlap:g}"
    elif fit.agreement < cfg.min_agreement:
        dec.reason = f"agreement {fit.agreement:.2f} < {cfg.min_agreement:g}"
    elif fit.rms > cfg.max_rms:
        dec.reason = f"rms {fit.rms:.3f} m > {cfg.max_rms:g} m"
    elif ratio < cfg.min_information_ratio:
        dec.reason = f"degenerate (information ratio {ratio:.3f} < {cfg.min_information_ratio:g})"
    elif seen > cfg.max_see_through:
        dec.reason = f"see-through {seen:.2f} > {cfg.max_see_through:g} (beams cross the submap's surfaces)"
    else:
        dec.accepted = True
    return dec
