"""The two-stage scenario of Li & Yang (Sensors 2022) reproduced: LMB and delta-GLMB on static and moving feature
points, 100 Monte Carlo runs, OSPA (p = 1, c = 100 m) at every step (their Fig. 15) and CPU time (their Table 2).

Run: ``python benchmarks/bench_two_stage.py [--runs 0-99] [--paths serpentine] [--cases static,moving]
[--filters lmb,glmb] [--config benchmarks/configs/two_stage.yaml] [--set key=value ...] [--sim key=value ...] [--workers 2]
[--out DIR] [--csv runs.csv] [--figure two-stage-ospa.png]``.

Run i is ``detcal simulate two-stage --seed i`` (``--moving`` for the moving case) with filter seed i and the
settings of ``benchmarks/configs/two_stage.yaml``, the filter kind changed per row; in the moving case the filters
predict the points through the constant-velocity transition (``filter.feature_motion: constant_velocity``; ``--set
filter.feature_motion=static`` gives the static model's figures on the moving points). At step k the estimate is
compared with the feature points the sensor has come within its detection radius of up to k (the traversed map
of the paper's sec. 2.1, M_k = M_k-1 u C(x_k-1)), at their positions at k: OSPA with p = 1 and c = 100 m and its
localisation and cardinality parts (for p = 1 they add up: OSPA = loc + card, card = c (n - m) / n). CPU is the
run's process CPU time (the whole filter over the 100 steps), one process per core, BLAS pinned. Prints per case
and filter the OSPA, loc and card averaged over the steps and at the last step, the features mapped at the end
and the CPU per run and per step, with standard errors over the runs; ``--figure`` draws the mean curves. ``--out DIR``
keeps each run's curves and figures in DIR as it ends (one ``.npz`` per path, case, filter and run) and reads the
runs already there back instead of running them again: a stopped measurement resumes where it stopped (one DIR per
set of ``--config``/``--set``/``--sim`` settings: the files do not record them).
"""

from __future__ import annotations

import os

for var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "NUMBA_NUM_THREADS"):
    os.environ.setdefault(var, "1")

import argparse  # noqa: E402
import csv  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from multiprocessing import Pool  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from benchmarks.common import ints, parse_set  # noqa: E402

CONFIG = ROOT / "benchmarks/configs/two_stage.yaml"
C, P = 100.0, 1.0


class TraversedOSPA:
    """Hook: OSPA (and its cardinality part) of the map estimate against the features seen so far, at their positions
    now (the map); and of the estimates within the detection radius against the features within it (the view)."""

    name = "ospa"

    def __init__(self, features: np.ndarray, poses: np.ndarray, radius: float) -> None:
        self.features, self.poses, self.radius = features, poses, radius  # (T, F, 4), (T, 3)
        d = np.hypot(features[..., 0] - poses[:, None, 0], features[..., 1] - poses[:, None, 1])
        self.inside = d <= radius  # (T, F)
        self.seen = np.logical_or.accumulate(self.inside, axis=0)
        t = features.shape[0]
        self.card, self.view, self.view_card = np.zeros(t), np.zeros(t), np.zeros(t)
        self.n = np.zeros(t, np.int64)

    def __call__(self, k: int, slam) -> float:
        from slam_runtime.metrics import ospa

        x = slam.mf.feature.position(slam.map_estimate()[0])
        self.n[k] = len(x)
        truth = self.features[k, self.seen[k], :2]
        self.card[k] = _card(len(x), len(truth))
        xin = x[np.hypot(x[:, 0] - self.poses[k, 0], x[:, 1] - self.poses[k, 1]) <= self.radius] if len(x) else x
        tin = self.features[k, self.inside[k], :2]
        self.view[k], self.view_card[k] = ospa(xin, tin, C, P), _card(len(xin), len(tin))
        return ospa(x, truth, C, P)


def _card(a: int, b: int) -> float:
    """OSPA's cardinality part for p = 1: c (n - m) / n of two sets of sizes a and b."""
    m, n = sorted((a, b))
    return C * (n - m) / n if n else 0.0


