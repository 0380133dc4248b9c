"""Time per step of the three map filters (RB-PHD, LMB, delta-GLMB) at the four clutter rates of the
delta-GLMB-SLAM paper, in one process: ``python benchmarks/bench_glmb.py [--frames N] [--particles P] [--config F]
[--filters lmb,glmb]``.

The scenario is ``detcal simulate glmb-paper`` (seed 0) at 1, 5, 10 and 15 false alarms per scan, with the
settings of ``benchmarks/configs/glmb_paper.yaml`` (100 particles by default; RB-PHD with its defaults and
the same motion, detection and metric settings; the settings the filters share, such as survival, birth and
Gibbs samples, carry over from the config as on ``detcal slam sweep --filter``). BLAS is pinned to one thread and every filter runs once
before timing (numba compiles or loads its kernels then), so the figures are one core's. Per step =
motion model + map update + weighting + resampling, as ``detcal slam run`` times it; wall and process CPU
time are both printed (on a shared machine the CPU time is the fairer one), with the load average before
and after. Compare the rows of one run with each other, not with another machine's.
"""

from __future__ import annotations

import os

for var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "NUMBA_NUM_THREADS"):
    os.environ.setdefault(var, "1")

import argparse  # noqa: E402
import sys  # noqa: E402
from pathlib import Path  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from calib.config import load_yaml_model  # noqa: E402
from calib.sim.glmb_paper import GlmbPaperConfig, simulate_glmb_paper, truth_profile  # noqa: E402
from slam_runtime.config import SlamConfig, override, with_filter  # noqa: E402
from slam_runtime.run import run_slam  # noqa: E402

CLUTTER = (1.0, 5.0, 10.0, 15.0)
FILTERS = ("rbphd", "lmb", "glmb")


def load() -> str:
    return " ".join(Path("/proc/loadavg").read_text().split()[:3]) if Path("/proc/loadavg").exists() else "n/a"


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--frames", type=int, default=None, help="frames per run (default: the whole run, 451)")
    ap.add_argument("--particles", type=int, default=None, help="default: the config's (100)")
    ap.add_argument("--config", type=Path, default=ROOT / "benchmarks/configs/glmb_paper.yaml")
    ap.add_argument("--filters", default=",".join(FILTERS), help=f"comma-separated, of {', '.join(FILTERS)} (default: all)")
    a = ap.parse_args()
    base = load_yaml_model(SlamConfig, a.config)
    if a.particles:
        base = override(base, particles=a.particles)
    runs = {c: (simulate_glmb_paper(GlmbPaperConfig(clutter=c), 0), truth_profile(GlmbPaperConfig(clutter=c))) for c in CLUTTER}
    filters = a.filters.split(",")
    # the settings the filters share (survival, birth, gate, samples, ...) carry over, as on `detcal slam sweep --filter`
    cfgs = {f: with_filter(base, f) for f in filters}
    for f in filters:  # compile or load the kernels before timing
        run_slam(*runs[1.0], cfgs[f], seed=1, max_frames=3)
    print(f"glmb-paper, {base.particles} particles, {a.frames or 'all'} frames; load average before: {load()}")
    print(f"{'filter':<8} {'clutter':>7}  {'wall ms/step':>12}  {'cpu ms/step':>11}  stages [ms/step]")
    for f in filters:
        for c in CLUTTER:
            res = run_slam(*runs[c], cfgs[f], seed=1, max_frames=a.frames)
            n = res.stamps.size
            stages = ", ".join(f"{k} {v / n:.1f}" for k, v in res.stage_ms.items() if v / n >= 0.05)
            print(f"{f:<8} {c:>7g}  {res.step_ms.mean():>12.1f}  {res.step_cpu_ms.mean():>11.1f}  {stages}")
    print(f"load average after: {load()}")


if __name__ == "__main__":
    main()
