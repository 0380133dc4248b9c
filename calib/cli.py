"""The ``detcal`` command line: the one composition root.

Thin by design: parse, cross-check options, call one pipeline function, print
a result table. Library errors (:class:`profiles.errors.DetcalError`) become
one-line messages with exit code 1 (bad data) or 2 (usage); a user never sees
a traceback for bad input.
"""

from __future__ import annotations

import os
import sys
from pathlib import Path
from typing import Annotated

import numpy as np
import typer
from rich.console import Console
from rich.table import Table

from calib import __version__
from profiles.errors import DetcalError, UsageError

app = typer.Typer(
    help="detcal: measure a feature detector's P_D and clutter statistics for RFS SLAM.",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
)
log_app = typer.Typer(help="Inspect and convert sensor logs.", no_args_is_help=True)
sim_app = typer.Typer(help="Simulate sensor logs with exported truth.", no_args_is_help=True)
profile_app = typer.Typer(help="List, show, validate, compare and export detector profiles.", no_args_is_help=True)
slam_app = typer.Typer(help="Run SLAM filters with a detector profile.", no_args_is_help=True)
app.add_typer(log_app, name="log")
app.add_typer(sim_app, name="simulate")
app.add_typer(profile_app, name="profile")
app.add_typer(slam_app, name="slam")

out = Console(highlight=False)
err = Console(stderr=True, highlight=False)

FormatOpt = Annotated[str | None, typer.Option("--format", "-f", help="Input format: native, carmen, rosbag, victoria, utias, kitti (default: from the path).")]
BackstepOpt = Annotated[float, typer.Option(help="Tolerated step back in time within a stream [s]; such records are re-sorted. 0 = strict.")]
LaserOpt = Annotated[str, typer.Option(help="CARMEN: which laser, front or rear.")]
RangeMaxOpt = Annotated[float | None, typer.Option(help="CARMEN: readings at or above this [m] are no return (default: the log's saturation value).")]
RobotOpt = Annotated[int, typer.Option(help="UTIAS: which robot (1-5).")]
ScanTopicOpt = Annotated[str | None, typer.Option(help="Bags: the LaserScan topic.")]
OdomTopicOpt = Annotated[str | None, typer.Option(help="Bags: the nav_msgs/Odometry topic.")]
TruthTopicOpt = Annotated[str | None, typer.Option(help="Bags: a ground-truth pose topic (Odometry or PoseStamped).")]


POSE_SOURCES = ("auto", "reference", "icp")


def _check_poses(poses: str | None) -> None:
    if poses is not None and poses not in POSE_SOURCES:
        raise UsageError(f"--poses: expected {', '.join(POSE_SOURCES)}, got {poses!r}")


def _fresh(target: Path, force: bool) -> None:
    """Refuse to replace an existing output unless --force was given."""
    if target.exists() and not force:
        raise UsageError(f"{target}: already exists (use --force to replace it)")


def _read(path: Path, fmt, max_backstep, laser, range_max, robot, scan_topic, odom_topic, truth_topic):
    from calib.io.registry import ReadOptions, read_log

    opts = ReadOptions(
        max_backstep=max_backstep,
        laser=laser,
        range_max=range_max,
        robot=robot,
        scan_topic=scan_topic,
        odom_topic=odom_topic,
        truth_topic=truth_topic,
    )
    return read_log(path, fmt, opts)


def _version(value: bool) -> None:
    if value:
        out.print(f"detcal {__version__}")
        raise typer.Exit()


@app.callback()
def _root(
    version: Annotated[bool, typer.Option("--version", callback=_version, is_eager=True, help="Print the version and exit.")] = False,
) -> None:
    """detcal: measure a feature detector's P_D and clutter statistics for RFS SLAM."""


@log_app.command("info")
def log_info(
    path: Annotated[Path, typer.Argument(help="A log file or folder.")],
    fmt: FormatOpt = None,
    max_backstep: BackstepOpt = 1.0,
    laser: LaserOpt = "front",
    range_max: RangeMaxOpt = None,
    robot: RobotOpt = 1,
    scan_topic: ScanTopicOpt = None,
    odom_topic: OdomTopicOpt = None,
    truth_topic: TruthTopicOpt = None,
) -> None:
    """Print a summary of a log: streams, counts, duration, beam geometry."""
    log = _read(path, fmt, max_backstep, laser, range_max, robot, scan_topic, odom_topic, truth_topic)
    out.print(info_table(log, path))


