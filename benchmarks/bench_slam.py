"""RB-PHD-SLAM time per step for 10, 50 and 200 particles: the simulated park and Victoria Park.

Run: ``python benchmarks/bench_slam.py [--frames N]``. Single process, BLAS pinned
to one thread. Per step = motion model + detection (laser) + map update +
weighting + resampling, as ``detcal slam run`` times it; the figures are the
mean and median over the first N frames (default 200 on the park, 1,000 on
Victoria Park). Victoria Park is skipped when ``../shared/data`` is absent.
Compare the rows of one run with each other, not with another machine's.
"""

from __future__ import annotations

import os

for var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(var, "1")

import argparse  # noqa: E402
import sys  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from calib.config import load_yaml_model  # noqa: E402
from calib.io.registry import ReadOptions, read_log  # noqa: E402
from calib.sim.park import ParkConfig, simulate_park  # noqa: E402
from profiles.store import load_profile_file, resolve  # noqa: E402
from slam_runtime.config import SlamConfig  # noqa: E402
from slam_runtime.run import run_slam  # noqa: E402

VP = ROOT.parent / "shared/data/victoria_park"


def bench(name, log, prof, cfg: SlamConfig, frames: int) -> None:
    for n in (10, 50, 200):
        c = cfg.model_copy(update={"rbphd": cfg.rbphd.model_copy(update={"particles": n})})
        res = run_slam(log, prof, c, seed=1, max_frames=frames)
        ms = res.step_ms[1:]  # the first step has no map yet
        key = next((k for k in res.metrics if k.startswith("trajectory_rmse")), None)
        rmse = f"{res.metrics[key]:.3f} m" if key else "-"
        print(f"{name:<26} {n:>4} particles  {ms.mean():7.1f} ms/step mean  {np.median(ms):7.1f} median   RMSE {rmse} over {res.stamps.size} frames")


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--frames", type=int, default=None)
    a = ap.parse_args()
    park = load_yaml_model(ParkConfig, ROOT / "benchmarks/configs/small_park.yaml")
    log = simulate_park(park, 1).log
    bench("simulated park (laser)", log, resolve("sim-park-laser"), SlamConfig(), a.frames or 200)
    if VP.is_dir():
        vp = read_log(VP, None, ReadOptions())
        prof = load_profile_file(ROOT / "benchmarks/profiles/victoria-park-nominal@1.0.0.yaml")
        cfg = load_yaml_model(SlamConfig, ROOT / "benchmarks/configs/victoria_park.yaml")
        bench("Victoria Park (detections)", vp, prof, cfg, a.frames or 1000)
    else:
        print(f"Victoria Park skipped: {VP} not found")


if __name__ == "__main__":
    main()
