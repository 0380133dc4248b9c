"""MH-FastSLAM beside RB-PHD and delta-GLMB: rfs-sim, the simulated park, Victoria Park, UTIAS robot 1, and
glmb-paper at 1, 5, 10 and 15 false alarms per scan (the thesis's claim, ch. 7: RFS filters degrade less with clutter).

Run: ``python benchmarks/bench_fastslam.py [--data ../shared/data] [--parts rfs,park,vp,utias,clutter] [--filters mhfastslam,rbphd,glmb]
[--seeds 0-2] [--workers 2] [--csv runs.csv] [--set key=value ...]``. Each part's settings:

* rfs: ``detcal simulate rfs-sim --seed W`` for worlds 1-3 (``--rfs-worlds``), ``benchmarks/configs/rfs_sim.yaml``
  (200 particles, the optimal proposal), the truth profile; map OSPA c = 1 m, p = 1;
* park: ``detcal simulate park --seed W --config benchmarks/configs/small_park.yaml`` for worlds 1-4
  (``--park-worlds``), the bundled laser profile ``sim-park-laser``, 20 particles (the park comparisons of
  docs/results/labelled-real.md); map OSPA c = 1 m against the trees;
* vp: Victoria Park, ``benchmarks/configs/victoria_park.yaml`` (10 particles), RB-PHD's self-calibrated profile
  ``benchmarks.common.VP_PROFILES``: RB-PHD's for RB-PHD and MH-FastSLAM, delta-GLMB's own for delta-GLMB, as in
  bench_real_filters.py; RMSE against GPS after a rigid fit (no landmark truth);
* utias: UTIAS dataset 1 robot 1, its camera profile calibrated on robots 2-5, ``benchmarks/configs/utias_mrclam/robot1.yaml``;
  map OSPA c = 1 m against the 15 surveyed landmarks;
* clutter: ``detcal simulate glmb-paper --clutter C --seed W`` for C in 1, 5, 10, 15 and worlds 1-5 (``--clutter-worlds``),
  ``benchmarks/configs/glmb_paper_optimal.yaml`` (300 particles, the optimal proposal), map OSPA c = 0.5 m.

Every filter takes the part's settings with only its kind changed (``slam_runtime.config.with_filter``: the shared
settings carry over, the rest are the filter's defaults). Each run is one process on one core (BLAS pinned);
CPU is the process's CPU time per step. Prints per part and filter the mean (+- standard error over the runs) of
the pose RMSE, the map OSPA, the landmarks mapped, the map's features and the CPU per step; for clutter, each
filter's OSPA per rate and its rise from 1 to 15 false alarms, paired by world and seed, and MH-FastSLAM less each
RFS filter at every rate. Same arguments, same figures.
"""

from __future__ import annotations

import os

for var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "NUMBA_NUM_THREADS"):
    os.environ.setdefault(var, "1")

import argparse  # noqa: E402
import functools  # noqa: E402
import sys  # noqa: E402
from multiprocessing import Pool  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from benchmarks.common import SHARED_DATA, VP_PROFILES, append_row, ints, parse_set, read_rows  # noqa: E402

DATA = SHARED_DATA
RATES = (1.0, 5.0, 10.0, 15.0)


def configured(cfg, kind: str):
    """``cfg`` with the map filter ``kind`` (the settings the filters share carry over)."""
    from slam_runtime.config import with_filter

    return with_filter(cfg, kind)


@functools.lru_cache(maxsize=4)
def _utias(robot: int):
    from calib.detlevel import DetectionCalibConfig, calibrate_detections
    from calib.io.utias import read_utias

    root = DATA / "utias_mrclam/dataset1"
    logs = {r: read_utias(root, robot=r) for r in range(1, 6)}
    prof = calibrate_detections([logs[r] for r in range(1, 6) if r != robot], DetectionCalibConfig(), name=f"utias-not{robot}", version="1.0.0").profile
    return logs[robot], prof


@functools.lru_cache(maxsize=1)
def _vp():
    from calib.io.registry import read_log

    return read_log(DATA / "victoria_park")


def scenario(part: str, world: float, clutter: float | None):
    """(log, profile, settings, OSPA cut-off c) of one part's world."""
    from calib.config import load_yaml_model
    from profiles.store import load_profile_file
    from slam_runtime.config import SlamConfig, override

    if part == "rfs":
        from calib.sim.rfs import RfsSimConfig, simulate_rfs, truth_profile

        sim = RfsSimConfig()
        return simulate_rfs(sim, int(world)), truth_profile(sim), load_yaml_model(SlamConfig, ROOT / "benchmarks/configs/rfs_sim.yaml"), 1.0
    if part == "park":
        from calib.sim.park import ParkConfig, simulate_park
        from profiles.store import bundled

        log = simulate_park(load_yaml_model(ParkConfig, ROOT / "benchmarks/configs/small_park.yaml"), seed=int(world)).log
        return log, load_profile_file(bundled("sim-park-laser", "1.0.0")), override(SlamConfig(), particles=20), 1.0
    if part == "clutter":
        from calib.sim.glmb_paper import GlmbPaperConfig, simulate_glmb_paper, truth_profile

        g = GlmbPaperConfig(clutter=clutter)
        return simulate_glmb_paper(g, int(world)), truth_profile(g), load_yaml_model(SlamConfig, ROOT / "benchmarks/configs/glmb_paper_optimal.yaml"), 0.5
    if part == "vp":
        return _vp(), load_profile_file(VP_PROFILES["rbphd"]), load_yaml_model(SlamConfig, ROOT / "benchmarks/configs/victoria_park.yaml"), 1.0
    if part == "utias":
        log, prof = _utias(int(world))
        return log, prof, load_yaml_model(SlamConfig, ROOT / f"benchmarks/configs/utias_mrclam/robot{int(world)}.yaml"), 1.0
    raise SystemExit(f"bench_fastslam: unknown part {part!r}")