def info_table(log, path: Path) -> Table:
    t = Table(title=f"{path} ({log.source.get('reader', 'native')})", show_header=True)
    t.add_column("stream")
    t.add_column("count", justify="right")
    t.add_column("details")
    span = log.time_span()
    if log.scans is not None:
        s = log.scans
        finite = np.isfinite(s.ranges)
        t.add_row("scans", f"{len(s):,}", f"{s.n_beams} beams, {finite.mean() * 100:.1f} % returning")
    if log.odometry is not None:
        t.add_row("odometry", f"{len(log.odometry):,}", f"{log.odometry.kind}: {', '.join(log.odometry.columns)}")
    for k, r in log.reference.items():
        t.add_row(f"reference ({k})", f"{len(r):,}", "x, y" + (", theta" if np.isfinite(r.poses[:, 2]).any() else ""))
    if log.landmarks is not None:
        t.add_row("landmarks", f"{len(log.landmarks):,}", "with radii" if np.isfinite(log.landmarks.radius).any() else "positions")
    if log.detections is not None:
        d = log.detections
        t.add_row("detection frames", f"{d.n_frames:,}", "")
        t.add_row("detections", f"{len(d):,}", "descriptors: " + (", ".join(sorted(d.descriptors)) or "none"))
    if log.clouds is not None:
        t.add_row("point clouds", f"{len(log.clouds):,}", f"{log.clouds.points.shape[0]:,} points")
    if span is not None:
        t.add_row("duration", "", f"{(span[1] - span[0]) / 1e9:,.3f} s")
    sen = log.sensor
    if sen is not None:
        geo = f"{sen.kind}"
        if sen.n_beams is not None:
            geo += (
                f", {sen.n_beams} beams from {np.rad2deg(sen.angle_min):.2f} deg every "
                f"{np.rad2deg(sen.angle_increment):.4f} deg (fov {np.rad2deg(sen.field_of_view):.1f} deg)"
            )
        if sen.range_max is not None:
            geo += f", range {sen.range_min:g}-{sen.range_max:g} m"
        if sen.range_sigma is not None:
            geo += f", sigma_r {sen.range_sigma:g} m"
        m = sen.mount
        geo += f", mounted at ({m.x:g}, {m.y:g}, {m.theta:g})"
        t.add_row("sensor", "", geo)
    moved = {k: v for k, v in dict(log.source.get("reordered", {})).items() if v}
    if moved:
        t.add_row("re-sorted", "", ", ".join(f"{k}: {v}" for k, v in moved.items()) + " records were out of time order")
    return t


@log_app.command("convert")
def log_convert(
    src: Annotated[Path, typer.Argument(help="The log to read.")],
    dst: Annotated[Path, typer.Argument(help="Output: NAME.dlog (native) or a folder name (ROS 2 bag).")],
    to: Annotated[str | None, typer.Option("--to", help="Output format: native or ros2 (default: from DST).")] = None,
    force: Annotated[bool, typer.Option(help="Replace DST if it exists.")] = False,
    fmt: FormatOpt = None,
    max_backstep: BackstepOpt = 1.0,
    laser: LaserOpt = "front",
    range_max: RangeMaxOpt = None,
    robot: RobotOpt = 1,
    scan_topic: ScanTopicOpt = None,
    odom_topic: OdomTopicOpt = None,
    truth_topic: TruthTopicOpt = None,
) -> None:
    """Convert a log to detcal's native format or to a ROS 2 bag."""
    from calib.io.registry import output_format, write_log

    kind = output_format(dst, to)  # check before the (possibly long) read
    _fresh(dst, force)
    log = _read(src, fmt, max_backstep, laser, range_max, robot, scan_topic, odom_topic, truth_topic)
    write_log(log, dst, kind, overwrite=force)
    out.print(f"wrote {dst} ({kind}): {', '.join(log.streams())}")


