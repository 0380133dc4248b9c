"""Ground truth of a laser log: front end, verified loop closures, robust pose graph.

1. **Dead reckoning** (:func:`calib.icp.odometry_poses`) predicts each scan.
2. **Front end** (:mod:`calib.frontend`): every scan registered on a local
   map of recent keyframes, correlative search then ICP.
3. **Loop closures** (:mod:`calib.loops`), verified geometrically, and the
   **pose graph** (:mod:`calib.posegraph`) over keyframes with sequential and
   loop edges, robust costs on the loops; ``rounds`` times, each round
   searching from the last solution.
4. The scans between keyframes keep their front-end pose relative to the
   keyframe before them.

The result's ``details`` (:class:`Registration`) hold what the quality report
(:mod:`calib.gtquality`) needs: per-scan fitness, loop decisions with the
back end's verdict, residuals after the solve, and the CPU time per stage.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
from pydantic import BaseModel, ConfigDict

from calib.frontend import FrontEnd, FrontEndConfig, ScanGeometry, run_front_end
from calib.icp import IcpConfig, IcpResult, odometry_poses
from calib.loops import LoopConfig, LoopDecision, find_loops
from calib.posegraph import Edges, GraphConfig, Solution, sequential_sigma, solve
from detectors.geometry import compose, relative
from detectors.sensor_log import SensorLog
from profiles.errors import DataError


class GroundTruthConfig(BaseModel):
    """Every setting of the ground truth, in groups with working defaults."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)
    icp: IcpConfig = IcpConfig()
    front_end: FrontEndConfig = FrontEndConfig()
    loops: LoopConfig = LoopConfig()
    graph: GraphConfig = GraphConfig()


@dataclass
class Registration:
    """What the registration saw (see the module docstring); K keyframes, E graph edges."""

    front_end: FrontEnd
    keyframe_poses: np.ndarray  # (K, 3) after the last solve
    edges: Edges
    solution: Solution
    loops: list[LoopDecision]  # every candidate verified, in the order tried
    loop_edges: list[int]  # index into ``loops`` of each loop edge, in edge order
    cpu_seconds: dict[str, float] = field(default_factory=dict)

    def back_end_rejected(self) -> np.ndarray:
        """(E_loop,) bool: loop edges the robust solve turned off (weight below 0.5)."""
        return self.solution.weight[self.edges.loop] < 0.5


def build_ground_truth(
    log: SensorLog, cfg: GroundTruthConfig | None = None, origin: np.ndarray | None = None, progress: Callable | None = None
) -> IcpResult:
    """Vehicle poses (S, 3) of every scan of ``log`` and the registration's details (see the module docstring).

    origin: the world pose of the first scan's vehicle (default the origin, heading 0).
    """
    cfg = cfg or GroundTruthConfig()
    if log.scans is None or log.sensor is None:
        raise DataError(f"log {log.name!r} has no laser scans to align")
    cpu: dict[str, float] = {}
    t0 = time.process_time()
    odo = odometry_poses(log)
    geo = ScanGeometry.of(log, cfg.icp, cfg.front_end.max_range)
    fe = run_front_end(log, odo, geo, cfg.front_end, cfg.icp, progress)
    cpu["front_end"] = time.process_time() - t0
    kf = fe.keyframes
    x = fe.poses[kf].copy()
    z = relative(x[:-1], x[1:])
    edges = Edges.empty().plus(np.arange(kf.size - 1), np.arange(1, kf.size), z, sequential_sigma(z, cfg.graph), loop=False)
    decisions: list[LoopDecision] = []
    loop_edges: list[int] = []
    known: set[tuple[int, int]] = set()
    sol = solve(x, edges, cfg.graph)
    cpu["loops"] = cpu["graph"] = 0.0
    for _ in range(cfg.loops.rounds):
        t0 = time.process_time()
        new = find_loops(geo, kf, x, cfg.loops, cfg.icp, known, progress)
        cpu["loops"] += time.process_time() - t0
        known |= {(d.query, d.anchor) for d in new}
        acc = [d for d in new if d.accepted]
        for d in acc:
            loop_edges.append(len(decisions) + new.index(d))
        decisions += new
        if not acc:
            break
        sigma = np.array([[cfg.graph.loop_sigma_xy, cfg.graph.loop_sigma_xy, cfg.graph.loop_sigma_theta]])
        edges = edges.plus([d.anchor for d in acc], [d.query for d in acc], np.array([d.rel for d in acc]), sigma, loop=True)
        t0 = time.process_time()
        sol = solve(x, edges, cfg.graph)
        cpu["graph"] += time.process_time() - t0
        x = sol.poses
    # scans between keyframes keep their front-end pose relative to the keyframe before them
    owner = np.searchsorted(kf, np.arange(odo.shape[0]), side="right") - 1
    poses = compose(x[owner], relative(fe.poses[kf][owner], fe.poses))
    if origin is not None:
        poses = compose(np.asarray(origin, dtype=np.float64), poses)
    reg = Registration(fe, x, edges, sol, decisions, loop_edges, cpu)
    kept = ~reg.back_end_rejected()
    pairs = [(decisions[i].anchor, decisions[i].query) for i, k in zip(loop_edges, kept, strict=True) if k]
    return IcpResult(poses, kf, pairs, odo, reg)
