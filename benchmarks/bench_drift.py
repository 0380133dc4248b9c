"""Drift verdicts on simulated parks: the false-drift rate on new parks of the same settings, and the
changed sensors caught at the part that changed (the docs' validation page).

Run: ``python benchmarks/bench_drift.py [--seeds 1-20] [--scale full|quarter|small] [--cases same,pd_lower,...]
[--workers 2] [--csv drift.csv] [--figures DIR]``, or ``--utias DIR`` for the study of UTIAS MRCLAM dataset 1.

For every seed s: a profile is calibrated on park 2s - 1 and validated on park 2s
(a new world of the same settings) and on park 2s with its sensor changed:

* ``pd_lower``: a tree beyond 10 m returns nothing in a scan with probability 0.1
  (P_D x 0.9 there: lowered by 0.09-0.10 where it is 0.92-1);
* ``clutter_double``: twice the clutter sources (bushes, posts, walls);
* ``noise_double``: twice the range noise (sigma_r 4 cm).

Prints the verdicts, the false-drift rate with its binomial interval, the share
of seeds where the changed part was flagged, each part's raw p-values under the
null against the uniform (Kolmogorov-Smirnov), and CPU seconds. ``--figures``
writes the p-value QQ plot and one validation report per case.
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
os.environ.setdefault("DETCAL_CACHE", tempfile.mkdtemp(prefix="detcal-bench-"))

import numpy as np  # noqa: E402
import pandas as pd  # noqa: E402
from scipy.stats import binomtest, kstest  # noqa: E402

from benchmarks.common import ints  # noqa: E402
from calib.drift import PARTS  # noqa: E402

SCALES = {
    "full": {},
    # the unit test's scale (tests/calib/test_drift.py): a few seconds per seed
    "small": {"width": 70.0, "height": 50.0, "trees": {"count": 50}, "bushes": {"count": 20}, "walls": {"count": 1, "min_length": 3.0, "max_length": 10.0},
              "posts": {"count": 6}, "path": {"margin": 8.0}},
    # a quarter of the area at the default densities: half the path, a quarter of the objects
    "quarter": {"width": 100.0, "height": 75.0, "trees": {"count": 75}, "bushes": {"count": 38}, "walls": {"count": 2}, "posts": {"count": 10},
                "path": {"margin": 10.0}},
}
CHANGED = {"pd_lower": "pd", "clutter_double": "clutter", "noise_double": "noise"}


def case_config(scale: str, case: str):
    from calib.sim.park import ParkConfig, changed

    return changed(ParkConfig.model_validate(SCALES[scale]), case)


def one_seed(seed: int, scale: str, figures: str | None, cases: tuple[str, ...] = ("same", *CHANGED)) -> tuple[list[dict], float]:
    """Calibrate on park 2s - 1, validate on park 2s unchanged and changed; (rows, CPU seconds)."""
    from calib.calibrate import CalibrateConfig, calibrate
    from calib.sim.park import simulate_park
    from calib.validate import plot_reliability, validate

    t0 = time.process_time()
    train = simulate_park(case_config(scale, "same"), 2 * seed - 1).log
    prof = calibrate([train], CalibrateConfig(), name="park", version="1.0.0").profile
    rows = []
    for case in cases:
        log = simulate_park(case_config(scale, case), 2 * seed).log
        v = validate(prof, log)
        r = v.drift.rows[0]
        row = {"seed": seed, "case": case, "verdict": r.verdict, "drift": r.headline}
        for k in PARTS:
            p = r.parts.get(k)
            row[f"{k}_p"] = p.p_value if p else np.nan
            row[f"{k}_p_adjusted"] = p.p_adjusted if p else np.nan
            row[f"{k}_verdict"] = p.verdict if p else "not tested"
            row[f"{k}_effect"] = p.effect if p else np.nan
        row["rate_ratio"] = v.summary["false_alarms_per_frame_observed"] / prof.clutter.rate
        rows.append(row)
        if figures and seed == 1:
            plot_reliability(v, Path(figures) / f"drift-{scale}-{case}.png", title=f"park profile (seed 1) on park seed 2: {case}")
    return rows, time.process_time() - t0


def _row(label: str, r, family: str) -> dict:
    out = {"case": label, "verdict": r.verdict}
    for k in PARTS:
        p = r.parts.get(k)
        out[k] = f"{p.verdict}, p {p.p_value:.2g} (adj. {p.p_adjusted:.2g}): {p.text}" if p else "not tested"
    out["holm_family"] = family
    return out


def utias(root: Path, csv: Path | None, figures: Path | None) -> None:
    """UTIAS dataset 1: each robot's own profile (first half of its run) on its second half; each robot against
    the pooled profile of the other four (leave one out, one Holm family); robots 1-3's pooled profile on 4 and 5."""
    from calib.crossval import halves
    from calib.detlevel import DetectionCalibConfig, calibrate_detections, exchangeability, leave_one_out, sensor_id, validate_detections
    from calib.io.utias import read_utias
    from calib.validate import plot_reliability

    cfg = DetectionCalibConfig()
    logs = [read_utias(root, robot=r) for r in range(1, 6)]
    rows = []
    t0 = time.process_time()
    for lg in logs:
        first, second = halves(lg)
        own = calibrate_detections([first], cfg, name="own", version="1.0.0").profile
        v = validate_detections(own, [second])
        r = v.drift.rows[0]
        rows.append(_row(f"{sensor_id(lg)}: own profile (1st half) on its 2nd half", r, f"its {v.drift.tests} tests"))
        print(f"{sensor_id(lg)} own 1st -> 2nd: {r.headline}", flush=True)
        if figures and sensor_id(lg) == "robot1":
            plot_reliability(v, figures / "drift-utias-robot1-halves.png", title="UTIAS robot 1: its own profile (first half) on its second half")
    loo = leave_one_out(logs, cfg)
    for r in loo.rows:
        rows.append(_row(f"{r.name}: the other four robots' pooled profile", r, f"these {loo.tests} tests"))
        print(f"{r.name} against the other four: {r.headline}", flush=True)
    ex = exchangeability(logs, cfg)
    for r in ex.rows:
        k = ex.round_of[r.name]
        rows.append(_row(f"{r.name}: stepwise, the pooled profile of the robots left", r, f"round {k} of {ex.steps}"))
        print(f"{r.name} against the others (round {k}): {r.headline}", flush=True)
    print(f"not exchangeable, in the order set apart: {ex.summary()['not_exchangeable']} ({', '.join(ex.odd)})")
    cal = calibrate_detections(logs[:3], cfg, name="utias-r123", version="1.0.0")
    v = validate_detections(cal.profile, logs[3:])
    for r in v.drift.rows:
        rows.append(_row(f"robots 1-3 pooled on {r.name}", r, f"these {v.drift.tests} tests"))
    print(f"robots 1-3 pooled on robots 4 and 5: overall {v.drift.verdict}; " + "; ".join(f"{r.name}: {r.headline}" for r in v.drift.rows))
    if figures:
        plot_reliability(v, figures / "drift-utias-r123-on-4-5.png", title="UTIAS: robots 1-3's pooled profile on robots 4 and 5 together")
        plot_reliability(v, figures / "drift-utias-r123-on-4.png", title="UTIAS: robots 1-3's pooled profile on robot 4", row=1)
    print(f"UTIAS: {time.process_time() - t0:.0f} CPU s")
    t = pd.DataFrame(rows)
    pd.set_option("display.width", 250)
    pd.set_option("display.max_colwidth", 120)
    print(t.to_string(index=False))
    if csv:
        t.to_csv(csv, index=False)


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--utias", type=Path, help="UTIAS MRCLAM dataset 1: its study instead of the parks")
    ap.add_argument("--seeds", default="1-20")
    ap.add_argument("--scale", choices=list(SCALES), default="full")
    ap.add_argument("--workers", type=int, default=1)
    ap.add_argument("--csv", type=Path)
    ap.add_argument("--figures", type=Path)
    ap.add_argument("--cases", default=",".join(("same", *CHANGED)), help="comma-separated: same, " + ", ".join(CHANGED))
    a = ap.parse_args()
    cases = tuple(a.cases.split(","))
    seeds = ints(a.seeds)
    if a.figures:
        a.figures.mkdir(parents=True, exist_ok=True)
    if a.utias:
        utias(a.utias, a.csv, a.figures)
        return
    fig = str(a.figures) if a.figures else None
    cpu = 0.0
    rows = []
    if a.workers > 1:
        with ProcessPoolExecutor(a.workers) as ex:
            for r, c in ex.map(one_seed, seeds, [a.scale] * len(seeds), [fig] * len(seeds), [cases] * len(seeds)):
                rows += r
                cpu += c
    else:
        for s in seeds:
            r, c = one_seed(s, a.scale, fig, cases)
            rows += r
            cpu += c
            print(f"seed {s}: " + "; ".join(f"{x['case']}: {x['drift']}" for x in r), flush=True)
    t = pd.DataFrame(rows)
    if a.csv:
        t.to_csv(a.csv, index=False, float_format="%.6g")
    n = len(seeds)
    same = t[t["case"] == "same"]
    k = int((same["verdict"] == "drifted").sum())
    ci = binomtest(k, n).proportion_ci(0.95)
    print(f"\n{a.scale} parks, seeds {a.seeds}: {cpu:.0f} CPU s ({cpu / n:.0f} per seed: {len(cases) + 1} parks, 1 calibration, {len(cases)} validations)")
    print(f"same settings: drifted {k} of {n} ({100 * k / n:.0f} %, 95 % interval {100 * ci.low:.0f}-{100 * ci.high:.0f} %), "
          f"verdicts {same['verdict'].value_counts().to_dict()}")
    for part in PARTS:
        p = same[f"{part}_p"].dropna()
        if len(p):
            print(f"  {part:8s} raw p under the null: mean {p.mean():.3f}, below 0.05: {int((p < 0.05).sum())} of {len(p)}, "
                  f"KS against uniform p = {kstest(p, 'uniform').pvalue:.3f}")
    for case, part in CHANGED.items():
        c = t[t["case"] == case]
        if c.empty:
            continue
        hit = int((c[f"{part}_verdict"] == "drifted").sum())
        others = {q: int((c[f"{q}_verdict"] == "drifted").sum()) for q in PARTS if q != part}
        print(f"{case:15s}: {part} drifted in {hit} of {n}; overall drifted {int((c['verdict'] == 'drifted').sum())}; "
              f"other parts flagged {others}; mean effect {c[f'{part}_effect'].mean():+.3f}; clutter rate ratio {c['rate_ratio'].mean():.2f}")
    if a.figures:
        qq(same, a.figures / f"drift-{a.scale}-pvalues.png", f"{a.scale} parks, {n} seeds")


def qq(same: pd.DataFrame, path: Path, title: str) -> None:
    """Sorted raw p-values of each part under the null against the uniform's quantiles."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(5.5, 5.2), dpi=100)
    ax.plot([0, 1], [0, 1], "k:", lw=0.8, label="uniform")
    for part in PARTS:
        p = np.sort(same[f"{part}_p"].dropna().to_numpy())
        if p.size:
            ax.plot((np.arange(p.size) + 0.5) / p.size, p, "o-", ms=3, label=part)
    ax.set_xlabel("uniform quantile")
    ax.set_ylabel("raw p-value (new park, same settings)")
    ax.set_title(f"p-values under the null: {title}", fontsize=9)
    ax.legend(fontsize=8)
    ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, metadata={"Software": None})
    plt.close(fig)


if __name__ == "__main__":
    main()