@sim_app.command("park")
def simulate_park_cmd(
    out_dir: Annotated[Path, typer.Option("--out", help="Run folder to create.")],
    seed: Annotated[int, typer.Option(help="Random seed; same seed and config, same bytes.")] = 0,
    config: Annotated[Path | None, typer.Option(help="YAML park config (unknown keys are refused); defaults otherwise.")] = None,
    force: Annotated[bool, typer.Option(help="Replace the run folder if it exists.")] = False,
) -> None:
    """Simulate a 2D park (trees, bushes, walls, posts, dust) seen by a laser on a moving vehicle."""
    from calib.config import load_yaml_model
    from calib.sim.park import ParkConfig
    from calib.sim.run import simulate_to

    if seed < 0:
        raise UsageError(f"--seed: expected a non-negative integer, got {seed}")
    cfg = load_yaml_model(ParkConfig, config)
    _fresh(out_dir, force)
    summary = simulate_to(out_dir, seed, cfg, overwrite=force)
    t = Table(title=f"simulated park -> {out_dir}")
    t.add_column("quantity")
    t.add_column("value", justify="right")
    for k, v in summary.items():
        t.add_row(k, f"{v:.3f}" if isinstance(v, float) else str(v))
    out.print(t)


@app.command("detect")
def detect_cmd(
    log_path: Annotated[Path, typer.Argument(metavar="LOG", help="A log with laser scans.")],
    out_dir: Annotated[Path | None, typer.Option("--out", help="Run folder (default: runs/detect_<log name>).")] = None,
    profile: Annotated[str | None, typer.Option(help="Use a profile's detector, Hotelling gate and P_D table (name or name@version, or a file).")] = None,
    config: Annotated[Path | None, typer.Option(help="YAML with `detector:` parameters and an optional `hotelling:` gate.")] = None,
    plot: Annotated[int | None, typer.Option("--plot", metavar="SCAN", help="Also draw this scan: clusters, circles, P_D field.")] = None,
    force: Annotated[bool, typer.Option(help="Replace the run folder if it exists.")] = False,
    fmt: FormatOpt = None,
    max_backstep: BackstepOpt = 1.0,
    laser: LaserOpt = "front",
    range_max: RangeMaxOpt = None,
    scan_topic: ScanTopicOpt = None,
) -> None:
    """Run the circle (tree) detector over every scan and write a detections table."""
    from calib.config import load_yaml_model
    from calib.detect import DetectConfig, write_detect_run
    pd_table = None
    if profile is not None:
        if config is not None:
            raise UsageError("--profile and --config both set the detector; give one")
        from profiles.schema import HotellingParams
        from profiles.store import resolve

        prof = resolve(profile)
        if prof.detector.kind != "circle2d":
            raise UsageError(f"profile {prof.ref} is for an external detector, not the circle detector")
        hot = None if prof.hotelling is None else HotellingParams.model_validate(prof.hotelling.model_dump(include=set(HotellingParams.model_fields)))
        cfg = DetectConfig(detector=prof.detector.circle, hotelling=hot, k_sigma=prof.detector.k_sigma)
        pd_table = prof.pd if prof.pd.covariate == "n_p" else None
    else:
        cfg = load_yaml_model(DetectConfig, config)
    log = _read(log_path, fmt, max_backstep, laser, range_max, 1, scan_topic, None, None)
    target = out_dir or Path("runs") / f"detect_{log.name}"
    _fresh(target, force)
    summary = write_detect_run(log, cfg, target, plot_scan=plot, pd_table=pd_table, overwrite=force)
    t = Table(title=f"detections -> {target}")
    t.add_column("quantity")
    t.add_column("value", justify="right")
    for k, v in summary.items():
        t.add_row(k, f"{v:.3f}" if isinstance(v, float) else str(v))
    out.print(t)


def _read_many(paths, robots, fmt, max_backstep, laser, range_max, scan_topic, truth_topic):
    """Logs from paths; a UTIAS dataset folder gives one log per requested robot."""
    from calib.io.registry import detect_format

    loaded, used = [], []
    for p in paths:
        kind = fmt or detect_format(p)
        for r in (robots or [1]) if kind == "utias" else [1]:
            loaded.append(_read(p, fmt, max_backstep, laser, range_max, r, scan_topic, None, truth_topic))
            used.append(p)
    return loaded, used


def _source_refs(log):
    from calib.detlevel import input_refs_for

    return input_refs_for(log)