def one(job: tuple) -> dict:
    path, case, kind, run, config, sets, sim_sets = job
    from calib.config import load_yaml_model
    from calib.sim.two_stage import TwoStageConfig, simulate_two_stage, truth_profile
    from slam_runtime.config import SlamConfig, override, with_filter
    from slam_runtime.run import run_slam

    sim_cfg = TwoStageConfig.model_validate({**dict(parse_set(x) for x in sim_sets), "path": path, "moving": case == "moving"})
    sim = simulate_two_stage(sim_cfg, run)
    cfg = with_filter(load_yaml_model(SlamConfig, config), kind)
    changes = {**(MOVING if case == "moving" else {}), **dict(parse_set(x) for x in sets)}  # (--set wins)
    if changes:
        cfg = override(cfg, **changes)
    hook = TraversedOSPA(sim.features, sim.log.reference["ground_truth"].poses, sim_cfg.detection_radius)
    t0 = time.process_time()
    res = run_slam(sim.log, truth_profile(sim_cfg), cfg, run, hooks=(hook,))
    cpu = time.process_time() - t0
    o = res.per_step["ospa"]
    return {
        "path": path, "case": case, "filter": kind, "run": run, "cpu_s": cpu, "cpu_ms_step": float(res.step_cpu_ms.mean()),
        "features_end": int(hook.n[-1]), "seen_end": int(hook.seen[-1].sum()),
        "ospa": o, "card": hook.card, "loc": o - hook.card, "view": hook.view, "view_card": hook.view_card, "view_loc": hook.view - hook.view_card,
    }


#: the settings of the moving case on top of the config: the labelled filters predict the feature points through the
#: constant-velocity transition (slam_runtime.cv_transition; Q = 0.5^2 B B^T, the simulator's)
MOVING: dict = {"filter.feature_motion": "constant_velocity"}


def run_file(folder: Path, job_or_run) -> Path:
    """Where ``--out`` keeps one run: ``{path}-{case}-{filter}-{run:03d}.npz``."""
    p, c, f, r = (job_or_run[k] for k in ("path", "case", "filter", "run")) if isinstance(job_or_run, dict) else job_or_run[:4]
    return folder / f"{p}-{c}-{f}-{int(r):03d}.npz"


def save_run(folder: Path, o: dict) -> None:
    """One run's curves and figures into ``folder`` (written to a temporary name, then renamed: never half a file)."""
    folder.mkdir(parents=True, exist_ok=True)
    path = run_file(folder, o)
    tmp = path.with_suffix(".tmp.npz")
    np.savez(tmp, **{k: np.asarray(v) for k, v in o.items()})
    os.replace(tmp, path)


def load_run(path: Path) -> dict:
    """A run kept by :func:`save_run`, with the types :func:`one` returns."""
    with np.load(path) as z:
        return {k: (z[k] if z[k].ndim else z[k].item()) for k in z.files}


def warm(filters: tuple[str, ...], config: Path) -> None:
    """Pool initializer: one short run of each filter, static and moving, so that no timed run pays for loading (or
    compiling) the compiled kernels."""
    for kind in filters:
        for case in ("static", "moving"):
            one(("serpentine", case, kind, 0, config, (), ("steps=5",)))


