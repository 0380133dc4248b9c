"""Ground truth on the Radish logs: accuracy, quality figures, CPU time per stage, and the pose-graph solvers compared.

Run: ``python benchmarks/bench_groundtruth.py [--logs aces,intel] [--solvers]``. For each log it builds the
ground truth with the defaults (:mod:`calib.mapping`) and prints

- the Kümmerle et al. (2009) relation scores when the log has relations (ACES: ``aces.relations``;
  Intel has none here), for the ground truth and for odometry;
- the quality figures (:mod:`calib.gtquality`) and the verdict;
- CPU seconds per stage and the peak resident memory of this process (wall time on a shared machine
  says little; measure it per log with ``/usr/bin/time -v`` around one ``detcal icp``).

``--solvers`` re-solves the final graph of each log (the same edges, from the front end's keyframe poses)
with GTSAM (GNC with truncated least squares; Levenberg-Marquardt with Cauchy) and with scipy (sparse
least squares, Cauchy by reweighting; plain least squares) and prints each one's CPU time, the loops
it turned off, and the relation scores of the poses it gives.
"""

from __future__ import annotations

import argparse
import resource
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import numpy as np  # noqa: E402

from calib.gtquality import assess  # noqa: E402
from calib.icp import read_relations  # noqa: E402
from calib.io.carmen import read_carmen  # noqa: E402
from calib.mapping import GroundTruthConfig, build_ground_truth  # noqa: E402
from calib.posegraph import GraphConfig, solve  # noqa: E402
from calib.trajectory import relation_scores  # noqa: E402
from detectors.geometry import compose, relative  # noqa: E402

DATA = Path(__file__).resolve().parents[2] / "shared" / "data" / "radish"


def scores_line(name: str, sc: dict) -> str:
    return (
        f"  {name:<26} {sc['relations']} relations: {sc['trans_mean_m']:.4f} +- {sc['trans_std_m']:.4f} m (max {sc['trans_max_m']:.3f}), "
        f"{sc['rot_mean_deg']:.3f} +- {sc['rot_std_deg']:.3f} deg (max {sc['rot_max_deg']:.2f})"
    )


def scan_poses(res, kposes: np.ndarray) -> np.ndarray:
    """Every scan's pose from keyframe poses (K, 3), the scans between keyframes following theirs."""
    kf = res.keyframes
    fe = res.details.front_end.poses
    owner = np.searchsorted(kf, np.arange(fe.shape[0]), side="right") - 1
    return compose(kposes[owner], relative(fe[kf][owner], fe))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--logs", default="aces,intel")
    ap.add_argument("--data", type=Path, default=DATA, help="folder of the Radish logs")
    ap.add_argument("--solvers", action="store_true", help="compare the pose-graph solvers on each log's final graph")
    args = ap.parse_args()
    for name in filter(None, args.logs.split(",")):
        path = args.data / f"{name}.clf.bz2"
        if not path.exists():
            print(f"{name}: {path} not found, skipped")
            continue
        c0 = time.process_time()
        log = read_carmen(path)
        c_read = time.process_time() - c0
        rel_path = args.data / f"{name}.relations"
        rel = read_relations(rel_path) if rel_path.exists() else None
        cfg = GroundTruthConfig()
        c0 = time.process_time()
        res = build_ground_truth(log, cfg)
        c_gt = time.process_time() - c0
        c0 = time.process_time()
        q = assess(log, res.poses, res.details, rel)
        c_q = time.process_time() - c0
        reg = res.details
        print(f"{name}: {len(log.scans)} scans, {res.keyframes.size} keyframes, {len(res.loops)} loop closures kept")
        print(f"  CPU s: read {c_read:.1f}, ground truth {c_gt:.1f} ({', '.join(f'{k} {v:.1f}' for k, v in reg.cpu_seconds.items())}), quality {c_q:.1f}")
        print(f"  peak resident memory so far: {resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024:.0f} MB")
        if rel is not None:
            print(scores_line("ground truth", relation_scores(log.scans.stamp, res.poses, rel)))
            print(scores_line("odometry", relation_scores(log.scans.stamp, res.odometry, rel)))
        else:
            print(f"  no benchmark relations for {name} ({rel_path.name} absent): judged by its quality figures alone")
        print(f"  {q.verdict.message(name)}")
        for k, v in q.figures.items():
            print(f"    {k}: {v:.4g}" if isinstance(v, float) else f"    {k}: {v}")
        if args.solvers:
            x0 = reg.front_end.poses[res.keyframes]
            for label, gc in (
                ("gtsam GNC (TLS)", GraphConfig(solver="gtsam", robust="gnc")),
                ("gtsam LM + Cauchy", GraphConfig(solver="gtsam", robust="cauchy")),
                ("scipy + Cauchy (IRLS)", GraphConfig(solver="scipy", robust="cauchy")),
                ("scipy, plain", GraphConfig(solver="scipy", robust="none")),
            ):
                c0 = time.process_time()
                sol = solve(x0, reg.edges, gc)
                dt = time.process_time() - c0
                off = int((sol.weight[reg.edges.loop] < 0.5).sum())
                line = f"  solver {label:<22} CPU {dt:6.2f} s, loops off {off:4d} of {int(reg.edges.loop.sum())}"
                if rel is not None:
                    sc = relation_scores(log.scans.stamp, scan_poses(res, sol.poses), rel)
                    line += f", relations {sc['trans_mean_m']:.4f} m (max {sc['trans_max_m']:.3f}), {sc['rot_mean_deg']:.3f} deg (max {sc['rot_max_deg']:.2f})"
                print(line)


if __name__ == "__main__":
    main()