def _summary_table(title: str, rows: dict) -> Table:
    t = Table(title=title)
    t.add_column("quantity")
    t.add_column("value", justify="right")
    for k, v in rows.items():
        if isinstance(v, float):
            v = f"{v:.4g}"
        elif isinstance(v, list):
            v = ", ".join(str(x) for x in v)
        t.add_row(k, str(v))
    return t


@app.command("calibrate")
def calibrate_cmd(
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
    robot: Annotated[list[int] | None, typer.Option(help="UTIAS: robots to read from a dataset folder (repeat the option).")] = None,
    fmt: FormatOpt = None,
    max_backstep: BackstepOpt = 1.0,
    laser: LaserOpt = "front",
    range_max: RangeMaxOpt = None,
    scan_topic: ScanTopicOpt = None,
    truth_topic: TruthTopicOpt = None,
) -> None:
    """Calibrate a detector on logs with truth -> a profile and a report.

    Laser logs: the circle detector, P_D against n_p, Hotelling ellipsoid, Poisson clutter.
    Detection-level logs (UTIAS): P_D against range, clutter from non-landmark detections.
    """
    import shlex

    from calib.calibrate import CalibrateConfig, calibrate
    from calib.config import load_yaml_model
    from calib.default import DEFAULT_PROFILE_NAME, default_log
    from calib.runs import write_calibration_run
    from profiles.profile import NAME_RE, SEMVER_RE
    from profiles.store import save_profile

    _check_poses(poses)
    if not SEMVER_RE.match(version):
        raise UsageError(f"--version: {version!r} is not MAJOR.MINOR.PATCH")
    from calib.io.common import file_digest
    from profiles.profile import InputRef

    if logs:
        loaded, paths = _read_many(logs, robot, fmt, max_backstep, laser, range_max, scan_topic, truth_topic)
        prof_name = name or loaded[0].name.lower().replace("_", "-")
    else:
        log, path = default_log()
        loaded = [log]
        prof_name = name or DEFAULT_PROFILE_NAME
        paths = [path]
    refs = [InputRef(name=p.name, sha256=file_digest(p)) for p in dict.fromkeys(paths)]
    if not NAME_RE.match(prof_name):
        raise UsageError(f"--name: {prof_name!r} must match [a-z0-9][a-z0-9._-]*")
    target = out_dir or Path("runs") / f"calibrate_{prof_name}@{version}"
    _fresh(target, force)
    # the command as typed; absolute paths lose their folders (a profile names inputs by file name and hash)
    words = [Path(a).name if os.path.isabs(a) else a for a in sys.argv[2:]]
    command = " ".join(["detcal calibrate", *(shlex.quote(w) for w in words)])
    # the logs decide which calibration (and so which config schema) applies
    if all(lg.scans is None and lg.detections is not None for lg in loaded):
        from calib.detlevel import DetectionCalibConfig, calibrate_detections, write_detection_run

        dcfg = load_yaml_model(DetectionCalibConfig, config)
        refs = [r for lg in loaded for r in _source_refs(lg)] or refs
        cal = calibrate_detections(loaded, dcfg, name=prof_name, version=version, description=description, input_refs=refs, command=command)
        figures = write_detection_run(cal, target, overwrite=force)
    else:
        cfg = load_yaml_model(CalibrateConfig, config)
        if poses is not None:
            cfg = cfg.model_copy(update={"poses": poses})
        cal = calibrate(
            loaded, cfg, name=prof_name, version=version, description=description, landmarks_csv=landmarks, input_refs=refs, command=command
        )
        figures = write_calibration_run(cal, target, overwrite=force)
    saved, status = save_profile(cal.profile, profiles_dir, force=force)
    p = cal.profile
    rows = {
        "profile": f"{p.ref} ({status}: {saved})",
        "run folder": f"{target} ({len(figures)} figures)",
        **{k: v for k, v in cal.summary.items() if k not in ("logs",)},
        "P_D table": ", ".join(f"{int(e) if float(e).is_integer() else e}:{v:.2f}" for e, v in zip(p.pd.edges[:-1], p.pd.pd, strict=True)),
    }
    out.print(_summary_table(f"calibration of {', '.join(cal.summary['logs'])}", rows))


