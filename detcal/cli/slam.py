"""``detcal slam run`` and ``detcal slam sweep``."""

from __future__ import annotations

import contextlib
import os
import shutil
from pathlib import Path
from typing import Annotated

import typer
from rich.table import Table

from detcal.cli.common import ReaderArgs, fresh, input_refs, out, positive, reader_options, summary_table, warn
from profiles.errors import DataError, UsageError

app = typer.Typer(help="Run SLAM filters with a detector profile.", no_args_is_help=True, rich_markup_mode=None)

PD_MODES = ("profile", "constant")


FEATURES = ("points", "planes")

POSES = ("estimated", "ground_truth")

PosesOpt = Annotated[
    str | None,
    typer.Option(
        "--poses",
        help="estimated (full SLAM) or ground_truth (mapping only: every particle at the log's ground-truth pose at every frame, "
        "the map filter and the profile without the path's error) (default: the config's, estimated).",
    ),
]


VaryOpt = Annotated[
    list[str] | None,
    typer.Option(
        "--vary",
        help="Vary a setting: KEY=V1,V2,... (a dotted path of the settings file, e.g. filter.noise_inflation=1,2, a setting "
        "of every filter; values read as YAML). Every run is made with each value (repeat the option to cross several settings), labelled `variant` "
        "in runs.csv and compared run by run in paired.csv; the last table ranks the values by the runs' log evidence, "
        "which needs no ground truth.",
    ),
]

#: settings that have their own option in the sweep: --vary refuses them
_OWN_OPTION = {"filter.kind": "--filter", "particles": "--particles", "detection.pd_mode": "--pd-mode"}


def variants(specs: list[str] | None) -> list[tuple[str | None, dict]]:
    """The --vary options as [(label, {dotted key: value})], every combination of their values (one (None, {})
    without the option). A value is read as YAML; the label keeps it as written (``filter.survival=0.99``)."""
    import itertools

    import yaml

    from detcal.pipelines.sweep import is_number

    if not specs:
        return [(None, {})]
    axes: list[list[tuple[str, str, object]]] = []
    seen: set[str] = set()
    for spec in specs:
        key, sep, text = spec.partition("=")
        key = key.strip()
        tokens = [t.strip() for t in text.split(",")]
        if not sep or not key or not all(tokens):
            raise UsageError(f"--vary: expected KEY=V1,V2,... (e.g. filter.noise_inflation=1,2), got {spec!r}")
        for own, opt in _OWN_OPTION.items():
            if own == key or own.startswith(key + "."):
                raise UsageError(f"--vary {key}: use {opt} (repeat it) to vary {own}" + ("" if own == key else f", and name single settings under {key}"))
        for other in seen:
            if other.startswith(key + ".") or key.startswith(other + "."):
                raise UsageError(f"--vary {key}: overlaps --vary {other} (vary single settings, not a group and a setting in it)")
        if key in seen:
            raise UsageError(f"--vary {key}: given twice (list its values in one option: {key}=V1,V2)")
        seen.add(key)
        axis, same = [], set()
        for t in tokens:
            try:
                v = yaml.safe_load(t)
            except yaml.YAMLError:
                raise UsageError(f"--vary {key}: cannot read the value {t!r}") from None
            if isinstance(v, str):  # (YAML 1.1 reads 1e-3 as text)
                with contextlib.suppress(ValueError):
                    v = float(v)
            if isinstance(v, dict | list):
                raise UsageError(f"--vary {key}: {t!r} is not a single value (vary one setting at a time)")
            ident = ("number", v) if is_number(v) else (type(v).__name__, v)  # (1 and 1.0 are one value; true is not 1)
            if ident not in same:
                same.add(ident)
                axis.append((key, t, v))
        axes.append(axis)
    return [(", ".join(f"{k}={t}" for k, t, _ in combo), {k: v for k, _, v in combo}) for combo in itertools.product(*axes)]


