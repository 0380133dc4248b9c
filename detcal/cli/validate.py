"""``detcal validate``: is a profile still right for these logs? Parse, check, call the validation pipeline, print
the verdicts and exit with the overall one's code (:data:`detcal.pipelines.validation.EXIT_CODES`)."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Annotated

import typer
from rich.table import Table

from calib.drift import LABELS, PARTS
from detcal.cli.calibrate import RobotsOpt, check_poses, landmark_input
from detcal.cli.common import ReaderArgs, fresh, out, reader_options, summary_table, warn
from profiles.errors import UsageError


@reader_options("fmt", "max_backstep", "laser", "range_max", "scan_topic", "truth_topic")
def validate_cmd(
    args: Annotated[
        list[str] | None, typer.Argument(metavar="[PROFILE] LOG...", help="A profile (name, name@version or file) and held-out logs; with --cv only logs.")
    ] = None,
    *,
    reader: ReaderArgs,
    cv: Annotated[str | None, typer.Option("--cv", help="Cross-validate the calibration instead: robots (leave one sensor out) or time (first half / second half).")] = None,
    config: Annotated[Path | None, typer.Option(help="--cv: the calibration config (as for calibrate).")] = None,
    adapt: Annotated[float | None, typer.Option(help="--cv robots on detection-level logs: seconds of the held-out sensor used for its own partially pooled profile.")] = None,
    landmarks: Annotated[Path | None, typer.Option(help="Landmark truth: a CSV (id, x, y, radius) or `cloud`.")] = None,
    poses: Annotated[str, typer.Option(help="Scan poses from: auto, reference, icp.")] = "auto",
    out_dir: Annotated[Path | None, typer.Option("--out", help="Run folder (default: runs/validate_<profile>_<log> or runs/cv_<kind>_<log>).")] = None,
    force: Annotated[bool, typer.Option(help="Replace the run folder if it exists.")] = False,
    robot: RobotsOpt = None,
    drift_config: Annotated[
        Path | None, typer.Option("--drift-config", help="YAML drift settings (alpha, replicates, seed, tolerances, bins; see docs/validation.md).")
    ] = None,
    alpha: Annotated[float | None, typer.Option(help="Chance of calling a right profile drifted anywhere (Holm over every test; default 0.05).")] = None,
    replicates: Annotated[int | None, typer.Option(help="Bootstrap replicates (default 1999; p-values down to 1 / (replicates + 1)).")] = None,
    seed: Annotated[int | None, typer.Option(help="Seed of the bootstrap (default 0): same inputs and seed, same report.")] = None,
    workers: Annotated[
        int | None, typer.Option(help="Laser logs: Dask worker processes for the per-log work (default: the CPU count when there are several logs); 0 = in this process.")
    ] = None,
    scheduler: Annotated[str | None, typer.Option(help="Address of an existing Dask scheduler (e.g. tcp://10.0.0.5:8786) for the per-log work.")] = None,
) -> None:
    """Is a profile still right for these logs? Or cross-validate a calibration (--cv robots|time).

    Each part of the profile -- P_D, clutter, measurement noise, gate coverage -- is tested on each log against
    what its score would be if the profile were exactly right for that log's own opportunities (a parametric
    bootstrap: the log's own pairs, frames and autocorrelation, and the profile's own sampling error). Printed per
    part: the observed score beside that range (95 %), the p-value (Holm-adjusted over every test) and a verdict:
    consistent; drifted (which part, and for P_D which bins); or too little data to tell (with the count that
    would do). Several logs (or robots): each log's verdict beside the pooled one; the overall verdict is the worst.
    The run folder holds the report figures (observed against predicted P_D per bin with the band; the clutter
    count distribution against the model's), parts.csv and logs.csv (one row per log).

    Exit code: 0 consistent, 3 drifted, 4 too little data to tell; 1 bad data, 2 usage error.
    """
    check_poses(poses)
    args = args or []
    if cv is not None:
        _cross_validate(args, reader, cv, config, adapt, landmarks, poses, out_dir, force, robot)
        return
    if config is not None or adapt is not None:
        raise UsageError("--config and --adapt go with --cv (drift settings: --drift-config)")
    if len(args) < 2:
        raise UsageError("validate needs a PROFILE and at least one LOG (or --cv robots|time with logs)")
    from calib.config import load_yaml_model
    from calib.drift import DriftConfig
    from detcal.engine import check_options
    from detcal.pipelines.validation import ValidationJob, run_validation
    from profiles.store import resolve

    check_options(workers, scheduler)
    drift = load_yaml_model(DriftConfig, drift_config, {"alpha": alpha, "replicates": replicates, "seed": seed})
    landmark_input(landmarks)
    prof = resolve(args[0])
    paths = [Path(a) for a in args[1:]]
    loaded, used = reader.read_many(paths, robot)
    target = out_dir or Path("runs") / f"validate_{prof.ref}_{loaded[0].name}"
    fresh(target, force, inputs=[*paths, landmarks, drift_config])
    job = ValidationJob(
        profile=prof, logs=loaded, out=target, drift=drift, landmarks=landmarks, poses=poses, force=force,
        sources=[(p, reader.fmt, reader.options_of(lg)) for p, lg in zip(used, loaded, strict=True)], workers=workers, scheduler=scheduler,
    )  # fmt: skip
    done = run_validation(job)
    for note in done.notes:
        warn(note)
    report = done.validation.drift
    parts = report.parts()
    first = report.rows[0].name  # all logs together, or the one log
    several = len(report.rows) > 1
    mine = parts[parts["log"] == first]
    out.print(parts_table(f"{prof.ref} on {f'all {len(report.rows) - 1} logs together' if several else first}", mine))
    for line in part_lines(mine):
        out.print(line)
    if several:
        out.print(logs_table(report))
    tail = f"the worst of {len(report.rows) - 1} logs and all together; " if several else ""
    out.print(f"verdict: {report.headline_all()} ({tail}{report.tests} tests, Holm at alpha {report.config.alpha:g})")
    out.print(f"report: {target} ({', '.join(done.figures)}; per-log work {done.engine})")
    raise typer.Exit(done.exit_code)


def _num(x: float) -> str:
    if x is None or (isinstance(x, float) and math.isnan(x)):
        return ""
    return f"{x:.3g}" if abs(x) < 1000 else f"{x:,.0f}"


def parts_table(title: str, rows) -> Table:
    """One row per part: its score as observed beside the 95 % a right profile would give on this log (its
    sampling floor), the Holm-adjusted p-value and the verdict."""
    t = Table(title=title)
    for c, just in (("part", "left"), ("score", "left"), ("observed", "right"), ("right profile, 95 %", "right"), ("p adj.", "right"), ("verdict", "left")):
        t.add_column(c, justify=just, overflow="fold")
    for r in rows.to_dict("records"):
        if r["verdict"] == "not tested":
            t.add_row(r["part"], "", "", "", "", "not tested")
        else:
            t.add_row(r["part"], r["score"], _num(r["observed"]), f"{_num(r['right_low'])} to {_num(r['right_high'])}", f"{r['p_adjusted']:.2g}", r["verdict"])
    return t


def part_lines(rows) -> list[str]:
    """Under the table, one line per part: the change in its own words, where P_D changed, what more data would do,
    or why it was not tested."""
    lines = []
    for r in rows.to_dict("records"):
        bits = [r["change"]] + ([f"where: {r['where']}"] if r.get("where") else []) + ([r["needed"]] if r.get("needed") else [])
        lines.append(f"  {r['part']}: " + "; ".join(b for b in bits if b))
    return lines


def logs_table(report) -> Table:
    """One row per log (the pooled row first): its verdict, each part's verdict with its adjusted p-value, and what
    drifted or lacks data."""
    t = Table(title="each log and all together (the overall verdict is the worst)")
    for c in ("log", "verdict", *(LABELS[k] for k in PARTS), "why"):
        t.add_column(c, overflow="fold")
    for r in report.rows:
        cells = []
        for k in PARTS:
            p = r.parts.get(k)
            cells.append("not tested" if p is None else f"{p.verdict} (p {p.p_adjusted:.2g})")
        t.add_row(r.name, r.verdict, *cells, _why(r))
    return t


def _why(row) -> str:
    """The parts behind a row's verdict, short: P_D with its two most changed bins (details: parts.csv)."""
    if row.verdict == "consistent":
        return ""
    bits = []
    for p in row.parts.values():
        if p.verdict == row.verdict:
            bits.append(LABELS[p.part] + (f" ({', '.join(p.where[:2])})" if p.where else ""))
    return ", ".join(bits)


def scores_table(title: str, t, first: tuple[str, ...]) -> Table:
    """Rows of validation scores (fold rows or per-log rows) in columns narrow enough for a terminal."""
    tab = Table(title=title)
    cover = "hotelling_coverage" in t and t["hotelling_coverage"].notna().any()
    for c in (*first, "ECE (noise)", "Brier", "loglik", "FA error [95 % CI]", *(["coverage"] if cover else [])):
        tab.add_column(c, overflow="fold", justify="left" if c in first else "right")
    for r in t.to_dict("records"):
        row = [str(r[c]) for c in first] + [
            f"{r['ece']:.3f} ({r['ece_if_calibrated_blocks']:.3f})",
            f"{r['brier']:.3f}",
            f"{r['loglik_per_pair']:.3f}",
            f"{100 * r['false_alarm_relative_error']:+.0f} [{100 * r['false_alarm_relative_error_ci95_low']:+.0f}, "
            f"{100 * r['false_alarm_relative_error_ci95_high']:+.0f}] %",
        ]
        if cover:
            n = r.get("true_detections")
            row.append(f"{r['hotelling_coverage']:.4f}" + (f" of {int(n)}" if n is not None and not math.isnan(n) else ""))
        tab.add_row(*row)
    return tab


def _cross_validate(args, reader, cv, config, adapt, landmarks, poses, out_dir, force, robot) -> None:
    from calib.config import load_yaml_model
    from calib.crossval import cross_validate, write_cv_run

    if cv not in ("robots", "time"):
        raise UsageError(f"--cv: expected robots or time, got {cv!r}")
    if not args:
        raise UsageError("--cv needs the logs to cross-validate")
    if adapt is not None and not 0 < adapt < float("inf"):
        raise UsageError(f"--adapt: expected a positive number of seconds, got {adapt:g}")
    loaded, _ = reader.read_many([Path(a) for a in args], robot)
    target = out_dir or Path("runs") / f"cv_{cv}_{loaded[0].name}"
    fresh(target, force, inputs=[*args, config, landmarks])
    from detcal.pipelines.calibrate import METHODS

    detection = METHODS.get("external").takes(loaded)  # cross-validation knows detection-level and laser calibrations
    cfg = load_yaml_model(METHODS.get("external" if detection else "circle2d").config(), config)
    res = cross_validate(loaded, cv, config=cfg, adapt=adapt, landmarks_csv=landmarks, poses=poses)
    figures = write_cv_run(res, target, overwrite=force)
    out.print(scores_table(f"cross-validation ({cv}) -> {target} ({len(figures)} figures)", res.table, ("fold", "test", "profile")))
    if "verdict" in res.table:  # each fold's drift verdict (folds.csv: per part, with p-values)
        for r in res.table.to_dict("records"):
            text = r["drift"] if isinstance(r.get("drift"), str) and r["drift"] else r["verdict"]
            out.print(f"  {r['fold']} on {r['test']} ({r['profile']}): {text}")
    for prof, s in res.summary.items():
        if isinstance(s, dict):
            out.print(summary_table(f"{prof} profile over the folds", s))
