"""RB-PHD-SLAM speed and accuracy: the rfs-sim scenario and Victoria Park at 10, 50 and 200 particles,
the per-stage split, and whether resampling stays as cheap at step 8,000 as at step 1,000.

Run: ``python benchmarks/bench_slam.py [--quick] [--parts sim,long,vp]``. Single process, BLAS pinned to one
thread. ms/step is the filter's own time per frame (motion, P_D, update, weighting, merging,
resampling); the per-stage split adds the measurement source ("detect"). Victoria Park is
skipped when ``../shared/data`` is absent. The machine's load is printed first: compare the
rows of one run with each other, not with another machine's.
"""

from __future__ import annotations

import os

for var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "NUMBA_NUM_THREADS"):
    os.environ.setdefault(var, "1")

import argparse  # noqa: E402
import sys  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from benchmarks.common import SHARED_DATA, VP_PROFILES  # noqa: E402
from calib.config import load_yaml_model  # noqa: E402
from calib.io.registry import ReadOptions, read_log  # noqa: E402
from calib.sim.rfs import RfsSimConfig, simulate_rfs, truth_profile  # noqa: E402
from profiles.store import load_profile_file  # noqa: E402
from slam_runtime.config import SlamConfig, override  # noqa: E402
from slam_runtime.run import evaluate, run_slam  # noqa: E402

VP = SHARED_DATA / "victoria_park"
STAGES = ("predict", "proposal", "pd", "update", "weight", "merge", "resample", "detect")


def row(name, n, seed, res, m) -> None:
    ms = res.step_ms[1:]
    cpu = res.step_cpu_ms[1:]
    split = "  ".join(f"{k} {res.stage_ms.get(k, 0.0) / res.stamps.size:5.2f}" for k in STAGES)
    acc = []
    for key, label, fmt in (
        ("landmarks_mapped", "mapped", "{:d}/{}"),
        ("final_position_error_vs_ground_truth_m", "final err", "{:.3f} m"),
        ("map_ospa", "OSPA", "{:.3f}"),
        ("trajectory_rmse_vs_ground_truth_m", "RMSE", "{:.3f} m"),
        ("trajectory_rmse_vs_gps_m", "RMSE vs GPS", "{:.2f} m"),
    ):
        if key in m:
            acc.append(f"{label} " + (fmt.format(m[key], m.get("landmarks_true")) if key == "landmarks_mapped" else fmt.format(m[key])))
    print(
        f"{name:<14} {n:>4} p  seed {seed}  {ms.mean():7.2f} ms/step mean {np.median(ms):7.2f} median (CPU {cpu.mean():6.2f} mean)  | {split} |  {', '.join(acc)}",
        flush=True,
    )


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--quick", action="store_true", help="fewer seeds and frames")
    ap.add_argument("--long", type=int, default=10_000, help="steps of the long rfs-sim run (resampling cost)")
    ap.add_argument("--parts", default="sim,long,vp", help="comma-separated: sim (rfs-sim at 10/50/200), long (resampling cost), vp")
    a = ap.parse_args()
    parts = set(a.parts.split(","))
    if not parts <= {"sim", "long", "vp"}:
        ap.error(f"--parts: unknown part(s) {', '.join(sorted(parts - {'sim', 'long', 'vp'}))}")
    print("load average:", " ".join(f"{x:.2f}" for x in os.getloadavg()))
    seeds = [0] if a.quick else [0, 1, 2]

    # rfs-sim: the C++ RFS-SLAM library's scenario, 1,000 steps, world seed 1
    sim_cfg = RfsSimConfig()
    log = simulate_rfs(sim_cfg, 1)
    prof = truth_profile(sim_cfg)
    cfg = load_yaml_model(SlamConfig, ROOT / "benchmarks/configs/rfs_sim.yaml")
    for n in (10, 50, 200) if "sim" in parts else ():
        for sd in seeds:
            c = override(cfg, particles=n)
            res = run_slam(log, prof, c, seed=sd)
            row("rfs-sim", n, sd, res, evaluate(log, res, cfg=c))

    if "long" in parts:
        long_run(cfg, sim_cfg, a.long)
    if "vp" in parts:
        victoria_park(a.quick)


def long_run(cfg, sim_cfg, steps) -> None:
    """Resampling cost over a long run: steps ~1,000 against ~8,000, resampling at every step (the worst case)."""
    long = simulate_rfs(RfsSimConfig(steps=steps, landmarks=max(50, steps // 20)), 2)
    c = override(cfg, particles=50, resample_ess=1.0)
    res = run_slam(long, truth_profile(sim_cfg), c, seed=0)
    for at in (1000, 8000):
        sl = slice(at - 100, at + 100)
        print(
            f"long rfs-sim ({steps} steps, 50 particles, resampling every step): steps {at - 100}-{at + 100}: "
            f"resampling {res.resample_ms[sl].mean():.3f} ms/step, whole step {res.step_ms[sl].mean():.2f} ms (CPU {res.step_cpu_ms[sl].mean():.2f}), "
            f"components/particle {res.components[sl].mean():.0f}",
            flush=True,
        )


def victoria_park(quick: bool) -> None:
    """Victoria Park with the self-calibrated profile: 10 particles over the full run (1,500 frames with
    --quick), 50 and 200 over the first 1,500 frames."""
    if not VP.is_dir():
        print(f"Victoria Park skipped: {VP} not found")
        return
    vp = read_log(VP, None, ReadOptions())
    prof = load_profile_file(VP_PROFILES["rbphd"])
    cfg = load_yaml_model(SlamConfig, ROOT / "benchmarks/configs/victoria_park.yaml")
    for n in (10, 50, 200):
        frames = None if n == 10 and not quick else 1500
        c = override(cfg, particles=n)
        res = run_slam(vp, prof, c, seed=0, max_frames=frames)
        row(f"VP{'' if frames is None else f' {frames} fr'}", n, 0, res, evaluate(vp, res, cfg=c))


if __name__ == "__main__":
    main()
