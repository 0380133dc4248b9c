"""Compile detcal's numba kernels into their cache ahead of the first run (``python -m detcal.warm``; ``make`` runs
it after installing).

The kernels are declared with ``cache=True``: the first process that calls one compiles it (seconds each) and
writes it to the cache, and every later process loads it. Without this step the first SLAM run of a fresh install
pays the compilation; with it every run pays only the loading. Runs each map filter with its default settings for a
few steps of a small seeded scenario (rfs-sim: points on increment odometry, the optimal proposal), which calls the
kernels those runs call.
"""

from __future__ import annotations

import time

from detcal.environment import numba_cache


def warm(steps: int = 80) -> dict[str, float]:
    """{filter kind: CPU seconds its first short run took (compiling what was not cached)}."""
    numba_cache()
    from calib.sim.rfs import simulate_rfs, truth_profile
    from profiles.parameters import RfsSimConfig
    from slam_runtime.config import SlamConfig, override
    from slam_runtime.mapfilter import MAP_FILTERS
    from slam_runtime.run import run_slam

    sc = RfsSimConfig(steps=max(steps, 60), clutter_intensity=0.01)
    log, prof = simulate_rfs(sc, 0), truth_profile(sc)
    out = {}
    for kind in MAP_FILTERS.names():
        c0 = time.process_time()
        run_slam(log, prof, override(SlamConfig(), particles=4, **{"filter.kind": kind}), 0)
        out[kind] = time.process_time() - c0
    return out


if __name__ == "__main__":
    for kind, s in warm().items():
        print(f"{kind}: {s:.1f} s of CPU (compiling what the cache did not hold)")
