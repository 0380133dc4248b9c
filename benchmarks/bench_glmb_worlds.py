"""A labelled filter's map on the held-out glmb-paper worlds, many runs per setting:
``python benchmarks/bench_glmb_worlds.py [--clutter 1,15] [--worlds 2,3,4,5] [--seeds 0-14] [--filter glmb]
[--filter lmb] [--config C.yaml] [--set key=value ...] [--pair-set key=value ...] [--true-poses] [--clutter-draws 0-9]
[--csv runs.csv] [--workers 2]``.

Each run is ``detcal simulate glmb-paper --clutter C --seed W`` (world W) and one filter seed with the
settings of ``benchmarks/configs/glmb_paper_optimal.yaml`` or ``--config`` (``--set`` overrides any, e.g.
``--set particles=100 --set filter.samples=400``), evaluated as ``detcal slam sweep`` does (map OSPA c = 0.5,
p = 1). World 1 is the paper-protocol table's and is left out by default, so that settings are chosen on
other worlds. Per clutter rate it prints the mean map OSPA and its standard error, the pose RMSE, GOSPA's
landmarks missed and false per run, the localisation error per landmark found and the mean CPU per step, and
with several worlds or several clutter draws each one's mean map OSPA and its standard error.
``--true-poses`` gives every particle the true pose at every scan (``poses: ground_truth``, as ``--set
poses=ground_truth``; mapping only: what the map filter loses
by itself). ``--clutter-draws`` runs each world under other draws of its false alarms (the path, controls and
detections kept: ``simulate_glmb_paper(..., clutter_draw=D)``), to tell a world's own clutter draw from the
filter. With two ``--filter`` each run is made with both and the paired difference (first - second, matched by
clutter rate, world, clutter draw and filter seed) is printed with its standard error and the number of runs the
first is lower in. ``--pair-set key=value`` (repeatable) pairs one filter with itself under those settings instead
(e.g. ``--pair-set filter.release_unseen=false``: the exact delta-GLMB beside the hybrid); the second's rows are
labelled ``glmb[filter.release_unseen=false]``. ``--csv`` writes every run's figures, one row per run, as each run
ends; the runs already in it are read back and not run again (a stopped measurement resumes). Same arguments, same
figures; BLAS is pinned to one thread per worker.
"""

from __future__ import annotations

import os

for var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "NUMBA_NUM_THREADS"):
    os.environ.setdefault(var, "1")

import argparse  # noqa: E402
import sys  # noqa: E402
from multiprocessing import Pool  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from benchmarks.common import append_row, ints, parse_set, read_rows  # noqa: E402
from calib.config import load_yaml_model  # noqa: E402
from calib.sim.glmb_paper import GlmbPaperConfig, simulate_glmb_paper, truth_profile  # noqa: E402
from slam_runtime.config import SlamConfig, override, with_filter  # noqa: E402
from slam_runtime.metrics import gospa, ospa  # noqa: E402
from slam_runtime.run import evaluate, run_slam  # noqa: E402
from profiles.override import updated

CONFIG = ROOT / "benchmarks/configs/glmb_paper_optimal.yaml"


def one(job: tuple) -> dict:
    clutter, world, seed, label, sets, true_poses, draw, config = job
    kind = label.split("[", 1)[0]
    cfg = load_yaml_model(SlamConfig, config)
    if kind != cfg.filter.kind:
        cfg = with_filter(cfg, kind)
    cfg = override(cfg, **dict(parse_set(x) for x in sets))
    g = GlmbPaperConfig(clutter=clutter)
    log, prof = simulate_glmb_paper(g, world, draw), truth_profile(g)
    if true_poses:
        cfg = override(cfg, poses="ground_truth")
    # the labelled filters run with seen_mean, which records the mean at every step, and the map is then placed both
    # ways (the runs do not depend on the placement): "ospa" is the configured placement's, "ospa_other" the other's
    placing = getattr(cfg.filter, "map_estimate", None)
    if placing is not None:
        cfg = override(cfg, **{"filter.map_estimate": "seen_mean"})
    last = _Last()
    res = run_slam(log, prof, cfg, seed=seed, hooks=(last,))
    m = evaluate(log, res, 0.5, 1.0, cfg)
    est, other = res.map_xy, float("nan")
    if placing is not None:
        best = last.placed("best")
        est, alt = (best, res.map_xy) if placing == "best" else (res.map_xy, best)
        other = ospa(alt, log.landmarks.xy, 0.5, 1.0)
    g = gospa(est, log.landmarks.xy, 0.5, 1.0)
    found = max(m["landmarks_true"] - g["n_missed"], 1)
    return {
        "filter": label, "clutter": clutter, "world": world, "draw": draw, "seed": seed, "ospa": ospa(est, log.landmarks.xy, 0.5, 1.0), "ospa_other": other,
        "rmse": m["trajectory_rmse_vs_ground_truth_m"], "rmse_mean": m["mean_trajectory_rmse_vs_ground_truth_m"], "missed": g["n_missed"],
        "false": g["n_false"], "loc": g["localisation"] / found, "cpu": m["cpu_ms_per_step_mean"],
    }


