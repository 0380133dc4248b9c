"""SLAM with planar landmarks on simulated streets: calibrated against constant P_D, per map filter.

A profile is calibrated on its own street (seed 100, every second frame); then each of ``--streets`` streets
(seeds 1..N, about 345 frames each, HDL-64E-like) runs through every map filter asked for (``--filter``, any of
``slam_runtime.mapfilter.MAP_FILTERS``) with the ECT model, the profile's P_D (``profile``) and a constant P_D of
0.9 inside the range (``constant``), for ``--seeds`` filter seeds. Printed per setting (mean +- standard
deviation over runs): the trajectory RMSE against the truth beside dead reckoning's, the map OSPA (c = 1 m,
p = 1) on the plane embedding (L n, d) with L = 10 m against the planes seen with >= 200 returns, the matched
planes' median normal angle and offset error, mapped and true landmarks, ms per step.

The plane detector's output of every frame is computed once per street and shared by all runs (it does not
depend on the filter), so the timing column is the filter's own.

    python benchmarks/bench_street_slam.py [--streets 3] [--seeds 1] [--filter rbphd] [--particles 20] [--set key=value ...]

The last row is the runs' log evidence (``slam_runtime.run.evaluate``): settings of one filter on one street compare
by it without ground truth.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

import numpy as np

from calib.planes import PlaneCalibConfig, calibrate_planes
from calib.sim.street import StreetConfig, simulate_street
from slam_runtime.config import SlamConfig, with_filter, with_settings
from slam_runtime.mapfilter import MAP_FILTERS
from slam_runtime.run import evaluate, run_slam
from detectors.kinds import DETECTORS
from detectors.plane import CloudPlanes, PlaneDetector

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from benchmarks.common import parse_set

KEYS = (
    ("trajectory RMSE [m]", "trajectory_rmse_vs_ground_truth_m"),
    ("dead reckoning RMSE [m]", "odometry_rmse_vs_ground_truth_m"),
    ("map OSPA", "map_ospa"),
    ("normal angle [deg]", "map_normal_angle_median_deg"),
    ("offset error [m]", "map_offset_error_median_m"),
    ("planes mapped", "landmarks_mapped"),
    ("landmarks (truth)", "landmarks_true"),
    ("map features", "map_features"),
    ("ms per step", "ms_per_step_mean"),
    ("log evidence [nats]", "log_evidence"),
)


class Cached:
    """A CloudPlanes source whose frames are detected once per log and reused by every run."""

    store: dict = {}

    def __init__(self, log, profile, detection) -> None:
        self.inner = CloudPlanes(log, profile, detection)
        self.key = id(log)

    def __call__(self, frame):
        d = Cached.store.setdefault(self.key, {})
        if frame.rows not in d:
            d[frame.rows] = self.inner(frame)
        return d[frame.rows]


class CachedPlanes(PlaneDetector):
    """The plane detector kind with its measurement source cached (:class:`Cached`)."""

    def source(self, log, profile, detection, options):
        return Cached(log, profile, detection)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--streets", type=int, default=3)
    ap.add_argument("--seeds", type=int, default=1)
    ap.add_argument("--filter", action="append", dest="filters", default=None)
    ap.add_argument("--particles", type=int, default=20)
    ap.add_argument("--frames", type=int, default=None)
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", help="override a setting of every run (e.g. filter.survival=1)")
    args = ap.parse_args()
    sets = dict(parse_set(x) for x in args.set)
    filters = args.filters or ["rbphd"]
    for f in filters:
        if f not in MAP_FILTERS:
            raise SystemExit(f"--filter: {f!r} is not one of {MAP_FILTERS.names()}")
    print(f"load average: {os.getloadavg()[0]:.2f} on {os.cpu_count()} cores")
    t0 = time.perf_counter()
    cal_log = simulate_street(StreetConfig(), 100).log
    prof = calibrate_planes([cal_log], PlaneCalibConfig(every=2), name="street-bench", version="1.0.0").profile
    print(f"profile calibrated on street 100 ({len(cal_log.clouds)} frames, every second) in {time.perf_counter() - t0:.0f} s: "
          f"P_D {dict(zip(prof.pd.edges[:-1], np.round(prof.pd.pd, 2), strict=True))}, clutter {prof.clutter.rate:.2f} per frame")
    DETECTORS.add("plane3d", CachedPlanes(), replace=True)  # one detection pass per street, shared by the runs
    results: dict = {}
    for s in range(1, args.streets + 1):
        log = simulate_street(StreetConfig(frames=args.frames), s).log
        for f in filters:
            for mode in ("profile", "constant"):
                cfg = with_settings(with_filter(SlamConfig(), f), {"features": "planes", "particles": args.particles, "detection.pd_mode": mode, **sets})
                for seed in range(args.seeds):
                    t1 = time.perf_counter()
                    res = run_slam(log, prof, cfg, seed)
                    m = evaluate(log, res, 1.0, 1.0, cfg)
                    results.setdefault((f, mode), []).append(m)
                    print(f"street {s} {f} {mode} seed {seed}: RMSE {m['trajectory_rmse_vs_ground_truth_m']:.3f} m "
                          f"(dead reckoning {m['odometry_rmse_vs_ground_truth_m']:.3f}), map OSPA {m['map_ospa']:.3f}, "
                          f"{time.perf_counter() - t1:.0f} s", flush=True)
    print(f"\n{'':26}" + "".join(f"{f + ' ' + mode:>22}" for (f, mode) in results))
    for label, key in KEYS:
        row = f"{label:26}"
        for runs in results.values():
            v = np.array([r[key] for r in runs], dtype=np.float64)
            row += f"{np.nanmean(v):>14.3f} ± {np.nanstd(v):<5.3f}"
        print(row)
    print(f"({args.streets} streets x {args.seeds} seeds per setting, {args.particles} particles)")


if __name__ == "__main__":
    main()