def slam_config(
    config: Path | None, filter_: str | None, particles: int | None, pd_mode: str | None, features: str | None = None, poses: str | None = None
):
    """The settings file (or the defaults) with the command-line overrides, validated."""
    from calib.config import load_yaml_model
    from slam_runtime.config import SlamConfig, override, with_filter
    from slam_runtime.mapfilter import MAP_FILTERS

    if filter_ is not None and filter_ not in MAP_FILTERS:
        raise UsageError(f"--filter: expected one of {', '.join(MAP_FILTERS.names())}, got {filter_!r}")
    positive("--particles", particles)
    if pd_mode is not None and pd_mode not in PD_MODES:
        raise UsageError(f"--pd-mode: expected one of {', '.join(PD_MODES)}, got {pd_mode!r}")
    if features is not None and features not in FEATURES:
        raise UsageError(f"--features: expected one of {', '.join(FEATURES)}, got {features!r}")
    if poses is not None and poses not in POSES:
        raise UsageError(f"--poses: expected one of {', '.join(POSES)}, got {poses!r}")
    cfg = load_yaml_model(SlamConfig, config, {"particles": particles})
    return override(with_filter(cfg, filter_), particles=particles, features=features, poses=poses, **{"detection.pd_mode": pd_mode})


@app.command("run")
@reader_options()
def slam_run_cmd(
    log_path: Annotated[Path, typer.Argument(metavar="LOG", help="A log with odometry and scans (or detections).")],
    reader: ReaderArgs,
    profile_ref: Annotated[str, typer.Option("--profile", help="Detector profile: name or name@version, or a file.")],
    filter_: Annotated[str | None, typer.Option("--filter", help="Map filter: rbphd, lmb or glmb (default: the config's).")] = None,
    particles: Annotated[int | None, typer.Option(help="Particles (default: the config's, 20).")] = None,
    seed: Annotated[int, typer.Option(help="Random seed; same log, profile, settings and seed give the same run.")] = 0,
    pd_mode: Annotated[str | None, typer.Option(help="P_D from the profile, or `constant` inside the sensor range (for comparison).")] = None,
    features: Annotated[str | None, typer.Option(help="Landmarks: points (2D) or planes (3D point clouds) (default: the config's, points).")] = None,
    config: Annotated[Path | None, typer.Option(help="YAML settings (filter, motion noise, metric); unknown keys are refused.")] = None,
    poses: PosesOpt = None,
    frames: Annotated[int | None, typer.Option(help="Only the first N frames.")] = None,
    out_dir: Annotated[Path | None, typer.Option("--out", help="Run folder (default: runs/slam_<log>_<profile>_<seed>).")] = None,
    force: Annotated[bool, typer.Option(help="Replace the run folder if it exists.")] = False,
) -> None:
    """SLAM over a log with a detector profile's P_D and clutter: trajectory, map, metrics, figures."""
    from calib.progress import progress
    from detcal.pipelines.slam_run import SlamRun
    from profiles.store import resolve
    from slam_runtime.run import check_inputs

    cfg = slam_config(config, filter_, particles, pd_mode, features, poses)
    positive("--frames", frames)
    if seed < 0:
        raise UsageError(f"--seed: expected a non-negative integer, got {seed}")
    prof = resolve(profile_ref)
    log = reader.read(log_path)
    check_inputs(log, prof)
    target = out_dir or Path("runs") / f"slam_{log.name}_{prof.ref}_{seed}"
    fresh(target, force, inputs=[log_path, profile_ref, config])
    inputs = [r.model_dump() for r in input_refs(log_path, log)]
    res = SlamRun(log, log_path.name, inputs, prof, cfg, seed, target, frames, force).run(progress)
    shown = {k: v for k, v in res.metrics.items() if not isinstance(v, dict)}
    mode = " (poses: ground truth, mapping only)" if cfg.poses == "ground_truth" else ""
    out.print(summary_table(f"{res.filter}-SLAM{mode} on {log.name} with {prof.ref} -> {target}", shown))


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
    from detcal.pipelines.sweep import COMPARED

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
    from detcal.pipelines.sweep import by_evidence

    t = Table(title="the varied settings by the log evidence (no ground truth): the likeliest, and its lead over the next, paired by log and seed")
    for c in ("profile, filter, P_D mode, particles", "likeliest (mean log evidence [nats])", "next", "lead ± standard error (pairs in which it is higher)"):
        t.add_column(c, justify="right" if c.startswith("lead") else "left", overflow="fold")
    for g in by_evidence(rows):
        lead = "" if g["next"] is None else f"{g['lead']:.1f} ± {g['lead_se']:.1f} ({g['lead_higher']}/{g['pairs']})"
        t.add_row(f"{g['profile']}\n{g['filter']}, {g['pd_mode']}, {g['particles']}", f"{g['best']} ({g['best_mean']:.1f})", g["next"] or "", lead)
    return t