@app.command("validate")
def validate_cmd(
    profile_ref: Annotated[str, typer.Argument(metavar="PROFILE", help="name or name@version, or a profile file.")],
    log_path: Annotated[Path, typer.Argument(metavar="LOG", help="A held-out log with truth.")],
    landmarks: Annotated[Path | None, typer.Option(help="Landmark truth: a CSV (id, x, y, radius) or `cloud`.")] = None,
    poses: Annotated[str, typer.Option(help="Scan poses from: auto, reference, icp.")] = "auto",
    out_dir: Annotated[Path | None, typer.Option("--out", help="Run folder (default: runs/validate_<profile>_<log>).")] = None,
    force: Annotated[bool, typer.Option(help="Replace the run folder if it exists.")] = False,
    robot: Annotated[list[int] | None, typer.Option(help="UTIAS: robots to read from a dataset folder (repeat the option).")] = None,
    fmt: FormatOpt = None,
    max_backstep: BackstepOpt = 1.0,
    laser: LaserOpt = "front",
    range_max: RangeMaxOpt = None,
    scan_topic: ScanTopicOpt = None,
    truth_topic: TruthTopicOpt = None,
) -> None:
    """Check a profile on a held-out log: P_D reliability (ECE), false alarms per scan, Hotelling coverage."""
    from calib.validate import validate, write_validation_run
    from profiles.store import resolve

    _check_poses(poses)
    prof = resolve(profile_ref)
    loaded, _ = _read_many([log_path], robot, fmt, max_backstep, laser, range_max, scan_topic, truth_topic)
    log = loaded[0]
    target = out_dir or Path("runs") / f"validate_{prof.ref}_{log.name}"
    _fresh(target, force)
    if prof.detector.kind == "external":
        from calib.detlevel import validate_detections

        v = validate_detections(prof, loaded)
    else:
        if len(loaded) > 1:
            raise UsageError("validate one laser log at a time")
        v = validate(prof, log, landmarks_csv=landmarks, poses=poses)
    write_validation_run(v, target, overwrite=force)
    out.print(_summary_table(f"validation of {prof.ref} on {log.name} -> {target}", v.summary))


@app.command("icp")
def icp_cmd(
    log_path: Annotated[Path, typer.Argument(metavar="LOG", help="A log with laser scans and odometry.")],
    out_dir: Annotated[Path | None, typer.Option("--out", help="Run folder (default: runs/icp_<log name>).")] = None,
    relations: Annotated[Path | None, typer.Option(help="Benchmark relations (t1 t2 x y z roll pitch yaw) to score the poses against.")] = None,
    force: Annotated[bool, typer.Option(help="Replace the run folder if it exists.")] = False,
    fmt: FormatOpt = None,
    max_backstep: BackstepOpt = 1.0,
    laser: LaserOpt = "front",
    range_max: RangeMaxOpt = None,
    scan_topic: ScanTopicOpt = None,
) -> None:
    """Ground truth from the scans: sequential point-to-line ICP, loop closures, pose graph."""
    from calib.groundtruth import write_icp_run

    log = _read(log_path, fmt, max_backstep, laser, range_max, 1, scan_topic, None, None)
    target = out_dir or Path("runs") / f"icp_{log.name}"
    _fresh(target, force)
    summary = write_icp_run(log, target, relations=relations, overwrite=force)
    out.print(_summary_table(f"ICP ground truth of {log.name} -> {target}", summary))


FILTERS = ("rbphd",)
PD_MODES = ("profile", "constant")


def _slam_config(config: Path | None, filter_: str, particles: int | None, pd_mode: str | None):
    from calib.config import load_yaml_model
    from slam_runtime.config import SlamConfig

    if filter_ not in FILTERS:
        raise UsageError(f"--filter: expected one of {', '.join(FILTERS)}, got {filter_!r} (delta-GLMB-SLAM is not available yet)")
    if particles is not None and particles < 1:
        raise UsageError(f"--particles: expected a positive integer, got {particles}")
    if pd_mode is not None and pd_mode not in PD_MODES:
        raise UsageError(f"--pd-mode: expected one of {', '.join(PD_MODES)}, got {pd_mode!r}")
    cfg = load_yaml_model(SlamConfig, config)
    upd = {k: v for k, v in (("particles", particles), ("pd_mode", pd_mode)) if v is not None}
    return cfg.model_copy(update={"rbphd": cfg.rbphd.model_copy(update=upd)}) if upd else cfg


