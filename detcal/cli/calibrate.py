"""``detcal calibrate``, ``detcal validate``, ``detcal selfcal`` and ``detcal icp``: parse, check, call one pipeline, print."""

from __future__ import annotations

import os
import shlex
from pathlib import Path
from typing import Annotated

import typer

from detcal.cli.common import ReaderArgs, fresh, input_refs, out, reader_options, summary_table, warn
from profiles.errors import UsageError

POSE_SOURCES = ("auto", "reference", "icp")

RobotsOpt = Annotated[list[int] | None, typer.Option("--robot", help="UTIAS: robots to read from a dataset folder (repeat the option).")]


def check_poses(poses: str | None) -> None:
    if poses is not None and poses not in POSE_SOURCES:
        raise UsageError(f"--poses: expected {', '.join(POSE_SOURCES)}, got {poses!r}")


#: Options that say where the work runs, not what it computes: not part of the command a profile records.
EXECUTION_OPTIONS = ("--workers", "--scheduler")


def portable_path(word: str) -> str:
    """An absolute path as the same command would name it from the working folder: relative to it when inside it
    (or near it), else from the home folder (``~/...``); the machine's absolute paths stay out of a profile."""
    if not os.path.isabs(word):
        return word
    p, cwd, home = Path(word), Path.cwd(), Path.home()
    if p.is_relative_to(cwd):
        return str(p.relative_to(cwd))
    if p.is_relative_to(home) and not cwd.is_relative_to(home):
        return str(Path("~") / p.relative_to(home))
    return os.path.relpath(p, cwd)


def typed_command(name: str) -> str:
    """The command as typed, every argument and option; absolute paths made relative to the working folder
    (:func:`portable_path`); ``--workers`` and ``--scheduler`` are left out, so a profile is the same bytes
    wherever it was computed."""
    from detcal.cli.common import ARGV

    words, skip = [], False
    for a in ARGV[1:]:
        if skip:
            skip = False
        elif a in EXECUTION_OPTIONS:
            skip = True
        elif not a.startswith(tuple(f"{o}=" for o in EXECUTION_OPTIONS)):
            opt, eq, value = a.partition("=")
            words.append(f"{opt}={portable_path(value)}" if eq and opt.startswith("--") else portable_path(a))
    return " ".join([f"detcal {name}", *(shlex.quote(w) for w in words)])