def one(job: tuple) -> dict:
    part, kind, world, seed, clutter, sets = job
    from profiles.store import load_profile_file
    from slam_runtime.config import override
    from slam_runtime.run import evaluate, run_slam

    log, prof, cfg, c = scenario(part, world, clutter)
    if part == "vp" and kind in ("lmb", "glmb"):
        prof = load_profile_file(VP_PROFILES[kind])
    cfg = configured(cfg, kind)
    if sets:
        cfg = override(cfg, **dict(parse_set(x) for x in sets))
    res = run_slam(log, prof, cfg, seed)
    m = evaluate(log, res, c, 1.0, cfg)
    ref = "ground_truth" if "trajectory_rmse_vs_ground_truth_m" in m else "gps"
    return {
        "part": part, "filter": kind, "world": world, "seed": seed, "clutter": clutter if clutter is not None else float("nan"),
        "rmse": m[f"trajectory_rmse_vs_{ref}_m"], "reference": ref, "ospa": m.get("map_ospa", float("nan")),
        "mapped": m.get("landmarks_mapped", -1), "true": m.get("landmarks_true", -1), "features": int(res.map_xy.shape[0]),
        "cpu": m["cpu_ms_per_step_mean"], "steps": m["frames"], "sets": " ".join(sets),
    }


def key(part, kind, world, seed, clutter, sets) -> tuple:
    """A run's identity: a job's fields, or a row's (read back from the CSV, where no clutter is NaN and the --set
    items one text)."""
    c = -1.0 if clutter is None or float(clutter) != float(clutter) else float(clutter)
    return (str(part), str(kind), int(world), int(seed), c, sets if isinstance(sets, str) else " ".join(sets))


def warm(filters: tuple[str, ...]) -> None:
    """Pool initializer: a short rfs-sim run of each filter, so that no timed run pays for loading (or compiling) the
    compiled kernels."""
    from calib.sim.rfs import RfsSimConfig, simulate_rfs, truth_profile
    from slam_runtime.config import SlamConfig, override
    from slam_runtime.run import run_slam

    sim = RfsSimConfig(steps=60)
    for kind in filters:
        run_slam(simulate_rfs(sim, 0), truth_profile(sim), configured(override(SlamConfig(), particles=4), kind), 0)


def _ms(x) -> str:
    x = np.asarray(x, dtype=float)
    if x.size == 0 or np.all(np.isnan(x)):
        return "n/a"
    se = x.std(ddof=1) / np.sqrt(x.size) if x.size > 1 else float("nan")
    return f"{x.mean():.3f} +- {se:.3f}"


def report(runs: list[dict], part: str, filters: list[str]) -> None:
    rows = [o for o in runs if o["part"] == part]
    if not rows:
        return
    ref = rows[0]["reference"]
    n = ", ".join(f"{f} {sum(o['filter'] == f for o in rows)}" for f in filters)
    print(f"\n{part}: runs {n}; pose RMSE vs {ref}")
    for f in filters:
        r = [o for o in rows if o["filter"] == f and (part != "clutter" or o["clutter"] == RATES[-1])]
        if part == "clutter" or not r:  # (a stopped measurement: a filter with no run yet)
            continue
        mapped = f"{np.mean([o['mapped'] for o in r]):.1f} of {r[0]['true']}" if r[0]["true"] > 0 else "n/a"
        print(
            f"  {f:<11} RMSE {_ms([o['rmse'] for o in r])} m  map OSPA {_ms([o['ospa'] for o in r])}  landmarks mapped {mapped}"
            f"  features {np.mean([o['features'] for o in r]):.1f}  CPU {_ms([o['cpu'] for o in r])} ms/step",
            flush=True,
        )
    if part == "clutter":
        _clutter(rows, filters)


