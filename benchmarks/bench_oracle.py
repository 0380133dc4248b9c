"""What the simulated data allow: the batch oracle (slam_runtime.oracle) beside the filters.

Run: ``python benchmarks/bench_oracle.py [--worlds 1,4-9] [--glmb-worlds 1-3] [--runs 0-2] [--particles 200]
[--set proposal=prior --set filter.noise_inflation=10] [--workers 2]``.

* rfs-sim, per world: the oracle MAP's final position error, the posterior's standard deviation there
  (sqrt of the trace), and what an exact posterior *sample* gives (mean final error, share above 0.05 m):
  an RB particle filter's estimate, one particle's path after its ancestry has collapsed, behaves like
  one sample.
* glmb-paper, per world: the MAP's map OSPA (c = 0.5 m, p = 1, the paper's) and the posterior samples'
  mean and 90th percentile (the associations given, so the same at every clutter rate).
* glmb-paper also what an ideal Rao-Blackwellised particle's map gives (the map's conditional mean given a
  path drawn from the posterior): its OSPA and its normalised distance from the mode
  (``slam_runtime.oracle.map_distance``: 1 for a posterior sample).
* glmb-paper, per clutter rate: :func:`slam_runtime.oracle.clutter_information_ratio`, the share of a
  detection's information the false alarms leave when the association is not given (at most: the
  innovation covariance taken as the measurement noise alone), and the oracle solved again with every
  measurement carrying that share of its information (its noise over the ratio's square root, the
  odometry's unchanged): how much an ideal RB particle's map OSPA grows with the clutter (over draws of the
  data), and this world's ideal figure times that growth: what an ideal filter can be expected to reach.
* glmb-paper, per clutter rate, on the world's own false alarms: :func:`slam_runtime.oracle.clutter_oracle`, the
  posterior's mode and covariance with the associations *not* given (each landmark's exact single-feature
  likelihood of each scan; the missing information of the associations taken off): the mode's map OSPA, an
  ideal RB particle's (the map's conditional mean given a path drawn from that posterior, on this data), and
  the mean of three such particles' maps (three ideal islands, ``benchmarks/configs/glmb_paper_islands.yaml``),
  with the share of the measurements' information the association doubt removes. The first row (0) is the
  labelled oracle's.
* with ``--sweep DIR`` (a ``detcal slam sweep`` folder of glmb-paper runs on world ``--sweep-world``): each
  filter's maps on the same scale, mean and median over the runs, beside their OSPA.
* with ``--runs``: RB-PHD-SLAM with ``benchmarks/configs/rfs_sim.yaml`` (and ``--set`` overrides) on each
  rfs-sim world and filter seed: final error, map OSPA, and the squared Mahalanobis distance d2 of the final
  position from the oracle's MAP under its posterior covariance (chi-square(2) for an exact posterior sample:
  mean 2, median 1.39). This is how the rfs-sim settings were chosen (worlds 4-9; world 1 held out).

BLAS is pinned to one thread; ``--workers`` runs filter runs in parallel processes.
"""

from __future__ import annotations

import os

for _v in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "NUMBA_NUM_THREADS"):
    os.environ.setdefault(_v, "1")

import argparse  # noqa: E402
import sys  # noqa: E402
from concurrent.futures import ProcessPoolExecutor  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402
import yaml  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import slam_runtime.oracle as so  # noqa: E402
from benchmarks.common import ints, parse_set  # noqa: E402
from calib.sim import glmb_paper, rfs  # noqa: E402
from slam_runtime.metrics import ospa  # noqa: E402


def rfs_oracle(world: int):
    cfg = rfs.RfsSimConfig()
    log = rfs.simulate_rfs(cfg, world)
    return log, so.batch_oracle(log, **rfs.oracle_noise(cfg))


def glmb_oracle(world: int):
    cfg = glmb_paper.GlmbPaperConfig(clutter=1.0)  # the oracle drops the clutter: the four rates share the landmark detections
    log = glmb_paper.simulate_glmb_paper(cfg, world)
    return log, so.batch_oracle(log, **glmb_paper.oracle_noise(cfg))