@reader_options("fmt", "max_backstep", "laser", "range_max", "range_sigma", "scan_topic", "truth_topic")
def calibrate_cmd(
    reader: ReaderArgs,
    logs: Annotated[list[Path] | None, typer.Argument(metavar="[LOG]...", help="Logs with truth; none: the embedded default park log.")] = None,
    name: Annotated[str | None, typer.Option(help="Profile name (default: sim-park-laser for the default log, else the first log's name).")] = None,
    version: Annotated[str, typer.Option("--version", help="Profile version MAJOR.MINOR.PATCH; an existing one is never replaced silently.")] = "1.0.0",
    description: Annotated[str, typer.Option(help="Free text stored in the profile.")] = "",
    config: Annotated[Path | None, typer.Option(help="YAML calibration config (detector, descriptors, confidence, gate, pd, ...).")] = None,
    landmarks: Annotated[
        Path | None, typer.Option(help="Landmark truth: a CSV (id, x, y, radius; world frame) or `cloud` (recurring circles of the registered scans).")
    ] = None,
    poses: Annotated[str | None, typer.Option(help="Scan poses from: auto (truth if the log has it, else ICP), reference, icp.")] = None,
    out_dir: Annotated[Path | None, typer.Option("--out", help="Run folder (default: runs/calibrate_<name>@<version>).")] = None,
    profiles_dir: Annotated[Path | None, typer.Option(help="Where to save the profile (default: the user profile folder).")] = None,
    force: Annotated[bool, typer.Option(help="Replace an existing run folder and profile version.")] = False,
    robot: RobotsOpt = None,
    per_sensor: Annotated[
        bool | None,
        typer.Option(
            "--per-sensor/--pooled-only",
            help="Detection-level logs of several sensors: also write one partially pooled profile per sensor (<name>-<sensor>); "
            "the default with several sensors. The summary says which sensors the pooled profile does not describe.",
            show_default=False,
        ),
    ] = None,
    workers: Annotated[
        int | None,
        typer.Option(
            help="Laser logs: Dask worker processes for the per-log work (default: the CPU count when there are several logs); 0 = in this process."
        ),
    ] = None,
    scheduler: Annotated[str | None, typer.Option(help="Address of an existing Dask scheduler (e.g. tcp://10.0.0.5:8786) for the per-log work.")] = None,
    accept_poor_ground_truth: Annotated[
        bool,
        typer.Option(
            "--accept-poor-ground-truth",
            help="Laser logs: write the profile even when the ground truth fails its quality checks or the data are too thin "
            "for the fits (the profile records that it did; default: refused, nothing written).",
        ),
    ] = False,
) -> None:
    """Calibrate a detector on logs with truth -> a profile and a report.

    Laser logs: the circle detector, P_D against n_p, Hotelling ellipsoid, Poisson clutter;
    sigma_r from the log, --range-sigma, or estimated from the registered scans.
    Detection-level logs (UTIAS): P_D against range, clutter from non-landmark detections.
    Several laser logs: detection, ground truth and labelling of each log on Dask workers, the fits here.
    A laser log's ground truth (ICP poses) and the data behind the fits are checked: a calibration on a poor
    ground truth or too few landmarks, true detections or populated P_D bins is refused (exit 1, nothing written).
    3D lidar logs with plane truth (detcal simulate street): the plane detector, P_D against the
    ray-traced visible points and incidence angle, clutter planes (profile kind lidar3d-planes).
    """
    from detcal.engine import check_options
    from detcal.pipelines.calibrate import CalibrationJob, ProfileTarget, check_name, run_calibration

    check_poses(poses)
    check_name(name, version)
    check_options(workers, scheduler)
    landmark_ref = landmark_input(landmarks)
    if logs:
        loaded, paths = reader.read_many(logs, robot)
        prof_name = name or loaded[0].name.lower().replace("_", "-")
        fmt = reader.fmt
    else:
        from detcal.default_log import DEFAULT_PROFILE_NAME, default_log

        log, path = default_log()
        loaded, paths, prof_name, fmt = [log], [path], name or DEFAULT_PROFILE_NAME, "native"
    if out_dir is not None and force:  # (without --force the run folder of the same request is reused: the pipeline checks)
        fresh(out_dir, force, inputs=[*paths, config, landmarks])
    refs = unique_refs([r for p, lg in zip(paths, loaded, strict=True) for r in input_refs(p, lg)] + landmark_ref)
    sources = [(p, fmt, reader.options_of(lg)) for p, lg in zip(paths, loaded, strict=True)]
    job = CalibrationJob(
        logs=loaded, inputs=refs, config=config, landmarks=landmarks, poses=poses, command=typed_command("calibrate"),
        target=ProfileTarget(name=prof_name, version=version, description=description, profiles_dir=profiles_dir, out=out_dir, force=force),
        range_sigma_given=reader.options.range_sigma is not None, per_sensor=per_sensor, sources=sources, workers=workers, scheduler=scheduler,
        accept_poor_ground_truth=accept_poor_ground_truth,
    )  # fmt: skip
    done = run_calibration(job)
    for note in done.notes:
        warn(note)
    for failure in done.summary.get("accepted_poor", []):
        warn(f"written anyway (--accept-poor-ground-truth): {failure}")
    p = done.profile
    hidden = ("logs", "range_noise", "ground_truth", "data_sufficiency", "accepted_poor", "exchangeability")
    rows = {
        "profile": f"{p.ref} ({done.profile_status}: {done.profile_path})",
        "run folder": f"{done.run_folder} ({done.run_status}" + (f", {len(done.figures)} figures)" if done.figures else ")"),
        **({"per-sensor profiles": ", ".join(f"{path.stem} ({st})" for path, st in done.members)} if done.members else {}),
        **({"per-log work": done.engine} if len(done.summary["logs"]) > 1 else {}),
        **{f"ground truth of {lg}": v for lg, v in done.summary.get("ground_truth", {}).items()},
        **({"data sufficiency": done.summary["data_sufficiency"]} if "data_sufficiency" in done.summary else {}),
        **{k: v for k, v in done.summary.items() if k not in hidden},
        **exchange_rows(done.summary.get("exchangeability")),
    }
    if not p.pd.two_d:
        rows["P_D table"] = ", ".join(f"{int(e) if float(e).is_integer() else e}:{v:.2f}" for e, v in zip(p.pd.edges[:-1], p.pd.pd, strict=True))
    out.print(summary_table(f"calibration of {', '.join(done.summary['logs'])}", rows))