def _ms(x) -> str:
    x = np.asarray(x, dtype=float)
    se = x.std(ddof=1) / np.sqrt(x.size) if x.size > 1 else float("nan")
    return f"{x.mean():.2f} +- {se:.2f}"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--runs", default="0-99", help="Monte Carlo runs (simulator and filter seeds)")
    ap.add_argument("--paths", default="serpentine", help="serpentine, spiral or both")
    ap.add_argument("--cases", default="static,moving")
    ap.add_argument("--filters", default="lmb,glmb")
    ap.add_argument("--config", type=Path, default=CONFIG)
    ap.add_argument("--set", dest="sets", action="append", default=[], help="override a setting of every run: key=value")
    ap.add_argument("--sim", dest="sim_sets", action="append", default=[], help="a setting of the scenario: key=value (e.g. steps=400)")
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--report-only", action="store_true", help="print the figures of the runs already kept, run nothing")
    ap.add_argument("--out", type=Path, default=None, help="keep every run here as it ends; the runs already there are read back")
    ap.add_argument("--csv", type=Path, default=None, help="every run's summary figures, one row per run")
    ap.add_argument("--figure", type=Path, default=None, help="the mean OSPA curves (PNG)")
    a = ap.parse_args()
    jobs = [
        (p, c, f, r, a.config, tuple(a.sets), tuple(a.sim_sets))
        for p in a.paths.split(",") for c in a.cases.split(",") for f in a.filters.split(",") for r in ints(a.runs)
    ]
    out = [load_run(f) for j in jobs if a.out is not None and (f := run_file(a.out, j)).exists()]
    todo = [j for j in jobs if a.out is None or not run_file(a.out, j).exists()]
    todo = [] if a.report_only else todo
    back = f" ({len(out)} of {len(jobs)} read back from {a.out})" if out else ""
    print(f"CPUs {os.cpu_count()}, load average {'/'.join(f'{x:.1f}' for x in os.getloadavg())}; {len(todo)} runs on {a.workers} workers{back}", flush=True)
    if todo:
        with Pool(a.workers, initializer=warm, initargs=(tuple(a.filters.split(",")), a.config)) as pool:
            for o in pool.imap_unordered(one, todo, chunksize=1):
                out.append(o)
                if a.out is not None:
                    save_run(a.out, o)
    out.sort(key=lambda o: (o["path"], o["case"], o["filter"], o["run"]))
    if a.csv is not None:
        keys = [k for k in out[0] if not isinstance(out[0][k], np.ndarray)]
        with a.csv.open("w", newline="") as fh:
            w = csv.DictWriter(fh, fieldnames=[*keys, "ospa_mean", "loc_mean", "card_mean", "ospa_end", "view_mean", "view_end"])
            w.writeheader()
            for o in out:
                w.writerow({
                    **{k: o[k] for k in keys}, "ospa_mean": o["ospa"].mean(), "loc_mean": o["loc"].mean(), "card_mean": o["card"].mean(),
                    "ospa_end": o["ospa"][-1], "view_mean": o["view"].mean(), "view_end": o["view"][-1],
                })  # fmt: skip
    groups = sorted({(o["path"], o["case"], o["filter"]) for o in out}, key=lambda g: (g[0], g[1] != "static", g[2]))
    for g in groups:
        r = [o for o in out if (o["path"], o["case"], o["filter"]) == g]
        print(
            f"{g[0]:<10} {g[1]:<7} {g[2]:<5} ({len(r)} runs): OSPA over the steps {_ms([o['ospa'].mean() for o in r])} m"
            f" (loc {_ms([o['loc'].mean() for o in r])}, card {_ms([o['card'].mean() for o in r])});"
            f" at the last step {_ms([o['ospa'][-1] for o in r])} m; features mapped {np.mean([o['features_end'] for o in r]):.2f}"
            f" of {np.mean([o['seen_end'] for o in r]):.2f} seen; in view: OSPA {_ms([o['view'].mean() for o in r])} m"
            f" (loc {_ms([o['view_loc'].mean() for o in r])}, card {_ms([o['view_card'].mean() for o in r])}); CPU {_ms([o['cpu_s'] for o in r])} s per run,"
            f" {_ms([o['cpu_ms_step'] for o in r])} ms per step",
            flush=True,
        )
    if a.figure is not None:
        _figure(out, groups, a.figure)


def _figure(out: list, groups: list, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    cases = sorted({g[:2] for g in groups}, key=lambda c: (c[0], c[1] != "static"))
    panels = [(case, what) for case in cases for what in ("map", "view")]
    fig, axes = plt.subplots(len(panels), 3, figsize=(12, 3.0 * len(panels)), squeeze=False)
    for row, (case, what) in zip(axes, panels, strict=True):
        keys = ("ospa", "loc", "card") if what == "map" else ("view", "view_loc", "view_card")
        for g in [g for g in groups if g[:2] == case]:
            r = [o for o in out if (o["path"], o["case"], o["filter"]) == g]
            for ax, key in zip(row, keys, strict=True):
                ax.plot(np.mean([o[key] for o in r], axis=0), label=f"{'delta-GLMB' if g[2] == 'glmb' else g[2].upper()} ({len(r)} runs)")
        for ax, key in zip(row, ("OSPA", "OSPA loc", "OSPA card"), strict=True):
            where = "the features seen so far" if what == "map" else "in the detection radius"
            ax.set_title(f"{case[0]}, {case[1]}: {key}, {where}", fontsize=8)
            ax.set_xlabel("step")
            ax.set_ylabel("[m] (p = 1, c = 100 m)")
            ax.set_ylim(0, C)
            ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=100, metadata={"Software": None})
    plt.close(fig)


if __name__ == "__main__":
    main()