@slam_app.command("run")
def slam_run_cmd(
    log_path: Annotated[Path, typer.Argument(metavar="LOG", help="A log with odometry and scans (or detections).")],
    profile_ref: Annotated[str, typer.Option("--profile", help="Detector profile: name or name@version, or a file.")],
    filter_: Annotated[str, typer.Option("--filter", help="Filter: rbphd.")] = "rbphd",
    particles: Annotated[int | None, typer.Option(help="Particles (default: the config's, 20).")] = None,
    seed: Annotated[int, typer.Option(help="Random seed; same log, profile, settings and seed give the same run.")] = 0,
    pd_mode: Annotated[str | None, typer.Option(help="P_D from the profile, or `constant` inside the sensor range (for comparison).")] = None,
    config: Annotated[Path | None, typer.Option(help="YAML settings (filter, motion noise, metric); unknown keys are refused.")] = None,
    frames: Annotated[int | None, typer.Option(help="Only the first N frames.")] = None,
    out_dir: Annotated[Path | None, typer.Option("--out", help="Run folder (default: runs/slam_<log>_<profile>_<seed>).")] = None,
    force: Annotated[bool, typer.Option(help="Replace the run folder if it exists.")] = False,
    robot: RobotOpt = 1,
    fmt: FormatOpt = None,
    max_backstep: BackstepOpt = 1.0,
    laser: LaserOpt = "front",
    range_max: RangeMaxOpt = None,
    scan_topic: ScanTopicOpt = None,
    odom_topic: OdomTopicOpt = None,
    truth_topic: TruthTopicOpt = None,
) -> None:
    """RB-PHD-SLAM over a log with a detector profile's P_D and clutter: trajectory, map, metrics, figures."""
    from calib.progress import progress
    from profiles.store import resolve
    from slam_runtime.report import write_slam_run
    from slam_runtime.run import check_inputs, run_slam

    cfg = _slam_config(config, filter_, particles, pd_mode)
    if frames is not None and frames < 1:
        raise UsageError(f"--frames: expected a positive integer, got {frames}")
    prof = resolve(profile_ref)
    log = _read(log_path, fmt, max_backstep, laser, range_max, robot, scan_topic, odom_topic, truth_topic)
    check_inputs(log, prof)
    target = out_dir or Path("runs") / f"slam_{log.name}_{prof.ref}_{seed}"
    _fresh(target, force)
    res = run_slam(log, prof, cfg, seed, progress=progress, max_frames=frames)
    settings = {
        "log": log_path.name,
        "inputs": [r.model_dump() for r in _input_refs(log_path, log)],
        "profile": prof.ref,
        "seed": seed,
        "frames": frames,
        "settings": cfg.model_dump(mode="json"),
    }
    write_slam_run(log, res, target, settings, overwrite=force)
    out.print(_summary_table(f"RB-PHD-SLAM on {log.name} with {prof.ref} -> {target}", res.metrics))


def _input_refs(path: Path, log) -> list:
    """The log's input files with their sha256 (a folder's files as its reader hashed them)."""
    from calib.io.common import file_digest
    from profiles.profile import InputRef

    return _source_refs(log) or ([InputRef(name=path.name, sha256=file_digest(path))] if path.is_file() else [])


def _seed_list(text: str) -> list[int]:
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
    if not seeds or min(seeds) < 0:
        raise UsageError(f"--seeds: expected non-negative seeds, got {text!r}")
    return seeds


