"""The tables ``detcal slam sweep`` prints: the settings' metrics, their paired differences and the log evidence."""

from __future__ import annotations

from rich.table import Table

from detcal.reports.sweep import COMPARED, SETTING, by_evidence, summarise

#: decimals of a metric in the sweep's tables (the rest: 3)
_DIGITS = {"log_evidence": 1}

#: the metrics of the sweep's paired table (metric, heading): those the runs have are shown
PAIRED_SHOWN = (
    ("map_ospa", "map OSPA"),
    ("trajectory_rmse_vs_ground_truth_m", "trajectory RMSE [m]"),
    ("trajectory_rmse_vs_gps_m", "trajectory RMSE vs GPS [m]"),
    ("log_evidence", "log evidence [nats]"),
)


def paired_table(rows: list[dict]) -> Table:
    """The sweep's paired differences (paired.csv, :func:`detcal.pipelines.sweep.paired`) of the metrics of
    PAIRED_SHOWN: one row per comparison, each cell the mean difference a - b +- its standard error and the
    pairs in which a is lower."""
    present = [(k, head) for k, head in PAIRED_SHOWN if any(r["metric"] == k for r in rows)]
    t = Table(title="paired by log and seed: a - b, mean ± standard error (pairs in which a is lower)")
    for c in ("a - b", "the other settings", "pairs"):
        t.add_column(c, justify="right" if c == "pairs" else "left", overflow="fold")
    for _, head in present:
        t.add_column(head, justify="right")
    comps: dict[tuple, dict] = {}
    for r in rows:
        key = (r["varies"], r["a"], r["b"], *(r.get(k) for k in COMPARED if k != r["varies"]))
        comps.setdefault(key, {})[r["metric"]] = r
    for by_metric in comps.values():
        r0 = next(iter(by_metric.values()))
        ctx = ", ".join(f"{k} {r0[k]}" for k in COMPARED if k != r0["varies"])
        cells = [
            "" if (r := by_metric.get(k)) is None else f"{r['mean_difference']:+.{_DIGITS.get(k, 3)}f} ± {r['standard_error']:.{_DIGITS.get(k, 3)}f} ({r['a_lower']}/{r['pairs']})"
            for k, _ in present
        ]
        t.add_row(f"{r0['varies']}: {r0['a']} - {r0['b']}", ctx, str(max(r["pairs"] for r in by_metric.values())), *cells)
    return t


def evidence_table(rows: list[dict]) -> Table:
    """The values of the varied settings ranked by the runs' log evidence (:func:`detcal.pipelines.sweep.by_evidence`): per
    profile, filter, P_D mode and particle count, the likeliest and its lead over the next, paired by log and seed."""
    t = Table(title="the varied settings by the log evidence (no ground truth): the likeliest, and its lead over the next, paired by log and seed")
    for c in ("profile, filter, P_D mode, particles", "likeliest (mean log evidence [nats])", "next", "lead ± standard error (pairs in which it is higher)"):
        t.add_column(c, justify="right" if c.startswith("lead") else "left", overflow="fold")
    for g in by_evidence(rows):
        lead = "" if g["next"] is None else f"{g['lead']:.1f} ± {g['lead_se']:.1f} ({g['lead_higher']}/{g['pairs']})"
        t.add_row(f"{g['profile']}\n{g['filter']}, {g['pd_mode']}, {g['particles']}", f"{g['best']} ({g['best_mean']:.1f})", g["next"] or "", lead)
    return t


#: the metrics of the sweep's table (heading, metric): those the runs have are shown
SWEEP_SHOWN = (
    ("trajectory RMSE [m]", "trajectory_rmse_vs_ground_truth_m"),
    ("weighted mean pose RMSE [m]", "mean_trajectory_rmse_vs_ground_truth_m"),
    ("dead reckoning RMSE [m]", "odometry_rmse_vs_ground_truth_m"),
    ("trajectory RMSE vs GPS [m]", "trajectory_rmse_vs_gps_m"),
    ("dead reckoning vs GPS [m]", "odometry_rmse_vs_gps_m"),
    ("RMSE x [m]", "rmse_x_vs_ground_truth_m"),
    ("RMSE y [m]", "rmse_y_vs_ground_truth_m"),
    ("RMSE heading [deg]", "rmse_heading_vs_ground_truth_deg"),
    ("map OSPA", "map_ospa"),
    ("map features", "map_features"),
    ("log evidence [nats]", "log_evidence"),
)


def sweep_table(res, where: str) -> Table:
    """One column per setting, one row per metric (mean +- standard deviation over its runs), and ms per step."""
    summary = res.summary
    attempt = (f"{res.ran} run {where}" + (f", {res.skipped} done before" if res.skipped else "")) if res.ran else "all done before"
    t = Table(title=f"sweep of {res.runs} runs ({attempt}) -> {res.folder}")
    t.add_column("metric")
    for e in summary:
        var = f"\n{e['variant']}" if e.get("variant") else ""
        t.add_column(f"{e['profile']}\n{e['filter']}, {e['pd_mode']}, {e['particles']} particles{var}\n{e['runs']} runs", justify="right", overflow="fold")
    for label, key in SWEEP_SHOWN:
        if f"{key}_mean" in summary[0]:
            digits = 0 if key == "log_evidence" else 3
            t.add_row(label, *(f"{e[key + '_mean']:.{digits}f} ± {e[key + '_std']:.{digits}f}" for e in summary))
    # timings.csv is apart from runs.csv: its rows take their run's setting to be summarised by the same grouping
    timed = [{**{k: row[k] for k in SETTING}, "ms_per_step": tim["ms_per_step_mean"]} for row, tim in zip(res.rows, res.timings, strict=True)]
    t.add_row("ms per step", *(f"{e['ms_per_step_mean']:.1f}" for e in summarise(timed, SETTING)))
    return t
