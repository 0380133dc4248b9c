"""The steering offset estimated in every particle (``motion.ackermann.steer_offset_sd``) against a known bias: the
glmb-paper circuit (``calib.sim.glmb_paper``, its truth profile) with ``--bias`` added to every steering reading.

Run: ``python benchmarks/bench_steer_offset.py [--bias 0.03] [--seeds 1-4] [--particles 10] [--sds 0.02,0.05]``.

For each simulation seed (filter seed 0, optimal proposal, motion noise 0.1 m/s and 0.035 rad): the trajectory RMSE
against the simulator's truth (no alignment: the filter starts at the true pose) with no offset, with the true offset
given, and with the offset estimated from 0 with each prior standard deviation of ``--sds``, and the heaviest
particle's offset at the end. One process on one core (BLAS pinned to one thread).
"""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

for _v in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_v, "1")

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from benchmarks.common import ints  # noqa: E402


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--bias", type=float, default=0.03, help="added to every steering reading [rad]")
    ap.add_argument("--seeds", default="1-4", help="simulation seeds")
    ap.add_argument("--particles", type=int, default=10)
    ap.add_argument("--sds", default="0.02,0.05", help="prior standard deviations of the estimated offset [rad]")
    a = ap.parse_args()

    import numpy as np

    from calib.sim.glmb_paper import GlmbPaperConfig, simulate_glmb_paper, truth_profile, with_steering_bias
    from slam_runtime.config import SlamConfig, with_settings
    from slam_runtime.metrics import trajectory_rmse
    from slam_runtime.run import SteeringOffset, run_slam

    sim = GlmbPaperConfig(clutter=1.0)
    prof = truth_profile(sim)
    base = with_settings(
        SlamConfig(particles=a.particles, proposal="optimal"), {"motion.ackermann.sigma_speed": 0.1, "motion.ackermann.sigma_steer": 0.035}
    )
    variants = [("no offset", {}), ("the true offset", {"motion.ackermann.steer_offset": a.bias})]
    variants += [(f"estimated from sd {sd:g}", {"motion.ackermann.steer_offset_sd": sd}) for sd in map(float, a.sds.split(","))]
    print(f"glmb-paper, steering bias {a.bias:+g} rad, {a.particles} particles; RMSE vs the truth [m] (offset at the end [rad])")
    for seed in ints(a.seeds):
        log = simulate_glmb_paper(sim, seed)
        biased = with_steering_bias(log, a.bias)
        gt = log.reference["ground_truth"]
        cells = []
        for name, sets in variants:
            res = run_slam(biased, prof, with_settings(base, sets), 0, hooks=(SteeringOffset(),))
            err = trajectory_rmse(np.asarray(res.trajectory), gt.poses[np.searchsorted(gt.stamp, res.stamps)], align=False)
            off = res.per_step["steer_offset"][-1]
            cells.append(f"{name} {err:.2f}" + (f" ({off:+.4f})" if np.isfinite(off) else ""))
        print(f"  seed {seed}: " + "; ".join(cells), flush=True)


if __name__ == "__main__":
    main()