@slam_app.command("sweep")
def slam_sweep_cmd(
    logs: Annotated[list[Path], typer.Argument(metavar="LOG...", help="Logs to run on (e.g. simulated parks of different seeds).")],
    profile_refs: Annotated[list[str], typer.Option("--profile", help="Detector profile(s): name or name@version, or a file (repeat the option).")],
    pd_modes: Annotated[list[str] | None, typer.Option("--pd-mode", help="profile and/or constant (repeat; default: both).")] = None,
    particles: Annotated[list[int] | None, typer.Option("--particles", help="Particle counts (repeat; default: the config's).")] = None,
    seeds: Annotated[str, typer.Option(help="Filter seeds: a count (3), a list (1,3,7) or a range (1-5).")] = "1",
    config: Annotated[Path | None, typer.Option(help="YAML settings shared by every run.")] = None,
    frames: Annotated[int | None, typer.Option(help="Only the first N frames of each log.")] = None,
    jobs: Annotated[int | None, typer.Option(help="Parallel processes (default: the CPU count).")] = None,
    out_dir: Annotated[Path, typer.Option("--out", help="Sweep folder: one run folder per run, runs.csv and summary.csv.")] = Path("runs/sweep"),
    force: Annotated[bool, typer.Option(help="Replace the sweep folder if it exists.")] = False,
    robot: RobotOpt = 1,
    fmt: FormatOpt = None,
    max_backstep: BackstepOpt = 1.0,
) -> None:
    """Monte Carlo sweep: every log x profile x P_D mode x particle count x seed, in parallel processes."""
    import pandas as pd

    from calib.io.atomic import atomic_output
    from profiles.store import resolve
    from slam_runtime.run import check_inputs
    from slam_runtime.sweep import SweepJob, run_sweep, summarise

    modes = list(dict.fromkeys(pd_modes or list(PD_MODES)))
    for m in modes:
        if m not in PD_MODES:
            raise UsageError(f"--pd-mode: expected one of {', '.join(PD_MODES)}, got {m!r}")
    base = _slam_config(config, "rbphd", None, None)
    counts = list(dict.fromkeys(particles or [base.rbphd.particles]))
    if min(counts) < 1:
        raise UsageError(f"--particles: expected positive integers, got {counts}")
    if frames is not None and frames < 1:
        raise UsageError(f"--frames: expected a positive integer, got {frames}")
    if jobs is not None and jobs < 1:
        raise UsageError(f"--jobs: expected a positive integer, got {jobs}")
    seed_list = _seed_list(seeds)
    profs = [resolve(r) for r in dict.fromkeys(profile_refs)]
    loaded = []
    for p in logs:
        log = _read(p, fmt, max_backstep, "front", None, robot, None, None, None)
        for prof in profs:
            check_inputs(log, prof)
        loaded.append((p, log))
    _fresh(out_dir, force)
    job_list = []
    for i, (p, log) in enumerate(loaded):
        for prof in profs:
            for m in modes:
                for n in counts:
                    cfg = base.model_copy(update={"rbphd": base.rbphd.model_copy(update={"particles": n, "pd_mode": m})})
                    for sd in seed_list:
                        name = f"{i:02d}_{log.name}_{prof.ref}_{m}_p{n}_s{sd}"
                        labels = {"log": log.name, "profile": prof.ref, "pd_mode": m, "particles": n, "seed": sd}
                        job_list.append(SweepJob(name, log, prof, cfg, sd, labels, frames))
    by = ("profile", "pd_mode", "particles")
    with atomic_output(out_dir, overwrite=force, directory=True) as tmp:
        tmp.mkdir()
        rows = run_sweep(job_list, tmp, jobs)
        label_keys = ("log", "profile", "pd_mode", "particles", "seed")
        pd.DataFrame(rows).to_csv(tmp / "runs.csv", index=False, float_format="%.6g")
        summary = summarise(rows, by, label_keys)
        pd.DataFrame(summary).to_csv(tmp / "summary.csv", index=False, float_format="%.6g")
        (tmp / "config.yaml").write_text(_yaml_dump({"settings": base.model_dump(mode="json"), "logs": [p.name for p, _ in loaded], "seeds": seed_list}))
    # one column per setting, one row per metric (mean +- standard deviation over its runs)
    t = Table(title=f"sweep of {len(job_list)} runs -> {out_dir}")
    t.add_column("metric")
    for e in summary:
        t.add_column(f"{e['profile']}\n{e['pd_mode']}, {e['particles']} particles\n{e['runs']} runs", justify="right")
    shown = [
        ("trajectory RMSE [m]", "trajectory_rmse_vs_ground_truth_m"),
        ("dead reckoning RMSE [m]", "odometry_rmse_vs_ground_truth_m"),
        ("trajectory RMSE vs GPS [m]", "trajectory_rmse_vs_gps_m"),
        ("dead reckoning vs GPS [m]", "odometry_rmse_vs_gps_m"),
        ("map OSPA", "map_ospa"),
        ("map features", "map_features"),
        ("ms per step", "ms_per_step_mean"),
    ]
    for label, key in shown:
        if f"{key}_mean" in summary[0]:
            t.add_row(label, *(f"{e[key + '_mean']:.3f} ± {e[key + '_std']:.3f}" for e in summary))
    out.print(t)