def own_particles(config: Path | None) -> int:
    """The particle count of a (validated) settings file, or the default."""
    import yaml

    from slam_runtime.config import SlamConfig

    data = yaml.safe_load(config.read_text(encoding="utf-8")) if config is not None else None
    return int((data or {}).get("particles", SlamConfig.model_fields["particles"].default))


def seed_list(text: str) -> list[int]:
    """`5` -> 0..4; `1,3,7` or `1-5` -> those seeds."""
    try:
        if "," in text:
            seeds = [int(x) for x in text.split(",")]
        elif "-" in text:
            a, b = (int(x) for x in text.split("-", 1))
            seeds = list(range(a, b + 1))
        else:
            seeds = list(range(int(text)))
    except ValueError:
        raise UsageError(f"--seeds: expected a count (5), a list (1,3,7) or a range (1-5), got {text!r}") from None
    if not seeds:
        what = "a count of at least 1" if "-" not in text else "a range whose end is not below its start"
        raise UsageError(f"--seeds: expected {what} (a count of 3 is seeds 0-2; seed 0 alone is --seeds 0-0), got {text!r}")
    if min(seeds) < 0:
        raise UsageError(f"--seeds: expected non-negative seeds, got {text!r}")
    if len(set(seeds)) != len(seeds):
        raise UsageError(f"--seeds: a seed is listed twice in {text!r}")
    return seeds


WorkersOpt = Annotated[
    int | None,
    typer.Option(help="Worker processes of the local Dask cluster (default: the CPU count); 0 = in this process, one task after another."),
]
SchedulerOpt = Annotated[str | None, typer.Option(help="Address of an existing Dask scheduler (e.g. tcp://10.0.0.5:8786) instead of a local cluster.")]


