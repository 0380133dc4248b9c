"""Runs with no settings file (the defaults and what the log and the profile give) beside the tuned settings files.

* rfs-sim (``detcal simulate rfs-sim``): worlds x filter seeds, with the profile of the simulator's true statistics;
  no settings (the default particle count) and ``benchmarks/configs/rfs_sim.yaml``;
* Victoria Park (skipped when ``../shared/data`` is absent): RB-PHD, 10 particles, seeds, the self-calibrated
  profile; no settings but the particle count and ``benchmarks/configs/victoria_park.yaml``.

The settings are made as ``detcal slam run`` makes them (:class:`detcal.pipelines.slam_run.SettingsRequest`,
then :meth:`~detcal.pipelines.slam_run.SettingsRequest.derived`).

Run: ``python benchmarks/bench_defaults.py [--parts sim,vp] [--worlds 1-3] [--seeds 0-2] [--vp-seeds 0-2]
[--frames N]``. Prints one row per run and the medians.
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
from benchmarks.common import SHARED_DATA, VP_PROFILES, ints  # noqa: E402

from calib.io.registry import ReadOptions, read_log  # noqa: E402
from calib.sim.rfs import simulate_rfs, truth_profile  # noqa: E402
from detcal.pipelines.slam_run import SettingsRequest  # noqa: E402
from profiles.parameters import RfsSimConfig  # noqa: E402
from profiles.store import load_profile_file  # noqa: E402
from slam_runtime.run import evaluate, run_slam  # noqa: E402

#: the shared data beside the repository (or beside the folder of its worktrees)
VP = SHARED_DATA / "victoria_park"


def one(log, prof, request: SettingsRequest, seed: int, frames: int | None = None) -> dict:
    cfg, _, _ = request.derived(log, prof)
    res = run_slam(log, prof, cfg, seed, max_frames=frames)
    m = evaluate(log, res, cfg=cfg)
    m["cpu_ms_per_step_median"] = float(np.median(res.step_cpu_ms[1:]))
    m["particles"] = cfg.particles
    m["features"] = int(res.map_xy.shape[0])
    return m


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--parts", default="sim,vp")
    ap.add_argument("--worlds", default="1-3")
    ap.add_argument("--seeds", default="0-2")
    ap.add_argument("--vp-seeds", default="0-2")
    ap.add_argument("--frames", type=int, default=None, help="Victoria Park: the first N frames only")
    a = ap.parse_args()
    parts = set(a.parts.split(","))
    print("load average:", " ".join(f"{x:.2f}" for x in os.getloadavg()), flush=True)
    if "sim" in parts:
        sc = RfsSimConfig()
        prof = truth_profile(sc)
        for label, req in (("no config", SettingsRequest()), ("rfs_sim.yaml", SettingsRequest(config=ROOT / "benchmarks/configs/rfs_sim.yaml"))):
            rows = []
            for w in ints(a.worlds):
                log = simulate_rfs(sc, w)
                for s in ints(a.seeds):
                    m = one(log, prof, req, s)
                    rows.append(m)
                    print(
                        f"rfs-sim {label:<13} world {w} seed {s} ({m['particles']} particles): mapped {m['landmarks_mapped']}/{m['landmarks_true']}, "
                        f"final error {m['final_position_error_vs_ground_truth_m']:.3f} m, OSPA {m['map_ospa']:.3f}, "
                        f"RMSE {m['trajectory_rmse_vs_ground_truth_m']:.3f} m, CPU {m['cpu_ms_per_step_mean']:.2f} ms/step",
                        flush=True,
                    )
            print(
                f"rfs-sim {label}: mapped min {min(r['landmarks_mapped'] for r in rows)}, final error max "
                f"{max(r['final_position_error_vs_ground_truth_m'] for r in rows):.3f} m, OSPA max {max(r['map_ospa'] for r in rows):.3f}",
                flush=True,
            )
    if "vp" in parts:
        if not VP.is_dir():
            print(f"Victoria Park skipped: {VP} not found")
            return
        log = read_log(VP, None, ReadOptions())
        prof = load_profile_file(VP_PROFILES["rbphd"])
        for label, req in (
            ("no config", SettingsRequest(particles=10, filter="rbphd")),
            ("victoria_park.yaml", SettingsRequest(config=ROOT / "benchmarks/configs/victoria_park.yaml", particles=10)),
        ):
            for s in ints(a.vp_seeds):
                m = one(log, prof, req, s, a.frames)
                print(
                    f"VP {label:<18} seed {s}: RMSE vs GPS {m['trajectory_rmse_vs_gps_m']:.2f} m (odometry {m['odometry_rmse_vs_gps_m']:.2f}), "
                    f"{m['features']} features, CPU {m['cpu_ms_per_step_median']:.2f} ms/step median, frames {m['frames']}",
                    flush=True,
                )


if __name__ == "__main__":
    main()