def _yaml_dump(data) -> str:
    from calib.config import dump_yaml

    return dump_yaml(data)


@profile_app.command("list")
def profile_list() -> None:
    """List the bundled and user profiles (name@version, origin, file)."""
    from profiles.store import registry, user_dirs

    t = Table(title="detector profiles (user folders: " + ", ".join(str(d) for d in user_dirs()) + ")")
    for col in ("profile", "origin", "file"):
        t.add_column(col)
    for e in registry():
        t.add_row(f"{e.name}@{e.version}", e.origin, str(e.path))
    out.print(t)


@profile_app.command("show")
def profile_show(ref: Annotated[str, typer.Argument(metavar="PROFILE", help="name or name@version, or a file.")]) -> None:
    """Print a profile as YAML."""
    from profiles.store import dump_profile, resolve

    sys.stdout.write(dump_profile(resolve(ref)))


@profile_app.command("validate")
def profile_validate(path: Annotated[Path, typer.Argument(metavar="FILE", help="A profile file (YAML or JSON).")]) -> None:
    """Check a profile file against the schema; errors name the field path."""
    from profiles.store import load_profile_file

    p = load_profile_file(path)
    out.print(f"{path}: valid profile {p.ref} (schema {p.schema_version})")


@profile_app.command("diff")
def profile_diff(
    a: Annotated[str, typer.Argument(metavar="A", help="name or name@version, or a file.")],
    b: Annotated[str, typer.Argument(metavar="B", help="name or name@version, or a file.")],
) -> None:
    """Show the fields in which two profiles differ."""
    from profiles.store import diff_profiles, resolve

    pa, pb = resolve(a), resolve(b)
    rows = diff_profiles(pa, pb)
    if not rows:
        out.print(f"{pa.ref} and {pb.ref} are identical")
        return
    t = Table(title=f"{pa.ref} -> {pb.ref}: {len(rows)} fields differ")
    for col in ("field", pa.ref, pb.ref):
        t.add_column(col, overflow="fold")
    for k, va, vb in rows:
        t.add_row(k, _short(va), _short(vb))
    out.print(t)


def _short(v) -> str:
    if isinstance(v, float):
        return f"{v:.6g}"
    if isinstance(v, list):
        return "[" + ", ".join(_short(x) for x in v[:8]) + (", ..." if len(v) > 8 else "") + "]"
    return "-" if v is None else str(v)


@profile_app.command("export")
def profile_export(
    ref: Annotated[str, typer.Argument(metavar="PROFILE", help="name or name@version, or a file.")],
    export_fmt: Annotated[str, typer.Option("--format", help="yaml or json.")] = "yaml",
    dest: Annotated[Path | None, typer.Option("--out", help="Write here instead of standard output (never replaced without --force).")] = None,
    force: Annotated[bool, typer.Option(help="Replace --out if it exists.")] = False,
) -> None:
    """Export a profile as YAML or JSON."""
    from profiles.atomic import atomic_output
    from profiles.store import dump_profile, resolve

    text = dump_profile(resolve(ref), export_fmt)
    if dest is None:
        sys.stdout.write(text)
        return
    with atomic_output(dest, overwrite=force) as tmp:
        tmp.write_text(text)
    out.print(f"wrote {dest}")


@profile_app.command("schema")
def profile_schema() -> None:
    """Print the JSON Schema of a detector profile."""
    import json

    from profiles.profile import DetectorProfile

    sys.stdout.write(json.dumps(DetectorProfile.model_json_schema(), indent=2) + "\n")


def main(argv: list[str] | None = None) -> int:
    """Entry point: run the app, map DetcalError to a one-line message and its exit code.

    Usage errors found by the option parser are reported by typer itself (exit 2).
    """
    try:
        app(args=argv, prog_name="detcal")
    except SystemExit as exc:
        code = exc.code
        return code if isinstance(code, int) else (0 if code is None else 1)
    except DetcalError as exc:
        err.print(f"detcal: error: {exc}", soft_wrap=True)
        return exc.exit_code
    except KeyboardInterrupt:
        err.print("detcal: interrupted")
        return 130
    return 0


if __name__ == "__main__":
    sys.exit(main())


def run() -> None:
    """Console-script entry point."""
    sys.exit(main())