@app.command("sweep")
@reader_options("fmt", "max_backstep", "robot")
def slam_sweep_cmd(
    logs: Annotated[list[Path], typer.Argument(metavar="LOG...", help="Logs to run on (e.g. simulated parks of different seeds).")],
    reader: ReaderArgs,
    profile_refs: Annotated[list[str], typer.Option("--profile", help="Detector profile(s): name or name@version, or a file (repeat the option).")],
    pd_modes: Annotated[list[str] | None, typer.Option("--pd-mode", help="profile and/or constant (repeat; default: both).")] = None,
    filters: Annotated[list[str] | None, typer.Option("--filter", help="Map filters: rbphd, lmb, glmb (repeat; default: the config's).")] = None,
    particles: Annotated[list[int] | None, typer.Option("--particles", help="Particle counts (repeat; default: the config's).")] = None,
    seeds: Annotated[str, typer.Option(help="Filter seeds: a count (3), a list (1,3,7) or a range (1-5).")] = "1",
    config: Annotated[Path | None, typer.Option(help="YAML settings shared by every run.")] = None,
    vary: VaryOpt = None,
    poses: PosesOpt = None,
    frames: Annotated[int | None, typer.Option(help="Only the first N frames of each log.")] = None,
    workers: WorkersOpt = None,
    scheduler: SchedulerOpt = None,
    out_dir: Annotated[Path, typer.Option("--out", help="Sweep folder: one run folder per run, runs.csv, summary.csv, paired.csv, timings.csv.")] = Path("runs/sweep"),
    force: Annotated[bool, typer.Option(help="Start the sweep folder anew (without it, the same command resumes an unfinished sweep).")] = False,
) -> None:
    """Monte Carlo sweep: every log x profile x filter x P_D mode x particle count x varied setting x seed, on Dask workers.

    Each run's folder is moved into the sweep folder as soon as the run ends; a
    failed run is named (log, seed) and the others go on; the same command again
    does only the runs that are missing. runs.csv and summary.csv are the same
    bytes whatever the number of workers. Settings that differ in one label (two
    P_D modes, filters, particle counts, profiles or values of a varied setting)
    are compared run by run on the same log and seed in paired.csv (mean
    difference, standard error, pairs in which the first is lower). Every run
    records its log evidence, log p(Z) of the measurements: the values of a
    varied setting are ranked by it, a choice that needs no ground truth.
    """
    from detcal.engine import InProcess, LogSource, check_options, open_engine
    from calib.progress import progress
    from profiles.store import resolve
    from slam_runtime.config import override, with_filter, with_settings
    from slam_runtime.mapfilter import MAP_FILTERS
    from slam_runtime.run import check_features, check_inputs, check_poses
    from detcal.pipelines.sweep import SETTING, SweepJob, check_run_names, make_plan, open_sweep, run_sweep, summarise

    modes = list(dict.fromkeys(pd_modes or list(PD_MODES)))
    for m in modes:
        if m not in PD_MODES:
            raise UsageError(f"--pd-mode: expected one of {', '.join(PD_MODES)}, got {m!r}")
    base = slam_config(config, None, particles[0] if particles else None, None, poses=poses)
    kinds = list(dict.fromkeys(filters or [base.filter.kind]))
    for f in kinds:
        if f not in MAP_FILTERS:
            raise UsageError(f"--filter: expected one of {', '.join(MAP_FILTERS.names())}, got {f!r}")
    counts = list(dict.fromkeys(particles or [base.particles]))
    if min(counts) < 1:
        raise UsageError(f"--particles: expected positive integers, got {counts}")
    varied = variants(vary)
    configs = {}  # (filter, variant) -> its settings, each checked before any log is read
    for f in kinds:
        fcfg = with_filter(base, f)
        plain = fcfg.model_dump()
        for key in varied[0][1]:  # (every variant has the same keys) a group's whole value would replace the settings
            node = plain  # in it, which other labels name
            for part in key.split("."):
                node = node.get(part) if isinstance(node, dict) else None
            if isinstance(node, dict):
                raise UsageError(f"--vary {key}: a group of settings; vary the single settings in it (e.g. {key}.{next(iter(node))})")
        for label, changes in varied:
            try:
                configs[f, label] = with_settings(fcfg, changes)
            except UsageError as exc:
                raise UsageError(f"--vary {label}, for filter {f}: {exc}") from None
    checked = {c.poses: c for c in configs.values()}  # (a varied setting may put the runs on the truth's poses)
    positive("--frames", frames)
    check_options(workers, scheduler)
    seeds_ = seed_list(seeds)
    profs = [resolve(r) for r in dict.fromkeys(profile_refs)]
    for (_, label), c in configs.items():  # every run's features against every profile, before any log is read
        for prof in profs:
            try:
                check_features(prof, c, planes="features: planes (in --config or --vary)")
            except UsageError as exc:
                raise UsageError(f"--vary {label}: {exc}" if label is not None else str(exc)) from None
    sources, described = [], []
    for p in logs:
        log = reader.read(p)
        for prof in profs:
            check_inputs(log, prof)
        for c in checked.values():  # a log the runs could not be put on the truth of is refused before any run
            check_poses(log, c, frames)
        src = LogSource.of(log, p, reader.fmt, reader.options)
        refs = [r.model_dump() for r in input_refs(p, log)]
        sources.append((src, refs))
        described.append({"name": log.name, "file": p.name, "inputs": refs, "fingerprint": src.fingerprint})
        del log  # the runs read it where they run
    job_list = []
    for i, (src, refs) in enumerate(sources):
        for prof in profs:
            for f in kinds:
                for m in modes:
                    for n in counts:
                        for v, (label, _) in enumerate(varied):
                            cfg = override(configs[f, label], particles=n, **{"detection.pd_mode": m})
                            tag = f"_v{v}" if vary else ""
                            for sd in seeds_:
                                name = f"{i:02d}_{src.name}_{prof.ref}_{f}_{m}_p{n}{tag}_s{sd}"
                                labels = {"log": src.name, "profile": prof.ref, "filter": f, "pd_mode": m, "particles": n, "variant": label, "seed": sd}
                                job_list.append(SweepJob(name, src, prof, cfg, sd, labels, frames, refs))
    # the plan records the config's own particle count, as before --particles met the islands check: each run holds its
    # own, and a sweep then resumes whatever order --particles comes in
    settings = {**base.model_dump(mode="json"), "particles": own_particles(config)}
    plan = make_plan(job_list, settings, described)
    if force:  # checked before any worker starts; the old sweep is replaced only once the engine is up
        fresh(out_dir, force, inputs=[*logs, *profile_refs, config])
        check_run_names(job_list)
        made, done = False, None
    else:
        made = not os.path.lexists(out_dir)
        done = open_sweep(out_dir, plan, job_list)  # checked (and created) before any worker starts
    todo = len(job_list) - len(done or ())
    engine_cm = open_engine(workers, scheduler, todo) if todo else contextlib.nullcontext(InProcess())
    with contextlib.ExitStack() as stack:
        try:
            engine = stack.enter_context(engine_cm)
        except BaseException:
            if made:  # the cluster refused before any run: leave no empty sweep folder behind
                shutil.rmtree(out_dir, ignore_errors=True)
            raise
        if done is None:
            done = open_sweep(out_dir, plan, job_list, force=True)
        res = run_sweep(job_list, out_dir, engine, done=done, progress=progress)
        where = engine.label
    if res.failed:
        for f in res.failed:
            warn(f"run {f.line()}")
        raise DataError(
            f"{len(res.failed)} of {res.runs} runs failed ({', '.join(f.job.name for f in res.failed)}; listed in {out_dir / 'failed.yaml'}); "
            f"the {res.skipped + res.ran} others are in {out_dir}: run the same command again to complete only the missing ones"
        )
    # one column per setting, one row per metric (mean +- standard deviation over its runs)
    summary = res.summary
    attempt = (f"{res.ran} run {where}" + (f", {res.skipped} done before" if res.skipped else "")) if res.ran else "all done before"
    t = Table(title=f"sweep of {res.runs} runs ({attempt}) -> {out_dir}")
    t.add_column("metric")
    for e in summary:
        var = f"\n{e['variant']}" if e.get("variant") else ""
        t.add_column(f"{e['profile']}\n{e['filter']}, {e['pd_mode']}, {e['particles']} particles{var}\n{e['runs']} runs", justify="right", overflow="fold")
    shown = [
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
    ]
    for label, key in shown:
        if f"{key}_mean" in summary[0]:
            digits = 0 if key == "log_evidence" else 3
            t.add_row(label, *(f"{e[key + '_mean']:.{digits}f} ± {e[key + '_std']:.{digits}f}" for e in summary))
    # timings.csv is apart from runs.csv: its rows take their run's setting to be summarised by the same grouping
    timed = [{**{k: row[k] for k in SETTING}, "ms_per_step": tim["ms_per_step_mean"]} for row, tim in zip(res.rows, res.timings, strict=True)]
    t.add_row("ms per step", *(f"{e['ms_per_step_mean']:.1f}" for e in summarise(timed, SETTING)))
    out.print(t)
    if res.paired:
        out.print(paired_table(res.paired))
    if len(varied) > 1:
        out.print(evidence_table(res.rows))
