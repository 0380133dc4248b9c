"""Reading speed of every reader, in scans (or frames) per second.

Run: ``python benchmarks/bench_readers.py`` (uses ../shared/data when present
and a simulated park log always). Prints one row per reader; best of 3 runs.
"""

from __future__ import annotations

import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
DATA = ROOT.parent / "shared" / "data"
sys.path.insert(0, str(ROOT))

from calib.io.registry import ReadOptions, read_log, write_log  # noqa: E402
from calib.sim.park import ParkConfig, simulate_park  # noqa: E402


def units(log) -> tuple[int, str]:
    if log.scans is not None:
        return len(log.scans), "scans"
    if log.detections is not None:
        return log.detections.n_frames, "frames"
    if log.clouds is not None:
        return len(log.clouds), "clouds"
    return len(log.odometry), "odometry rows"


def best_of(fn, n=3) -> tuple[float, object]:
    best, out = float("inf"), None
    for _ in range(n):
        t = time.perf_counter()
        out = fn()
        best = min(best, time.perf_counter() - t)
    return best, out


def main() -> None:
    tmp = Path(tempfile.mkdtemp(prefix="detcal-bench-"))
    sim = simulate_park(ParkConfig(), seed=1)
    write_log(sim.log, tmp / "park.dlog")
    write_log(sim.log, tmp / "park_bag")
    foreign = ReadOptions(scan_topic="/scan", odom_topic=None)
    cases = [
        ("native (.dlog), simulated park", tmp / "park.dlog", None),
        ("ROS 2 bag (detcal-written), simulated park", tmp / "park_bag", None),
        ("ROS 2 bag, LaserScan /scan path, sim. park", tmp / "park_bag", foreign),
    ]
    if DATA.exists():
        cases += [
            ("CARMEN intel.clf.bz2", DATA / "radish/intel.clf.bz2", None),
            ("CARMEN aces.clf.bz2", DATA / "radish/aces.clf.bz2", None),
            ("Victoria Park ASCII", DATA / "victoria_park", None),
            ("UTIAS dataset1 robot 1", DATA / "utias_mrclam/dataset1", None),
            ("KITTI velodyne .bin", DATA / "kitti_object/velodyne", None),
        ]
        vp = read_log(DATA / "victoria_park")
        write_log(vp, tmp / "vp_bag")
        cases.append(("ROS 2 bag (detcal-written), Victoria Park", tmp / "vp_bag", None))
    else:
        print("(../shared/data absent: real-log readers skipped)")
    print(f"{'reader':45s} {'units':>10s} {'seconds':>9s} {'per second':>12s}")
    for name, path, opts in cases:
        sec, log = best_of(lambda path=path, opts=opts: read_log(path, options=opts))
        n, what = units(log)
        print(f"{name:45s} {n:>7d} {what:<3s} {sec:9.3f} {n / sec:12,.0f}")


if __name__ == "__main__":
    main()