def exchange_rows(ex: dict | None) -> dict:
    """The summary's rows on which sensors the pooled profile does not describe (each tested against the pooled
    profile of the others, :func:`calib.detlevel.exchangeability`)."""
    if not ex:
        return {}
    odd = ex["not_exchangeable"]
    head = "none: the pooled profile describes every sensor" if odd == "none" else (odd if isinstance(odd, str) else ", ".join(odd))
    return {"not exchangeable (pooled profile rejected)": head, **{f"  {k} against the others": v for k, v in ex["per_sensor"].items()}}


def landmark_input(landmarks: Path | None) -> list:
    """A landmark CSV is an input of the profile (name and sha256); ``cloud`` is not a file."""
    if landmarks is None or str(landmarks) == "cloud":
        return []
    from calib.calibrate import read_landmarks_csv
    from calib.io.common import file_digest
    from profiles.profile import InputRef

    if not landmarks.is_file():
        raise UsageError(f"--landmarks: {landmarks}: no such file (give a CSV of id, x, y, radius, or `cloud`)")
    read_landmarks_csv(landmarks)  # a bad file is refused before any work
    return [InputRef(name=landmarks.name, sha256=file_digest(landmarks))]


def unique_refs(refs: list) -> list:
    """Each input once (a dataset folder read for several robots hashes the same files)."""
    seen, outl = set(), []
    for r in refs:
        if (r.name, r.sha256) not in seen:
            seen.add((r.name, r.sha256))
            outl.append(r)
    return outl


@reader_options("fmt", "max_backstep", "laser", "range_max", "scan_topic")
def icp_cmd(
    log_path: Annotated[Path, typer.Argument(metavar="LOG", help="A log with laser scans and odometry.")],
    reader: ReaderArgs,
    out_dir: Annotated[Path | None, typer.Option("--out", help="Run folder (default: runs/icp_<log name>).")] = None,
    relations: Annotated[Path | None, typer.Option(help="Benchmark relations (t1 t2 x y z roll pitch yaw) to score the poses against.")] = None,
    force: Annotated[bool, typer.Option(help="Replace the run folder if it exists.")] = False,
) -> None:
    """Ground truth from the scans: correlative scan-to-map matching refined by ICP, verified loop closures, a robust
    pose graph. Writes poses.csv, poses_tum.txt and poses_kitti.txt (for evo_ape / evo_rpe), quality.yaml, map.png."""
    from calib.groundtruth import write_icp_run

    log = reader.read(log_path)
    target = out_dir or Path("runs") / f"icp_{log.name}"
    fresh(target, force, inputs=[log_path, relations])
    summary = write_icp_run(log, target, relations=relations, overwrite=force)
    out.print(summary_table(f"ICP ground truth of {log.name} -> {target}", summary))
    if relations is not None:
        for name in ("icp", "odometry"):
            out.print(relation_line(summary, name), soft_wrap=True)
    if summary["ground_truth"] != "passes":
        warn(f"{log.name}: ground truth fails: {'; '.join(summary['failed'])} (map.png marks where; quality.yaml has the figures)")


def relation_line(summary: dict, name: str) -> str:
    """The relation error of ``name``'s poses (icp, odometry) as Kuemmerle et al. (2009) report it: mean +- sd, max."""
    keys = ("trans_error_mean_m", "trans_error_std_m", "trans_error_max_m", "rot_error_mean_deg", "rot_error_std_deg", "rot_error_max_deg")
    v = {k: summary[f"{name}_{k}"] for k in keys}
    return (
        f"relation error of the {'ground truth' if name == 'icp' else name} ({summary[f'{name}_relations']} relations): "
        f"{v['trans_error_mean_m']:.4f} +- {v['trans_error_std_m']:.4f} m (max {v['trans_error_max_m']:.3f}), "
        f"{v['rot_error_mean_deg']:.3f} +- {v['rot_error_std_deg']:.3f} deg (max {v['rot_error_max_deg']:.2f})"
    )


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
    from calib.progress import progress
    from detcal.pipelines.self_calibration import SelfCalibrationRequest
    from detcal.pipelines.slam_run import SettingsRequest

    request = SelfCalibrationRequest(
        log_path=log_path, read=reader.read, profile=profile_ref, settings=SettingsRequest(config, filter_, particles),
        iterations=iterations, tolerance=tolerance, average_from=average_from, seed=seed, name=name, version=version,
        out=out_dir, profiles_dir=profiles_dir, force=force, command=typed_command("selfcal"), inputs=input_refs,
    )  # fmt: skip
    rows = request.run(progress, fresh)
    out.print(summary_table(f"self-calibration of {rows.pop('log')}", rows))
