"""``detcal selfcal``: calibrate a detector against a SLAM run's own map, iterated (no landmark truth)."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from detcal.cli.common import ReaderArgs, fresh, input_refs, out, positive, reader_options, summary_table
from profiles.errors import UsageError


@reader_options()
def selfcal_cmd(
    log_path: Annotated[Path, typer.Argument(metavar="LOG", help="A detection-level log with odometry (no landmark truth needed).")],
    reader: ReaderArgs,
    profile_ref: Annotated[str, typer.Option("--profile", help="The starting profile (e.g. a nominal one): name@version or a file.")],
    config: Annotated[Path | None, typer.Option(help="YAML SLAM settings (see detcal slam run).")] = None,
    filter_: Annotated[
        str | None,
        typer.Option(
            "--filter", help="Map filter of the SLAM runs: rbphd, lmb or glmb (default: the config's); the profile is measured against its map."
        ),
    ] = None,
    iterations: Annotated[int, typer.Option(help="SLAM runs at most.")] = 5,
    tolerance: Annotated[float, typer.Option(help="Stop when P_D (absolute) and noise and clutter (relative) change by less than this.")] = 0.02,
    average_from: Annotated[
        int | None,
        typer.Option(
            help="Average the measurements of the runs from this iteration on (0 = the first) and run on their average: "
            "each run's map is a random draw, so the plain iteration scatters about its fixed point and only the average settles."
        ),
    ] = None,
    seed: Annotated[int, typer.Option(help="Filter seed of every run.")] = 0,
    particles: Annotated[int | None, typer.Option(help="Particles (default: the config's).")] = None,
    name: Annotated[str | None, typer.Option(help="Name of the measured profile (default: <log name>-selfcal).")] = None,
    version: Annotated[str, typer.Option("--version", help="Its version MAJOR.MINOR.PATCH.")] = "1.0.0",
    out_dir: Annotated[Path | None, typer.Option("--out", help="Run folder (default: runs/selfcal_<name>@<version>).")] = None,
    profiles_dir: Annotated[Path | None, typer.Option(help="Where to save the profile (default: the user profile folder).")] = None,
    force: Annotated[bool, typer.Option(help="Replace an existing run folder and profile version.")] = False,
) -> None:
    """Self-calibration: run SLAM, measure P_D against range (unoccluded map features), clutter, noise and the
    odometry's steering offset against the run's own map and trajectory, run again, until nothing changes."""
    from detcal.cli.calibrate import typed_command
    from detcal.pipelines.slam_run import SettingsRequest
    from calib.progress import progress
    from calib.selfcal import SelfCalConfig, pool_self_calibrations, profile_change, self_calibrate
    from detcal.reports.self_calibration import fill_selfcal_run
    from profiles.atomic import Output, atomic_outputs
    from profiles.profile import NAME_RE, SEMVER_RE
    from profiles.store import check_new_version, looks_like_profile, profile_path, resolve, write_profile_text
    from slam_runtime.run import check_inputs
    from detcal.pipelines.self_calibration import self_calibration

    positive("--iterations", iterations)
    request = SettingsRequest(config, filter_, particles)
    if seed < 0:
        raise UsageError(f"--seed: expected a non-negative integer, got {seed}")
    if average_from is not None and iterations < 2:
        raise UsageError(f"--average-from: averaging needs at least two runs, so --iterations 2 or more (got --iterations {iterations})")
    if average_from is not None and not 0 <= average_from <= iterations - 2:
        raise UsageError(
            f"--average-from: expected an iteration from 0 to {iterations - 2} (--iterations {iterations}: at least two runs to average), got {average_from}"
        )
    if not 0 < tolerance < float("inf"):
        raise UsageError(f"--tolerance: expected a positive number, got {tolerance}")
    if not SEMVER_RE.match(version):
        raise UsageError(f"--version: {version!r} is not MAJOR.MINOR.PATCH")
    cfg, _ = request.settings()
    start = resolve(profile_ref)
    if start.pd.covariate != "range":
        raise UsageError(f"profile {start.ref}: self-calibration measures P_D against range; this profile has a {start.pd.covariate} table")
    log = reader.read(log_path)
    if log.detections is None or log.scans is not None:
        raise UsageError(f"{log.name}: self-calibration takes a detection-level log (detections, no scans)")
    check_inputs(log, start)
    prof_name = name or f"{log.name.lower().replace('_', '-')}-selfcal"
    if not NAME_RE.match(prof_name):
        raise UsageError(f"--name: {prof_name!r} must match [a-z0-9][a-z0-9._-]*")
    target = out_dir or Path("runs") / f"selfcal_{prof_name}@{version}"
    start_file = profile_path(profile_ref)  # given by name, it is still a file --force must not replace
    fresh(target, force, inputs=[log_path, start_file, config])  # both outputs decided before any work
    saved, status = check_new_version(prof_name, version, profiles_dir, force=force)
    fresh(saved, force, directory=False, owned=looks_like_profile, inputs=[start_file])
    refs = input_refs(log_path, log)
    command = typed_command("selfcal")
    scfg = SelfCalConfig()

    cals = []

    def measure(lg, traj, map_xy, map_w, prior, k):
        c = self_calibrate(
            lg, traj, map_xy, map_w, prior, scfg, name=prof_name, version=version, run=f"iteration {k} of this self-calibration",
            iteration=k, input_refs=refs, command=command, mount_yaw=cfg.mount_yaw,
        )
        if average_from is None or k < average_from:
            return c.profile, c.summary
        cals.append(c)  # only the runs that are averaged are kept (their pairs and detections)
        pooled = pool_self_calibrations(cals, scfg, iterations=list(range(average_from, k + 1)))
        return pooled, {**c.summary, "averaged_runs": k + 1 - average_from, "averaged_false_alarms_per_frame": pooled.clutter.rate}

    history = self_calibration(
        log, start, cfg, seed, measure, profile_change, iterations=iterations, tolerance=tolerance, average_from=average_from, progress=progress
    )
    final = history[-1].measured
    from detcal.reports.slam_run import write_slam_run

    last = history[-1]
    settings = {"log": log_path.name, "inputs": [r.model_dump() for r in refs], "profile": last.profile.ref, "seed": seed,
                "settings": last.config.model_dump(mode="json")}
    outputs = [Output(target, directory=True, overwrite=force), Output(saved, overwrite=force, owned=looks_like_profile)]
    with atomic_outputs(outputs) as (run_tmp, prof_tmp):  # the run folder and the profile in one step
        run_tmp.mkdir()
        fill_selfcal_run(log, history, run_tmp, last_run=lambda folder: write_slam_run(log, last.result, folder, settings))
        write_profile_text(final, prof_tmp)
    status = "written" if status == "write" else "replaced"
    cfg_next = last.next_config or last.config  # the biases slam.yaml holds (averaged with --average-from)
    rows = {
        "profile": f"{final.ref} ({status}: {saved})",
        "run folder": str(target),
        "iterations": len(history),
        # with averaging the change of the average shrinks as 1/n whatever the runs do: it settles; its precision is the s.e. below
        ("converged" if average_from is None else "average settled (moved < tolerance)"): bool(last.change < tolerance),
        **(_spread(history[average_from:]) if average_from is not None and len(history) > average_from + 1 else {}),
        "last change": last.change,
        **{k: v for k, v in last.result.metrics.items() if k.startswith(("trajectory_rmse", "odometry_rmse", "ms_per_step_median"))},
        **(
            {"steering offset [rad]": cfg_next.motion.ackermann.steer_offset, "speed scale": cfg_next.motion.ackermann.speed_scale}
            if last.bias
            else {}
        ),
        "P_D table": ", ".join(f"{e:g}:{v:.2f}" for e, v in zip(final.pd.edges[:-1], final.pd.pd, strict=True)),
    }
    out.print(summary_table(f"self-calibration of {log.name}", rows))


def _spread(runs) -> dict:
    """What the averaged runs measured one by one: the mean with its standard error (the runs' sd / sqrt(n)),
    the precision of the average, which the change between consecutive averages (shrinking as 1/n) is not."""
    import numpy as np

    out = {"averaged runs": len(runs)}
    for key, label in (("false_alarms_per_frame", "false alarms per frame"), ("range_sigma_m", "range noise [m]")):
        x = np.array([it.summary[key] for it in runs], dtype=float)
        out[f"{label}, runs' mean +- s.e."] = f"{x.mean():.4g} +- {x.std(ddof=1) / np.sqrt(x.size):.2g}"
    return out
