"""How far a ground truth can be trusted: figures, thresholds, a verdict, and the stretches that fail.

Figures (each a named :class:`calib.checks.Check` against a threshold of
:class:`QualityThresholds`):

- ``registered_share``: share of scans the front end placed on its map (the
  rest followed odometry alone);
- ``poor_keyframe_share``: share of keyframes whose ICP fitness (overlap x
  agreement, :class:`calib.icp.Fit`) is under ``keyframe_min_fitness``;
- ``back_end_rejected_share``: share of the geometrically verified loop
  closures that the robust pose graph turned off (many means the graph is
  at odds with itself);
- ``loop_residual_p95_m``: 95th percentile of the translation residual of the
  kept loop closures after the solve;
- ``map_consistency_p95_m`` and ``inconsistent_pair_share``: scans taken at
  the same place and heading (within ``consistency_radius`` and
  ``consistency_max_turn``) at least ``consistency_gap_s`` apart are laid on
  each other with the final poses; a pair's residual is the median
  point-to-line distance of one scan's points to the other's (nearest point
  within ``consistency_max_corr``, line from its neighbours). Two scans taken
  from one pose see the same surfaces, so a consistent pair's median is the
  range noise (points hidden by someone walking by find no neighbour and do
  not count); a map with a doubled or skewed stretch has pairs whose median
  is the offset between the copies, however well each scan fitted its local
  map when it was registered, or, offset beyond the gate, pairs with fewer
  than ``consistency_min_overlap`` of their points within it. The figures
  are the 95th percentile of the pair medians, and the share of pairs that
  are inconsistent (median over ``inconsistent_pair_m``, or overlap under
  ``consistency_min_overlap``);
- ``relation_trans_mean_m``, ``relation_rot_mean_deg``: the error against
  benchmark relations (Kümmerle et al. 2009), when they are given;
- ``reference_ate_m``: position RMSE against the log's reference poses after a
  rigid fit, when the log has them (simulated logs).

A figure that cannot be measured (no loops, no relations) is reported as n/a
and passes. Scans are *failing* when their keyframe fitted poorly or they
take part in inconsistent pairs; runs of them are the failing stretches the
map figure marks.
"""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass, field

import numpy as np
import pandas as pd
from pydantic import BaseModel, ConfigDict, Field
from scipy.spatial import cKDTree

from calib.checks import Check, Verdict
from calib.frontend import ScanGeometry
from calib.icp import IcpConfig, _to_world
from calib.progress import progress
from calib.trajectory import relation_scores
from detectors.geometry import interpolate_poses, relative, rigid_align
from detectors.sensor_log import SensorLog