def expected_rb_ospa(orc, truth: np.ndarray, rng: np.random.Generator, n: int = 2000) -> float:
    """Mean map OSPA (c = 0.5, p = 1) of an ideal RB particle over draws of the data: truth + the mode's error
    N(0, Sigma_mm) + the path's N(0, Sigma_mm - H_mm^-1), the oracle's covariances (consistent: the tests check
    the mode's normalised error is 1)."""
    mode = orc.landmarks[orc.detected]
    maps = truth[orc.detected] + (so.posterior_samples(orc, rng, n)[1] - mode) + (so.rb_map_samples(orc, rng, n) - mode)
    return float(np.mean([ospa(x, truth, 0.5, 1.0) for x in maps]))


def ideal_maps(orc, truth: np.ndarray, rng: np.random.Generator, n: int = 3000, islands: int = 3) -> tuple[float, float, float]:
    """On one log's data: the map OSPA of the oracle's mode, the mean over n ideal RB particles' maps (the mode + a
    draw of N(0, Sigma_mm - H_mm^-1)), and the mean over n / islands averages of ``islands`` such maps."""
    mode = orc.landmarks[orc.detected]
    rb = so.rb_map_samples(orc, rng, n)
    one = np.mean([ospa(m, truth, 0.5, 1.0) for m in rb])
    k = n // islands
    avg = rb[: k * islands].reshape(k, islands, -1, 2).mean(axis=1)
    return ospa(mode, truth, 0.5, 1.0), float(one), float(np.mean([ospa(m, truth, 0.5, 1.0) for m in avg]))


def sweep_maps(folder: Path, world: int) -> None:
    """Each run's map (map.csv) of a sweep on glmb-paper world ``world``: normalised distance from the oracle's mode."""
    import pandas as pd

    log, orc = glmb_oracle(world)
    by: dict[str, list[tuple[float, float]]] = {}
    for run in sorted(p for p in folder.iterdir() if (p / "map.csv").is_file()):
        kind = yaml.safe_load((run / "config.yaml").read_text())["settings"]["filter"]["kind"]
        xy = pd.read_csv(run / "map.csv")[["x", "y"]].to_numpy()
        by.setdefault(kind, []).append((so.map_distance(orc, xy)[0], ospa(xy, log.landmarks.xy, 0.5, 1.0)))
    for kind, rows in sorted(by.items()):
        d, o = np.array(rows).T
        print(
            f"  {folder.name} {kind}: {len(rows)} runs, map OSPA {o.mean():.3f}, normalised distance from the oracle's mode "
            f"mean {np.nanmean(d):.2f}, median {np.nanmedian(d):.2f}",
            flush=True,
        )


def _join(rows: list[dict], key: str, fmt: str) -> str:
    return " / ".join(format(r[key], fmt) for r in rows)


