"""``detcal slam run`` and ``detcal slam sweep``: parse, check, call one pipeline, print."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from detcal.cli.common import ReaderArgs, SectionedCommand, fresh, input_refs, out, reader_options, summary_table, warn
from profiles.errors import UsageError
from slam_runtime.mapfilter import MAP_FILTERS

app = typer.Typer(help="Run SLAM filters with a detector profile.", no_args_is_help=True, rich_markup_mode=None)

FILTER, MEASUREMENT, MOTION, OUTPUT, ADVANCED = "Filter", "Measurement", "Motion", "Output", "Advanced"

ProfileOpt = Annotated[str, typer.Option("--profile", help="name[@version] or a file.", rich_help_panel=FILTER)]
FilterOpt = Annotated[str | None, typer.Option("--filter", help="Map filter.", rich_help_panel=FILTER)]
ParticlesOpt = Annotated[int | None, typer.Option(help="Particles.", rich_help_panel=FILTER)]
SeedOpt = Annotated[int, typer.Option(help="Seed: same seed, same run.", rich_help_panel=FILTER)]
FeaturesOpt = Annotated[str | None, typer.Option(help="Landmarks: points (2D) or planes (3D clouds).", rich_help_panel=MEASUREMENT)]
PdModeOpt = Annotated[str | None, typer.Option(help="P_D from the profile, or constant (for comparison).", rich_help_panel=MEASUREMENT)]
PosesOpt = Annotated[str | None, typer.Option("--poses", help="estimated (full SLAM) or ground_truth (mapping only).", rich_help_panel=MOTION)]
FramesOpt = Annotated[int | None, typer.Option(help="Only the first N frames.", rich_help_panel=OUTPUT)]
ConfigOpt = Annotated[Path | None, typer.Option(help="YAML settings (unknown keys are refused).", rich_help_panel=ADVANCED)]
SetOpt = Annotated[list[str] | None, typer.Option("--set", metavar="KEY=VALUE", help="One setting, e.g. filter.cap=600 (repeat).", rich_help_panel=ADVANCED)]


@app.command("run", cls=SectionedCommand)
@reader_options()
def slam_run_cmd(
    log_path: Annotated[Path, typer.Argument(metavar="LOG", help="A log with odometry and scans, detections or clouds.")],
    reader: ReaderArgs,
    profile_ref: ProfileOpt,
    filter_: FilterOpt = None,
    particles: ParticlesOpt = None,
    seed: SeedOpt = 0,
    features: FeaturesOpt = None,
    pd_mode: PdModeOpt = None,
    poses: PosesOpt = None,
    out_dir: Annotated[Path | None, typer.Option("--out", help="Run folder (default: runs/slam_<log>_<profile>_<seed>).", rich_help_panel=OUTPUT)] = None,
    frames: FramesOpt = None,
    force: Annotated[bool, typer.Option("--force", help="Replace the run folder if it exists.", rich_help_panel=OUTPUT)] = False,
    config: ConfigOpt = None,
    sets: SetOpt = None,
) -> None:
    """SLAM over a log with a detector profile: trajectory, map, metrics, figures. Without --config the settings come
    from the profile and the log, and the command prints what it used."""
    from calib.progress import progress
    from detcal.pipelines.slam_run import SettingsRequest, SlamRun, parse_sets
    from profiles.store import profile_path, resolve
    from slam_runtime.run import check_inputs, describe, why_undefined

    request = SettingsRequest(config, filter_, particles, pd_mode, features, poses, parse_sets(sets))
    if frames is not None and frames < 1:
        raise UsageError(f"--frames: expected a positive integer, got {frames}")
    if seed < 0:
        raise UsageError(f"--seed: expected a non-negative integer, got {seed}")
    prof = resolve(profile_ref)
    request.settings(profile_path(profile_ref))  # (a bad setting is refused before the log is read)
    log = reader.read(log_path)
    check_inputs(log, prof)
    cfg, motion, why = request.derived(log, prof, profile_path(profile_ref))
    target = out_dir or Path("runs") / f"slam_{log.name}_{prof.ref}_{seed}"
    fresh(target, force, inputs=[log_path, profile_ref, config])
    if config is None:
        used = describe(log, prof, cfg)
        if motion is not None:
            used["motion"] += f" (from {motion})"
        for group, source in why.items():
            used[group] += f" (from {source})"
        out.print(summary_table(f"settings derived for {log.name} and {prof.ref} (no --config)", used))
    elif why:
        out.print(f"settings {config} leaves unset, derived: " + "; ".join(f"{g} from {src}" for g, src in why.items()))
    inputs = [r.model_dump() for r in input_refs(log_path, log)]
    res = SlamRun(log, log_path.name, inputs, prof, cfg, seed, target, frames, force).run(progress)
    shown = {k: v for k, v in res.metrics.items() if not isinstance(v, dict)}
    mode = " (poses: ground truth, mapping only)" if cfg.poses == "ground_truth" else ""
    out.print(summary_table(f"{res.filter}-SLAM{mode} on {log.name} with {prof.ref} -> {target}", shown, why_undefined))


#: Most seeds one sweep takes (each seed is a run per log, profile and setting), and the largest seed (a seed is
#: recorded as a signed 64-bit integer in the run tables).
MAX_SEEDS = 10_000
MAX_SEED = 2**63 - 1


def seed_list(text: str) -> list[int]:
    """`5` -> 0..4; `1,3,7` or `1-5` -> those seeds. The count is checked before a list is built."""
    try:
        if "," in text:
            seeds = [int(x) for x in text.split(",")]
            count = len(seeds)
        elif "-" in text:
            a, b = (int(x) for x in text.split("-", 1))
            count, seeds = b - a + 1, None
        else:
            a, count, seeds = 0, int(text), None
    except ValueError:
        raise UsageError(f"--seeds: expected a count (5), a list (1,3,7) or a range (1-5), got {text!r}") from None
    if count > MAX_SEEDS:
        raise UsageError(f"--seeds: {text!r} gives {count} seeds, more than one sweep runs (at most {MAX_SEEDS}); split the sweep")
    if seeds is None:
        seeds = list(range(a, a + max(count, 0)))
    if seeds and max(seeds) > MAX_SEED:
        raise UsageError(f"--seeds: a seed above {MAX_SEED} (2^63 - 1) in {text!r}")
    if not seeds:
        what = "a count of at least 1" if "-" not in text else "a range whose end is not below its start"
        raise UsageError(f"--seeds: expected {what} (a count of 3 is seeds 0-2; seed 0 alone is --seeds 0-0), got {text!r}")
    if min(seeds) < 0:
        raise UsageError(f"--seeds: expected non-negative seeds, got {text!r}")
    if len(set(seeds)) != len(seeds):
        raise UsageError(f"--seeds: a seed is listed twice in {text!r}")
    return seeds


@app.command("sweep")
@reader_options("fmt", "max_backstep", "robot")
def slam_sweep_cmd(
    logs: Annotated[list[Path], typer.Argument(metavar="LOG...", help="Logs to run on (e.g. simulated parks of different seeds).")],
    reader: ReaderArgs,
    profile_refs: Annotated[list[str], typer.Option("--profile", help="Detector profile(s): name or name@version, or a file (repeat the option).")],
    pd_modes: Annotated[list[str] | None, typer.Option("--pd-mode", help="profile and/or constant (repeat; default: both).")] = None,
    filters: Annotated[list[str] | None, typer.Option("--filter", help=f"Map filters: {MAP_FILTERS.choices('and')} (repeat; default: the config's).")] = None,
    particles: Annotated[list[int] | None, typer.Option("--particles", help="Particle counts (repeat; default: the config's).")] = None,
    seeds: Annotated[str, typer.Option(help="Filter seeds: a count (3), a list (1,3,7) or a range (1-5).")] = "1",
    config: Annotated[Path | None, typer.Option(help="YAML settings shared by every run.")] = None,
    vary: Annotated[
        list[str] | None,
        typer.Option(
            "--vary",
            help="Vary a setting: KEY=V1,V2,... (a dotted path of the settings, e.g. filter.noise_inflation=1,2; values read as YAML; "
            "repeat to cross settings). Runs are labelled `variant`, compared in paired.csv and ranked by their log evidence.",
        ),
    ] = None,
    poses: Annotated[str | None, typer.Option("--poses", help="estimated (full SLAM) or ground_truth (mapping only).")] = None,
    frames: Annotated[int | None, typer.Option(help="Only the first N frames of each log.")] = None,
    workers: Annotated[
        int | None, typer.Option(help="Worker processes of the local Dask cluster (default: the CPU count); 0 = in this process, one task after another.")
    ] = None,
    scheduler: Annotated[str | None, typer.Option(help="Address of an existing Dask scheduler (e.g. tcp://10.0.0.5:8786) instead of a local cluster.")] = None,
    out_dir: Annotated[Path, typer.Option("--out", help="Sweep folder: one run folder per run, runs.csv, summary.csv, paired.csv, timings.csv.")] = Path("runs/sweep"),
    force: Annotated[bool, typer.Option(help="Start the sweep folder anew (without it, the same command resumes an unfinished sweep).")] = False,
    write_config: Annotated[
        Path | None,
        typer.Option(
            "--write-config",
            help="After the runs, write a settings file: --config's settings, the options given and the varied settings at the values of "
            "the likeliest variant (the largest mean log evidence). Needs --vary and one profile, filter, P_D mode and particle count.",
        ),
    ] = None,
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
    from calib.progress import progress
    from detcal.cli.tables import evidence_table, paired_table, sweep_table
    from detcal.pipelines.slam_run import SettingsRequest
    from detcal.pipelines.sweep import SweepRequest

    settings = SettingsRequest(config, particles=particles[0] if particles else None, poses=poses)
    sweep = SweepRequest(
        logs, reader.read, reader.fmt, reader.options, profile_refs, settings, seed_list(seeds), out_dir, filters, pd_modes,
        particles, vary, frames, workers, scheduler, force, inputs=input_refs, write_config=write_config,
    )  # fmt: skip
    sweep.prepare()
    if force:
        fresh(out_dir, force, inputs=[*logs, *profile_refs, config])
    res, where = sweep.run(progress)
    for f in res.failed:
        warn(f"run {f.line()}")
    sweep.refuse_failures(res)
    out.print(sweep_table(res, where))
    if res.paired:
        out.print(paired_table(res.paired))
    if len(sweep.varied) > 1:
        out.print(evidence_table(res.rows))
    if write_config is not None:
        rank = sweep.write_likeliest(res.rows)
        out.print(f"settings of the likeliest variant ({rank['best']}) written to {write_config}")