class QualityThresholds(BaseModel):
    """Thresholds of the ground-truth verdict and the settings of its figures (see the module docstring)."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)
    min_registered_share: float = Field(default=0.95, ge=0.0, le=1.0)
    keyframe_min_fitness: float = Field(default=0.5, ge=0.0, le=1.0, description="a keyframe fitting worse is poor")
    max_poor_keyframe_share: float = Field(default=0.05, ge=0.0, le=1.0)
    max_back_end_rejected_share: float = Field(default=0.3, ge=0.0, le=1.0)
    max_loop_residual_m: float = Field(default=0.1, gt=0.0)
    consistency_gap_s: float = Field(default=30.0, gt=0.0, description="scans compared are at least this far apart in time [s]")
    consistency_radius: float = Field(default=1.0, gt=0.0, description="and at most this far apart in space [m]")
    consistency_spacing: float = Field(default=0.5, gt=0.0, description="scans compared are picked every this much travel [m] (or 0.2 rad)")
    consistency_max_turn: float = Field(default=0.5, gt=0.0, description="and headings at most this far apart [rad]: both see the same things")
    consistency_max_corr: float = Field(default=0.5, gt=0.0, description="nearest-point gate of a pair [m]")
    consistency_min_overlap: float = Field(
        default=0.2, gt=0.0, le=1.0, description="a pair with a smaller share of points within the gate is inconsistent outright"
    )
    consistency_pairs: int = Field(default=3000, ge=1, description="pairs compared at most (evenly picked)")
    inconsistent_pair_m: float = Field(default=0.15, gt=0.0, description="a pair whose median residual exceeds this is inconsistent [m]")
    max_consistency_p95_m: float = Field(default=0.08, gt=0.0)
    max_inconsistent_share: float = Field(default=0.02, ge=0.0, le=1.0)
    max_relation_trans_mean_m: float = Field(default=0.1, gt=0.0)
    max_relation_rot_mean_deg: float = Field(default=1.0, gt=0.0)
    max_reference_ate_m: float = Field(default=0.1, gt=0.0)
    merge_gap_s: float = Field(default=5.0, ge=0.0, description="failing runs closer than this in time are one stretch [s]")


@dataclass
class Consistency:
    """Pairs of scans (P, 2) far apart in time at one place, their median residual [m] (P,; NaN where the overlap
    is under the minimum) and overlap (P,; NaN where not compared); ``spaced`` (M,) the scans pairs were drawn from."""

    pairs: np.ndarray
    median: np.ndarray
    overlap: np.ndarray
    spaced: np.ndarray

    @property
    def counted(self) -> np.ndarray:
        return np.isfinite(self.median)


@dataclass
class QualityReport:
    """The verdict, its figures, and the tables behind them (``keyframes``, ``loops``; ``failing`` (S,) per scan)."""

    verdict: Verdict
    figures: dict
    failing: np.ndarray
    stretches: list[dict]
    keyframes: pd.DataFrame | None = None
    loops: pd.DataFrame | None = None
    consistency: Consistency | None = None
    relations: dict = field(default_factory=dict)

    def as_dict(self) -> dict:
        return {
            **self.verdict.as_dict(),
            "figures": self.figures,
            "failing_stretches": self.stretches,
            **({"relations": self.relations} if self.relations else {}),
        }


def spaced_scans(poses: np.ndarray, dist: float, turn: float = 0.2) -> np.ndarray:
    """Indices of scans picked every ``dist`` metres or ``turn`` radians of the trajectory (S, 3), first included."""
    out = [0]
    for k in range(1, poses.shape[0]):
        d = relative(poses[out[-1]], poses[k])
        if np.hypot(d[0], d[1]) >= dist or abs(d[2]) >= turn:
            out.append(k)
    return np.array(out)


def map_consistency(geo: ScanGeometry, stamps_s: np.ndarray, poses: np.ndarray, th: QualityThresholds) -> Consistency:
    """Pairs of spaced scans at one place far apart in time, laid on each other by ``poses`` (S, 3) (module docstring)."""
    sel = spaced_scans(poses, th.consistency_spacing)
    pairs = cKDTree(poses[sel, :2]).query_pairs(th.consistency_radius, output_type="ndarray")
    if pairs.size == 0:
        return Consistency(np.zeros((0, 2), int), np.zeros(0), np.zeros(0), sel)
    pairs = sel[pairs]
    turn = np.abs(relative(poses[pairs[:, 0]], poses[pairs[:, 1]])[:, 2])
    pairs = pairs[(np.abs(stamps_s[pairs[:, 0]] - stamps_s[pairs[:, 1]]) >= th.consistency_gap_s) & (turn <= th.consistency_max_turn)]
    pairs = pairs[np.lexsort((pairs[:, 1], pairs[:, 0]))]
    if pairs.shape[0] > th.consistency_pairs:
        pairs = pairs[np.unique(np.linspace(0, pairs.shape[0] - 1, th.consistency_pairs).round().astype(int))]
    med = np.full(pairs.shape[0], np.nan)
    ovl = np.full(pairs.shape[0], np.nan)  # NaN: not compared (a scan with too few returns)
    trees: dict[int, tuple | None] = {}
    for n, (i, j) in enumerate(progress(pairs, pairs.shape[0], "checking map consistency")):
        if i not in trees:
            trees.clear()  # pairs are sorted by their first scan: one tree at a time
            wp, wn = _to_world(poses[i], geo.points[i], geo.normals[i])
            trees[i] = (cKDTree(wp), wp, wn) if wp.shape[0] >= 6 else None
        t = trees[i]
        q = _to_world(poses[j], geo.points[j])
        if t is None or q.shape[0] < 6:
            continue
        d, idx = t[0].query(q, distance_upper_bound=th.consistency_max_corr)
        near = np.isfinite(d)
        ovl[n] = near.mean()
        if ovl[n] < th.consistency_min_overlap:
            continue  # laid too far apart for the gate (or hidden behind something near): counted apart
        diff = q[near] - t[1][idx[near]]
        nrm = t[2][idx[near]]
        r = np.where(np.isfinite(nrm[:, 0]), np.abs(np.einsum("ij,ij->i", diff, np.nan_to_num(nrm))), np.hypot(diff[:, 0], diff[:, 1]))
        med[n] = float(np.median(r))
    return Consistency(pairs, med, ovl, sel)


def assess(
    log: SensorLog,
    poses: np.ndarray,
    registration=None,
    relations: np.ndarray | None = None,
    thresholds: QualityThresholds | None = None,
    geo: ScanGeometry | None = None,
) -> QualityReport:
    """Quality report of vehicle poses (S, 3) of ``log``'s scans (see the module docstring).

    registration: the :class:`calib.mapping.Registration` that made the poses, when there is one (fitness,
    loops, residuals); without it only the map consistency and the scores against relations or reference
    poses are measured. relations: (R, 5) benchmark relations (:func:`calib.icp.read_relations`).
    """
    th = thresholds or QualityThresholds()
    n = poses.shape[0]
    stamps_s = log.scans.stamp / 1e9
    geo = geo or ScanGeometry.of(log, IcpConfig(), None)
    nan = float("nan")
    figures: dict = {}
    checks: list[Check] = []
    failing = np.zeros(n, dtype=bool)
    kf_table = loop_table = None
    if registration is not None:
        fe = registration.front_end
        kf = fe.keyframes
        fit = fe.fitness[kf[1:]]
        poor = fit < th.keyframe_min_fitness
        figures["registered_share"] = float(fe.registered.mean())
        figures["keyframes"] = int(kf.size)
        figures["keyframe_fitness_median"] = float(np.median(fit)) if fit.size else nan
        figures["poor_keyframe_share"] = float(poor.mean()) if fit.size else nan
        figures["recovered_scans"] = int(fe.recovered.sum())
        checks.append(Check("registered_share", figures["registered_share"], th.min_registered_share, "min", "share of scans placed on the map"))
        checks.append(
            Check("poor_keyframe_share", figures["poor_keyframe_share"], th.max_poor_keyframe_share, "max", f"keyframes with ICP fitness < {th.keyframe_min_fitness:g}")
        )
        owner = np.searchsorted(kf, np.arange(n), side="right") - 1
        poor_kf = np.concatenate([[False], poor])
        failing |= poor_kf[owner]
        loop_table, loop_figs = _loop_figures(registration)
        figures.update(loop_figs)
        checks.append(
            Check("back_end_rejected_share", loop_figs["back_end_rejected_share"], th.max_back_end_rejected_share, "max", "verified loops the robust graph turned off")
        )
        checks.append(Check("loop_residual_p95_m", loop_figs["loop_residual_p95_m"], th.max_loop_residual_m, "max", "kept loops' translation residual after the solve", "m"))
        kf_table = pd.DataFrame(
            {
                "scan": kf,
                "time": stamps_s[kf],
                "x": registration.keyframe_poses[:, 0],
                "y": registration.keyframe_poses[:, 1],
                "theta": registration.keyframe_poses[:, 2],
                "score": fe.score[kf],
                "fitness": fe.fitness[kf],
                "rms_m": np.where(np.isfinite(fe.rms[kf]), fe.rms[kf], np.nan),
                "recovered": fe.recovered[kf],
                "poor": poor_kf,
            }
        )
    cons = map_consistency(geo, stamps_s, poses, th)
    counted = cons.counted
    compared = counted | (cons.overlap < th.consistency_min_overlap)
    figures["consistency_pairs"] = int(compared.sum())
    figures["map_consistency_median_m"] = float(np.median(cons.median[counted])) if counted.any() else nan
    figures["map_consistency_p95_m"] = float(np.quantile(cons.median[counted], 0.95)) if counted.any() else nan
    bad_pair = compared & ((np.nan_to_num(cons.median, nan=0.0) > th.inconsistent_pair_m) | ~counted)
    figures["inconsistent_pair_share"] = float(bad_pair[compared].mean()) if compared.any() else nan
    checks.append(
        Check("map_consistency_p95_m", figures["map_consistency_p95_m"], th.max_consistency_p95_m, "max", "scans at one place far apart in time disagree", "m")
    )
    checks.append(
        Check("inconsistent_pair_share", figures["inconsistent_pair_share"], th.max_inconsistent_share, "max", f"scan pairs disagreeing by more than {th.inconsistent_pair_m:g} m")
    )
    if bad_pair.any():
        # a spaced scan stands for the scans up to the next spaced one
        sel = cons.spaced
        bad = np.zeros(n, dtype=bool)
        bad[np.unique(cons.pairs[bad_pair])] = True
        owner = sel[np.searchsorted(sel, np.arange(n), side="right") - 1]
        failing |= bad[owner]
    rel_scores: dict = {}
    if relations is not None:
        rel_scores = relation_scores(log.scans.stamp, poses, relations)
        figures["relation_trans_mean_m"] = rel_scores["trans_mean_m"]
        figures["relation_rot_mean_deg"] = rel_scores["rot_mean_deg"]
        checks.append(Check("relation_trans_mean_m", rel_scores["trans_mean_m"], th.max_relation_trans_mean_m, "max", "error against the benchmark relations", "m"))
        checks.append(Check("relation_rot_mean_deg", rel_scores["rot_mean_deg"], th.max_relation_rot_mean_deg, "max", "error against the benchmark relations", "deg"))
    if "ground_truth" in log.reference:
        ref = log.reference["ground_truth"]
        truth = interpolate_poses(ref.stamp, ref.poses, log.scans.stamp)
        ate = float(np.sqrt(np.mean(np.sum((rigid_align(poses, truth)[:, :2] - truth[:, :2]) ** 2, axis=1))))
        figures["reference_ate_m"] = ate
        checks.append(Check("reference_ate_m", ate, th.max_reference_ate_m, "max", "position RMSE against the log's reference poses after a rigid fit", "m"))
    verdict = Verdict("ground truth", tuple(checks))
    if kf_table is not None:
        kf_table["failing"] = failing[kf_table["scan"].to_numpy()]
    return QualityReport(verdict, figures, failing, stretches(failing, stamps_s, th.merge_gap_s), kf_table, loop_table, cons, rel_scores)


def _loop_figures(reg) -> tuple[pd.DataFrame, dict]:
    """The loop decisions as a table, with the back end's verdict on each accepted one, and the loop figures."""
    decisions = reg.loops
    back = np.full(len(decisions), "", dtype=object)
    chi2 = np.full(len(decisions), np.nan)
    resid = np.full(len(decisions), np.nan)
    loop_rows = np.flatnonzero(reg.edges.loop)
    from calib.posegraph import residuals

    e = residuals(reg.keyframe_poses, reg.edges)[loop_rows]
    w = reg.solution.weight[loop_rows]
    for k, (di, row) in enumerate(zip(reg.loop_edges, loop_rows, strict=True)):
        chi2[di] = reg.solution.chi2[row]
        resid[di] = float(np.hypot(e[k, 0], e[k, 1]))
        back[di] = "kept" if w[k] >= 0.5 else "turned off by the robust graph"
    table = pd.DataFrame(
        {
            "query_keyframe": [d.query for d in decisions],
            "anchor_keyframe": [d.anchor for d in decisions],
            "verified": [d.accepted for d in decisions],
            "reason": [d.reason for d in decisions],
            "back_end": back,
            "score": [d.score for d in decisions],
            "overlap": [d.overlap for d in decisions],
            "agreement": [d.agreement for d in decisions],
            "rms_m": [d.rms for d in decisions],
            "information_ratio": [d.information_ratio for d in decisions],
            "chi2_after": chi2,
            "residual_m_after": resid,
        }
    )
    verified = int(table["verified"].sum())
    off = int((back == "turned off by the robust graph").sum())
    kept = back == "kept"
    reasons = Counter(d.reason.split(" ")[0] for d in decisions if not d.accepted)
    figs = {
        "loop_candidates": len(decisions),
        "loops_verified": verified,
        "loops_rejected": {k: int(reasons[k]) for k in sorted(reasons)},
        "loops_turned_off_by_back_end": off,
        "loops_kept": int(kept.sum()),
        "back_end_rejected_share": off / verified if verified else float("nan"),
        "loop_residual_p95_m": float(np.quantile(resid[kept], 0.95)) if kept.any() else float("nan"),
    }
    return table, figs


def stretches(failing: np.ndarray, stamps_s: np.ndarray, merge_gap_s: float = 0.0) -> list[dict]:
    """Runs of failing scans (S,) as {first_scan, last_scan, start_s, end_s} (seconds from the log's start), in
    time order; runs less than ``merge_gap_s`` apart are one stretch."""
    if not failing.any():
        return []
    edges = np.diff(np.concatenate([[0], failing.astype(np.int8), [0]]))
    starts, ends = np.flatnonzero(edges == 1), np.flatnonzero(edges == -1) - 1
    if starts.size > 1:
        join = stamps_s[starts[1:]] - stamps_s[ends[:-1]] < merge_gap_s
        starts = np.concatenate([starts[:1], starts[1:][~join]])
        ends = np.concatenate([ends[:-1][~join], ends[-1:]])
    return [
        {"first_scan": int(a), "last_scan": int(b), "start_s": float(stamps_s[a] - stamps_s[0]), "end_s": float(stamps_s[b] - stamps_s[0])}
        for a, b in zip(starts, ends, strict=True)
    ]