def _clutter(rows: list[dict], filters: list[str]) -> None:
    by = {(o["filter"], o["clutter"], o["world"], o["seed"]): o for o in rows}
    keys = sorted({(o["world"], o["seed"]) for o in rows})
    for f in filters:
        print(f"  {f}")
        for c in RATES:
            r = [by[(f, c, *k)] for k in keys if (f, c, *k) in by]
            if not r:
                continue
            print(
                f"    {c:>4g} false alarms/scan: map OSPA {_ms([o['ospa'] for o in r])}  RMSE {_ms([o['rmse'] for o in r])} m"
                f"  mapped {np.mean([o['mapped'] for o in r]):.1f} of {r[0]['true']}  features {np.mean([o['features'] for o in r]):.1f}"
                f"  CPU {_ms([o['cpu'] for o in r])} ms/step",
                flush=True,
            )
            print("      per world (seed): " + ", ".join(f"{o['world']} ({o['seed']}) {o['ospa']:.3f}" for o in sorted(r, key=lambda o: (o["world"], o["seed"]))), flush=True)
        rise = [by[(f, RATES[-1], *k)]["ospa"] - by[(f, RATES[0], *k)]["ospa"] for k in keys if (f, RATES[0], *k) in by and (f, RATES[-1], *k) in by]
        print(f"    rise of the map OSPA from {RATES[0]:g} to {RATES[-1]:g}, paired: {_ms(rise)}", flush=True)
    base = filters[0]
    for f in filters[1:]:
        for c in RATES:
            d = [by[(base, c, *k)]["ospa"] - by[(f, c, *k)]["ospa"] for k in keys if (base, c, *k) in by and (f, c, *k) in by]
            print(f"  {base} - {f} at {c:g}: map OSPA {_ms(d)} ({sum(x > 0 for x in d)} of {len(d)} runs higher)", flush=True)
        dr = [
            (by[(base, RATES[-1], *k)]["ospa"] - by[(base, RATES[0], *k)]["ospa"]) - (by[(f, RATES[-1], *k)]["ospa"] - by[(f, RATES[0], *k)]["ospa"])
            for k in keys
            if all((g, c, *k) in by for g in (base, f) for c in (RATES[0], RATES[-1]))
        ]
        print(f"  {base}'s rise less {f}'s: {_ms(dr)}", flush=True)


def main() -> None:
    global DATA
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--data", type=Path, default=DATA, help="folder holding utias_mrclam/ and victoria_park/")
    ap.add_argument("--parts", default="rfs,park,vp,utias,clutter")
    ap.add_argument("--filters", default="mhfastslam,rbphd,glmb", help="the first is compared with the others")
    ap.add_argument("--seeds", default="0-2", help="filter seeds (the clutter part: --clutter-seeds)")
    ap.add_argument("--rfs-worlds", default="1-3")
    ap.add_argument("--park-worlds", default="1-4")
    ap.add_argument("--clutter-worlds", default="1-5")
    ap.add_argument("--clutter-seeds", default="0")
    ap.add_argument("--set", dest="sets", action="append", default=[], help="override a setting of every run: key=value")
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--report-only", action="store_true", help="print the figures of the runs already kept, run nothing")
    ap.add_argument(
        "--csv", type=Path, default=None,
        help="every run's figures, one row per run, added as each run ends; the runs already there are read back and not run again",
    )
    a = ap.parse_args()
    DATA = a.data  # (the workers are forked after this)
    parts, filters, seeds = a.parts.split(","), a.filters.split(","), ints(a.seeds)
    jobs = []
    for part in parts:
        if part == "vp" and not (DATA / "victoria_park").is_dir():
            print(f"Victoria Park not found at {DATA / 'victoria_park'}: skipped")
            continue
        if part == "utias" and not (DATA / "utias_mrclam/dataset1").is_dir():
            print(f"UTIAS dataset 1 not found at {DATA / 'utias_mrclam/dataset1'}: skipped")
            continue
        worlds = {"rfs": ints(a.rfs_worlds), "park": ints(a.park_worlds), "clutter": ints(a.clutter_worlds), "vp": [0], "utias": [1]}[part]
        rates = RATES if part == "clutter" else (None,)
        sd = ints(a.clutter_seeds) if part == "clutter" else seeds
        jobs += [(part, f, w, s, c, tuple(a.sets)) for f in filters for c in rates for w in worlds for s in sd]
    done = {key(o["part"], o["filter"], o["world"], o["seed"], o["clutter"], o["sets"] or ""): o for o in (read_rows(a.csv) if a.csv else [])}
    runs = [done[key(*j)] for j in jobs if key(*j) in done]
    todo = [j for j in jobs if key(*j) not in done]
    todo = [] if a.report_only else todo
    back = f" ({len(runs)} of {len(jobs)} read back from {a.csv})" if runs else ""
    print(f"CPUs {os.cpu_count()}, load average {'/'.join(f'{x:.1f}' for x in os.getloadavg())}; {len(todo)} runs on {a.workers} workers{back}", flush=True)
    if todo:
        with Pool(a.workers, initializer=warm, initargs=(tuple(filters),)) as pool:
            for o in pool.imap_unordered(one, todo, chunksize=1):  # each run kept as it ends
                runs.append(o)
                if a.csv is not None:
                    append_row(a.csv, o)
                print(f"  run {len(runs)}/{len(jobs)}: " + ", ".join(f"{k} {v:.4g}" if isinstance(v, float) else f"{k} {v}" for k, v in o.items()), flush=True)
    for part in parts:
        report(runs, part, filters)


if __name__ == "__main__":
    main()