def filter_run(args) -> dict:
    """One RB-PHD run on an rfs-sim world; the caller scores its last position against that world's oracle."""
    world, seed, particles, sets = args
    from calib.config import load_yaml_model
    from slam_runtime.config import SlamConfig, override
    from slam_runtime.run import evaluate, run_slam

    cfg_sim = rfs.RfsSimConfig()
    log = rfs.simulate_rfs(cfg_sim, world)
    cfg = override(load_yaml_model(SlamConfig, ROOT / "benchmarks/configs/rfs_sim.yaml"), particles=particles, **sets)
    res = run_slam(log, rfs.truth_profile(cfg_sim), cfg, seed=seed)
    m = evaluate(log, res, cfg=cfg)
    return {
        "world": world,
        "seed": seed,
        "final": m["final_position_error_vs_ground_truth_m"],
        "ospa": m["map_ospa"],
        "mapped": m["landmarks_mapped"],
        "last": res.trajectory[-1],
        "cpu": float(res.step_cpu_ms[1:].mean()),
    }


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--worlds", default="1,4-9", help="rfs-sim world seeds")
    ap.add_argument("--glmb-worlds", default="1-3", help="glmb-paper world seeds ('' to skip)")
    ap.add_argument("--runs", default="", help="filter seeds of RB-PHD runs on every rfs-sim world ('' to skip)")
    ap.add_argument("--particles", type=int, default=200)
    ap.add_argument(
        "--set", action="append", default=[], metavar="KEY=VALUE", help="override of rfs_sim.yaml (value parsed as YAML)"
    )
    ap.add_argument("--workers", type=int, default=1)
    ap.add_argument("--sweep", action="append", default=[], metavar="DIR", help="a detcal slam sweep folder of glmb-paper runs")
    ap.add_argument("--sweep-world", type=int, default=1, help="the glmb-paper world seed of the --sweep logs")
    a = ap.parse_args()
    worlds = ints(a.worlds)
    print(f"load average: {' '.join(f'{x:.2f}' for x in os.getloadavg())}")
    print("rfs-sim: the batch oracle (true associations, the simulator's noise)")
    oracles = {}
    for w in worlds:
        log, orc = oracles[w] = rfs_oracle(w)
        fin, _ = so.posterior_samples(
            orc, np.random.default_rng(w), 20000
        )  # a stream per world: the same figures whatever else is asked
        err = np.hypot(*(fin - log.reference["ground_truth"].poses[-1, :2]).T)
        print(
            f"  world {w}: MAP final error {orc.final_error(log.reference['ground_truth'].poses[-1]):.4f} m, posterior sd "
            f"{np.sqrt(np.trace(orc.final_cov[:2, :2])):.4f} m; a posterior sample: mean final error {err.mean():.4f} m, "
            f"above 0.05 m in {np.mean(err > 0.05):.1%}",
            flush=True,
        )
    for w in ints(a.glmb_worlds):
        log, orc = glmb_oracle(w)
        rng = np.random.default_rng(w)
        truth = log.landmarks.xy
        _, lms = so.posterior_samples(orc, rng, 1000)
        rb = so.rb_map_samples(orc, rng, 1000)
        s = np.array([ospa(x, truth, 0.5, 1.0) for x in lms])
        r = np.array([ospa(x, truth, 0.5, 1.0) for x in rb])
        d = np.mean([so.map_distance(orc, x)[0] for x in rb])
        print(
            f"glmb-paper world {w}: MAP map OSPA {ospa(orc.landmarks[orc.detected], truth, 0.5, 1.0):.4f} (c = 0.5, p = 1); "
            f"a posterior sample: mean {s.mean():.4f}, 90th percentile {np.percentile(s, 90):.4f}; an ideal RB particle's map: "
            f"mean {r.mean():.4f}, 90th percentile {np.percentile(r, 90):.4f}, normalised distance from the mode {d:.2f} "
            f"(a posterior sample: 1); MAP final error {orc.final_error(log.reference['ground_truth'].poses[-1]):.3f} m",
            flush=True,
        )
        # what false alarms take away from an ideal filter (the oracle has none): the clutter information ratio q at each
        # rate (the clutter intensity per (m rad) whitened by the measurement noise alone, |S|^(1/2) >= |R|^(1/2), so q is
        # an upper bound), the oracle again with every measurement carrying q of its information (its noise over sqrt(q);
        # the odometry's unchanged), and the ideal RB particle's map OSPA over draws of the data (truth + the mode's error,
        # N(0, Sigma_mm), + the path's, N(0, Sigma_mm - H_mm^-1)): its growth from no clutter, applied to this world's figure
        g = glmb_paper.GlmbPaperConfig()
        noise = glmb_paper.oracle_noise(g)
        base = None
        parts = []
        for c in (0.0, 1.0, 5.0, 10.0, 15.0):
            dens = c / ((g.range_max - g.range_min) * 2 * np.pi) * g.sigma_range * g.sigma_bearing
            q = so.clutter_information_ratio(g.pd, dens, np.random.default_rng(w))
            orc_c = so.batch_oracle(log, **{**noise, "range_sigma": noise["range_sigma"] / np.sqrt(q), "bearing_sigma": noise["bearing_sigma"] / np.sqrt(q)})
            e = expected_rb_ospa(orc_c, truth, np.random.default_rng(w))
            base = e if base is None else base
            if c:
                parts.append(f"{c:g}: ratio {q:.3f}, x {e / base:.3f}, {r.mean() * e / base:.3f}")
        print(
            f"  under clutter (false alarms per scan: the information ratio, the ideal RB map OSPA's growth over data draws "
            f"(no clutter: {base:.4f}), this world's ideal RB figure times it): {'; '.join(parts)}",
            flush=True,
        )
        rows = []
        for c in (0.0, 1.0, 5.0, 10.0, 15.0):
            if c == 0.0:
                m, one, three = ideal_maps(orc, truth, np.random.default_rng(w))
                rows.append(f"    {c:>4g}  {m:.4f}  {one:.4f}  {three:.4f}   (associations given)")
                continue
            gc = glmb_paper.GlmbPaperConfig(clutter=c)
            log_c = glmb_paper.simulate_glmb_paper(gc, w)
            kappa = c / ((gc.range_max - gc.range_min) * 2 * np.pi)
            oc = so.clutter_oracle(
                log_c, **noise, pd=gc.pd, clutter_density=kappa, range_min=gc.range_min, range_max=gc.range_max
            )
            m, one, three = ideal_maps(oc, truth, np.random.default_rng(w))
            rows.append(
                f"    {c:>4g}  {m:.4f}  {one:.4f}  {three:.4f}   information removed {oc.information_loss:.3f}, a detection's "
                f"weight on its landmark {oc.own_weight:.3f}, false alarms' weight per scan {oc.false_weight:.3f}"
                f"{'' if oc.converged else f', NOT converged in {oc.iterations} iterations'}"
            )
        print(
            "  on this world's own false alarms, the associations not given (clutter_oracle): false alarms per scan, map OSPA "
            "of the mode, an ideal RB particle, three ideal islands\n" + "\n".join(rows),
            flush=True,
        )
    for folder in a.sweep:
        sweep_maps(Path(folder), a.sweep_world)
    seeds = ints(a.runs)
    if not seeds:
        return
    sets = dict(parse_set(kv) for kv in a.set)
    jobs = [(w, s, a.particles, sets) for w in worlds for s in seeds]
    with ProcessPoolExecutor(max(1, a.workers)) as ex:
        rows = list(ex.map(filter_run, jobs))
    for r in rows:
        r["d2"] = so.mahalanobis2(oracles[r["world"]][1], r["last"])
    print(f"RB-PHD-SLAM, {a.particles} particles, benchmarks/configs/rfs_sim.yaml {sets or ''}")
    for w in worlds:
        rs = [r for r in rows if r["world"] == w]
        print(
            f"  world {w}: final error {_join(rs, 'final', '.3f')} m, d2 {_join(rs, 'd2', '.1f')}, "
            f"OSPA {_join(rs, 'ospa', '.3f')}, mapped {_join(rs, 'mapped', 'd')}",
            flush=True,
        )
    d2 = np.array([r["d2"] for r in rows])
    fe = np.array([r["final"] for r in rows])
    print(
        f"  all {len(rows)} runs: d2 mean {d2.mean():.2f}, median {np.median(d2):.2f} (an exact posterior sample: 2.00 / 1.39); "
        f"final error mean {fe.mean():.4f} m, {int(np.sum(fe > 0.05))} above 0.05 m; OSPA mean {np.mean([r['ospa'] for r in rows]):.4f}; "
        f"CPU {np.mean([r['cpu'] for r in rows]):.1f} ms/step"
    )


if __name__ == "__main__":
    main()
