"""Detection throughput (361-beam scans/s) and ray-tracing throughput (landmark-beam tests/s).

Run: ``python benchmarks/bench_detectors.py``. Single process; numpy may use
more threads for the small 3x3 solves, so the script pins BLAS to one thread
(the issue's targets are per core). Prints best of 3 and where the time goes.
"""

from __future__ import annotations

import os

for var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(var, "1")

import cProfile  # noqa: E402
import pstats  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from calib.sim.park import ParkConfig, sensor_poses, simulate_park  # noqa: E402
from detectors.circle import detect_circles  # noqa: E402
from detectors.raytrace import count_unoccluded  # noqa: E402
from profiles.schema import CircleDetectorParams  # noqa: E402


def best(fn, n=3):
    t = []
    for _ in range(n):
        a = time.perf_counter()
        fn()
        t.append(time.perf_counter() - a)
    return min(t)


def main() -> None:
    sim = simulate_park(ParkConfig(), seed=1)
    log = sim.log
    ang = log.sensor.angles()
    params = CircleDetectorParams()
    n = len(log.scans)
    det = detect_circles(log.scans.ranges, ang, params, range_sigma=0.02)
    t_batch = best(lambda: detect_circles(log.scans.ranges, ang, params, range_sigma=0.02))
    t_one = best(lambda: [detect_circles(log.scans.ranges[i], ang, params, range_sigma=0.02) for i in range(200)], 1) / 200
    print(f"simulated park: {n} scans x {log.scans.n_beams} beams, {len(det)} clusters fitted ({len(det) / n:.1f} per scan)")
    print(f"circle detector, whole log in one batch : {n / t_batch:9,.0f} scans/s")
    print(f"circle detector, one scan per call      : {1 / t_one:9,.0f} scans/s")

    gt = log.reference["ground_truth"]
    sp = sensor_poses(gt.poses[np.searchsorted(gt.stamp, log.scans.stamp)], log.sensor.mount)
    trees, radii = sim.world.tree_xy, sim.world.tree_r
    t_rt = best(lambda: count_unoccluded(sp, ang, log.scans.ranges, trees, radii, range_sigma=0.02, range_max=80.0), 2)
    tests = n * ang.size * trees.shape[0]
    print(f"ray tracing n_p, {trees.shape[0]} landmarks x {ang.size} beams x {n} scans: {tests / t_rt / 1e6:6.1f} M tests/s")
    one = sp[:1], log.scans.ranges[:1]
    t_rt1 = best(lambda: [count_unoccluded(one[0], ang, one[1], trees, radii, range_sigma=0.02, range_max=80.0) for _ in range(50)], 1) / 50
    print(f"ray tracing n_p, one scan per call       : {ang.size * trees.shape[0] / t_rt1 / 1e6:6.1f} M tests/s ({t_rt1 * 1e3:.2f} ms per scan)")

    print("\nwhere the detector's time goes (top 8 by own time):")
    prof = cProfile.Profile()
    prof.enable()
    detect_circles(log.scans.ranges, ang, params, range_sigma=0.02)
    prof.disable()
    pstats.Stats(prof).sort_stats("tottime").print_stats(8)


if __name__ == "__main__":
    main()