def _key(label, clutter, world, draw, seed) -> tuple:
    """A run's identity (a row read back from the CSV holds no clutter draw as an empty text)."""
    return (str(label), float(clutter), int(world), -1 if draw in (None, "") else int(draw), int(seed))


def _job_key(job: tuple) -> tuple:
    clutter, world, seed, label, _sets, _true, draw, _config = job
    return _key(label, clutter, world, draw, seed)


class _Last:
    """Hook: keeps the particle loop, to place the run's map estimate another way at the end."""

    name = "last"

    def __call__(self, k: int, slam) -> float:
        self.slam = slam
        return 0.0

    def placed(self, how: str) -> np.ndarray:
        """The run's map estimate (positions) with ``map_estimate: how``."""
        mf = self.slam.mf
        mf.cfg = updated(mf.cfg, {"map_estimate": how})
        return mf.feature.position(self.slam.map_estimate()[0])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--clutter", default="1,15", help="false alarms per scan, comma-separated")
    ap.add_argument("--worlds", default="2,3,4,5", help="simulator seeds: 2-5 or 2,4")
    ap.add_argument("--seeds", default="0-14", help="filter seeds: 0-14 or 0,3")
    ap.add_argument("--filter", dest="filters", action="append", choices=("glmb", "lmb", "rbphd"), help="glmb (default); twice to pair two")
    ap.add_argument("--config", type=Path, default=CONFIG, help="the settings (default: glmb_paper_optimal.yaml)")
    ap.add_argument("--csv", type=Path, default=None, help="every run's figures, one row per run as it ends; runs already there are not run again")
    ap.add_argument("--pair-set", dest="pair_sets", action="append", default=[], help="pair the filter with itself under this setting: key=value")
    ap.add_argument("--set", dest="sets", action="append", default=[], help="override a setting: key=value (repeatable)")
    ap.add_argument("--true-poses", action="store_true", help="every particle at the true pose (mapping only)")
    ap.add_argument("--clutter-draws", default=None, help="other clutter streams of each world: 0-9 (default: the world's own)")
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--report-only", action="store_true", help="print the figures of the runs already kept, run nothing")
    a = ap.parse_args()
    filters = a.filters or ["glmb"]
    if len(filters) > 2 or len(set(filters)) < len(filters) or (a.pair_sets and len(filters) > 1):
        sys.exit("bench_glmb_worlds: --filter takes one filter, or two different ones to pair (one with --pair-set)")
    variants = [(f, a.sets) for f in filters]
    if a.pair_sets:
        variants.append((f"{filters[0]}[{' '.join(a.pair_sets)}]", [*a.sets, *a.pair_sets]))
        filters = [v[0] for v in variants]
    if any(x.split("=", 1)[0].strip() == "map_refine" for x in [*a.sets, *a.pair_sets]):
        # the runs place the map two ways after the run (seen_mean and best); map_refine would refine only the first
        sys.exit("bench_glmb_worlds: map_refine is not measured here; run detcal slam sweep with a config that holds it")
    rates = [float(c) for c in a.clutter.split(",")]
    draws = [None] if a.clutter_draws is None else ints(a.clutter_draws)
    jobs = [  # the filters of one pair side by side, so that a stopped measurement keeps whole pairs
        (c, w, s, f, sets, a.true_poses, d, a.config)
        for c in rates for w in ints(a.worlds) for d in draws for s in ints(a.seeds) for f, sets in variants
    ]
    back = [{**o, "draw": None if o["draw"] == "" else o["draw"]} for o in (read_rows(a.csv) if a.csv else [])]
    done = {_key(o["filter"], o["clutter"], o["world"], o["draw"], o["seed"]): o for o in back}
    runs = [done[k] for j in jobs if (k := _job_key(j)) in done]
    todo = [j for j in jobs if _job_key(j) not in done]
    todo = [] if a.report_only else todo
    if runs:
        print(f"{len(runs)} of {len(jobs)} runs read back from {a.csv}", flush=True)
    if todo:
        with Pool(a.workers) as pool:
            for o in pool.imap_unordered(one, todo, chunksize=1):  # each run kept as it ends
                runs.append(o)
                if a.csv is not None:
                    append_row(a.csv, o)
    for f in filters:
        _report([o for o in runs if o["filter"] == f], f, a, rates, draws)
    if len(filters) == 2:
        _paired(runs, filters, rates)


def _report(out: list, kind: str, a, rates: list, draws: list) -> None:
    """One filter's figures per clutter rate."""
    if not out:
        return
    config = "" if a.config == CONFIG else f"{a.config.name}, "
    print(
        f"{kind}, worlds {a.worlds}, filter seeds {a.seeds}, {config}{' '.join(a.sets) or 'the config'}{', true poses' if a.true_poses else ''}"
        f"{'' if a.clutter_draws is None else f', clutter draws {a.clutter_draws}'}"
    )
    worlds = ints(a.worlds)
    for c in rates:
        if not any(o["clutter"] == c for o in out):  # (a stopped measurement: no run at this rate yet)
            continue
        r = {k: np.array([o[k] for o in out if o["clutter"] == c], dtype=float) for k in out[0] if k not in ("filter", "clutter", "world", "draw", "seed")}
        print(
            f"  {c:g} false alarms per scan ({r['ospa'].size} runs): map OSPA {_mean_se(r['ospa'])}"
            f" (placed the other way: {_mean_se(r['ospa_other'])})"
            f"  pose RMSE {r['rmse'].mean():.3f} m (weighted mean {r['rmse_mean'].mean():.3f} m)"
            f"  missed / false {r['missed'].mean():.2f} / {r['false'].mean():.2f}"
            f"  localisation per landmark found {r['loc'].mean():.4f} m  CPU {r['cpu'].mean():.1f} ms/step",
            flush=True,
        )
        if len(worlds) > 1:  # the spread between worlds: how much one world's data draw decides
            print("    per world: " + _per(out, c, "world", worlds), flush=True)
        if len(draws) > 1:  # the spread between clutter draws of the same worlds
            print("    per clutter draw: " + _per(out, c, "draw", draws), flush=True)


def _paired(runs: list, filters: list, rates: list) -> None:
    """The first filter's map OSPA less the second's, run by run (same clutter rate, world, clutter draw, filter seed)."""
    key = {(o["filter"], o["clutter"], o["world"], o["draw"], o["seed"]): o for o in runs}
    print(f"{filters[0]} - {filters[1]}, paired")
    for c in rates:
        pairs = [(o, key[(filters[1], *k[1:])]) for k, o in key.items() if k[0] == filters[0] and k[1] == c and (filters[1], *k[1:]) in key]
        if not pairs:
            continue
        d = np.array([x["ospa"] - y["ospa"] for x, y in pairs])
        dm = np.array([x["missed"] - y["missed"] for x, y in pairs], dtype=float)
        dl = np.array([x["loc"] - y["loc"] for x, y in pairs])
        print(
            f"  {c:g} false alarms per scan ({d.size} pairs): map OSPA {_mean_se(d)}, {filters[0]} lower in {int((d < 0).sum())}"
            f" (higher in {int((d > 0).sum())});  landmarks missed per run {_mean_se(dm)};  localisation per landmark found {_mean_se(dl)}",
            flush=True,
        )


def _mean_se(x: np.ndarray) -> str:
    """``mean +- standard error`` of the runs x (nan for one run)."""
    se = x.std(ddof=1) / np.sqrt(x.size) if x.size > 1 else float("nan")
    return f"{x.mean():.4f} +- {se:.4f}"


def _per(out: list, clutter: float, key: str, values: list) -> str:
    """Mean map OSPA +- its standard error for each value of ``key`` (world or clutter draw)."""
    return ", ".join(f"{v} {_mean_se(np.array([o['ospa'] for o in out if o['clutter'] == clutter and o[key] == v]))}" for v in values)


if __name__ == "__main__":
    main()
