"""``detcal calibrate`` as one pipeline: logs in, a profile and its run folder out, written as one step.

1. The logs decide which calibration applies (laser scans: the circle
   detector and n_p; detection-level logs: P_D against range; point clouds
   with plane truth: the plane detector, :mod:`calib.planes`) and so which
   config schema the ``--config`` file must follow.
2. Scans and detection frames outside the ground truth's time span are
   dropped, and counted (:mod:`calib.truth`).
3. The request -- name@version, description, the inputs with their sha256
   and every parameter, including what the data decide (pose source, where
   the landmarks and sigma_r come from) -- is known before any work and is
   checked against the profile store and the run folder: an existing
   name@version made from another request is refused at once (unless
   ``force``), a bundled one is never shadowed, and an identical request is
   no conflict (the creation time and the command line are not content).
4. The calibration runs.
5. The run folder and the profile are prepared completely, then moved into
   place one after the other (:func:`profiles.atomic.atomic_outputs`): a
   profile in the store always has its run folder; a kill leaves only hidden
   ``.part`` entries, which a rerun removes.
"""

from __future__ import annotations

import contextlib
import dataclasses
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path

from profiles.version import __version__
from calib.config import load_yaml_model
from detectors.logs import SensorLog
from profiles.atomic import Output, atomic_outputs, check_replaceable
from profiles.errors import UsageError
from profiles.profile import NAME_RE, SEMVER_RE, InputRef
from profiles.store import Request, check_save, final_status, load_profile_file, same_content, same_request, write_profile_text


@dataclass
class CalibrationJob:
    """Everything ``detcal calibrate`` was asked: logs already read, and where they came from."""

    logs: list[SensorLog]
    inputs: list[InputRef]  # the input files (logs, a landmark CSV) with their sha256
    name: str
    version: str
    out: Path | None = None  # run folder (default runs/calibrate_<name>@<version>)
    profiles_dir: Path | None = None
    description: str = ""
    config: Path | None = None
    landmarks: Path | None = None  # a CSV or "cloud"
    poses: str | None = None
    force: bool = False
    command: str = ""
    range_sigma_given: bool = False
    per_sensor: bool = False  # detection-level logs of several sensors: one profile per sensor too
    # where each log came from, (path, format, reader options), so a worker can read it where it lives
    sources: list[tuple] | None = None
    workers: int | None = None  # --workers: Dask worker processes for the per-log work (0: this process)
    scheduler: str | None = None  # --scheduler: an existing Dask cluster


@dataclass
class CalibrationOutcome:
    profile: object  # DetectorProfile
    summary: dict
    profile_path: Path
    profile_status: str  # written | replaced | unchanged | unchanged (bundled)
    run_folder: Path
    run_status: str  # written | replaced | unchanged
    figures: list[str]
    notes: list[str] = field(default_factory=list)  # what the user should know (records dropped, ...)
    members: list[tuple[Path, str]] = field(default_factory=list)  # per-sensor profiles: (path, status)
    engine: str = "in this process"  # where the per-log work ran


def check_name(name: str | None, version: str) -> None:
    """The profile's name (when given) and version, as ``--name`` and ``--version`` must be."""
    if name is not None and not NAME_RE.match(name):
        raise UsageError(f"--name: {name!r} must match [a-z0-9][a-z0-9._-]*")
    if not SEMVER_RE.match(version):
        raise UsageError(f"--version: {version!r} is not MAJOR.MINOR.PATCH")


def detection_level(logs: list[SensorLog]) -> bool:
    """True when every log carries detections and no scans (UTIAS): P_D against range."""
    return all(lg.scans is None and lg.detections is not None for lg in logs)


def plane_logs(logs: list[SensorLog]) -> bool:
    """True when every log carries point clouds and neither scans nor detections: planes in 3D."""
    return all(lg.clouds is not None and lg.scans is None and lg.detections is None for lg in logs)


def _seed(logs: list[SensorLog]) -> int | None:
    seeds = {lg.source.get("seed") for lg in logs if lg.source.get("seed") is not None}
    return seeds.pop() if len(seeds) == 1 else None


def run_calibration(job: CalibrationJob) -> CalibrationOutcome:
    """Steps 1-5 of the module docstring."""
    from calib.truth import trim_to_truth

    check_name(job.name, job.version)
    run_dir = job.out or Path("runs") / f"calibrate_{job.name}@{job.version}"
    notes = []
    logs = []
    for lg in job.logs:
        lg, dropped = trim_to_truth(lg)
        notes += [f"log {lg.name!r}: {n} {what} outside the ground truth's time span dropped" for what, n in dropped.items()]
        logs.append(lg)
    planes = plane_logs(logs)
    levels = not planes and detection_level(logs)
    derived: tuple[str, ...] = ()
    members: list[str] = []
    if planes:
        from calib.planes import PlaneCalibConfig

        cfg = load_yaml_model(PlaneCalibConfig, job.config)
        if job.landmarks is not None:
            raise UsageError("--landmarks: lidar logs carry their plane truth")
        if job.per_sensor:
            raise UsageError("--per-sensor applies to detection-level logs (lidar logs are pooled)")
        params = cfg.model_dump(mode="json")
        seed = _seed(logs)
    elif levels:
        from calib.detlevel import DetectionCalibConfig, sensor_names

        cfg = load_yaml_model(DetectionCalibConfig, job.config)
        if job.landmarks is not None:
            raise UsageError("--landmarks: detection-level logs carry their landmark truth")
        # the frame period and the identity audit follow from the inputs and the config: not part of the request
        derived = ("frame_period", "identity_remap")
        params = {k: v for k, v in cfg.model_dump(mode="json").items() if k not in derived}
        seed = None
        if job.per_sensor:
            if len(logs) < 2:
                raise UsageError("--per-sensor needs logs of at least two sensors (e.g. --robot 1 --robot 2)")
            members = [f"{job.name}-{n}" for n in sensor_names(logs)]
    else:
        from calib.calibrate import CalibrateConfig, parameters

        if job.per_sensor:
            raise UsageError("--per-sensor applies to detection-level logs (laser logs are pooled)")
        cfg = load_yaml_model(CalibrateConfig, job.config)
        if job.poses is not None:
            cfg = CalibrateConfig.model_validate({**cfg.model_dump(), "poses": job.poses})
        params = parameters(logs, cfg, job.landmarks, job.range_sigma_given)
        seed = _seed(logs)
    request = Request(job.name, job.version, job.description, list(job.inputs), params, __version__, seed, derived)
    for ref in [job.name, *members]:  # every profile this calibration will write, before any work
        check_save(dataclasses.replace(request, name=ref), job.profiles_dir, force=job.force)
    run_plan = _check_run_folder(run_dir, request, job.force)
    # ---- the work
    where = "in this process"
    if planes:
        from calib.planes import calibrate_planes
        from detcal.reports.plane_calibration import fill_plane_run

        cal = calibrate_planes(
            logs, cfg, name=job.name, version=job.version, description=job.description, input_refs=list(job.inputs), command=job.command
        )
        fill = fill_plane_run
    elif levels:
        from calib.detlevel import calibrate_detections
        from detcal.reports.detection_calibration import fill_detection_run

        if job.workers or job.scheduler:
            notes.append("detection-level logs are calibrated in this process (their per-log work takes milliseconds); --workers and --scheduler are not used")
        cal = calibrate_detections(
            logs, cfg, name=job.name, version=job.version, description=job.description, input_refs=list(job.inputs),
            command=job.command, per_sensor=job.per_sensor,
        )  # fmt: skip
        fill = fill_detection_run
    else:
        from calib.calibrate import calibrate
        from detcal.reports.calibration import fill_calibration_run

        with _per_log_engine(job, logs) as (per_log, where):
            cal = calibrate(
                logs,
                cfg,
                name=job.name,
                version=job.version,
                description=job.description,
                landmarks_csv=job.landmarks,
                input_refs=list(job.inputs),
                command=job.command,
                range_sigma_given=job.range_sigma_given,
                per_log=per_log,
            )
        fill = fill_calibration_run
    profile = cal.profile
    if Request.of(profile, derived) != request:  # the request said what the work would record
        raise RuntimeError(f"calibration recorded other parameters than planned ({profile.provenance.parameters} != {params})")
    path, status = final_status(profile, job.profiles_dir, job.force, derived)
    written = [(m, *final_status(m, job.profiles_dir, job.force, derived)) for m in getattr(cal, "members", [])]
    run_status = run_plan
    if run_plan == "unchanged" and not same_content(load_profile_file(run_dir / "profile.yaml"), profile):
        raise UsageError(f"{run_dir}: holds a calibration of {profile.ref} with other content; use --force or another --out")
    from profiles.store import looks_like_profile

    outputs, writers = [], []
    if run_status != "unchanged":
        outputs.append(Output(run_dir, directory=True, overwrite=job.force))
        writers.append(lambda tmp: fill(cal, tmp))
    for prof, p_path, p_status in [(profile, path, status), *written]:  # the profiles last: one in the store has its run folder
        if p_status in ("written", "replaced"):
            outputs.append(Output(p_path, overwrite=job.force, owned=looks_like_profile))
            writers.append(lambda tmp, prof=prof: write_profile_text(prof, tmp))
    figures: list[str] = []
    if outputs:
        with atomic_outputs(outputs) as tmps:
            for w, tmp in zip(writers, tmps, strict=True):
                got = w(tmp)
                if isinstance(got, list):
                    figures = got
    return CalibrationOutcome(profile, cal.summary, path, status, run_dir, run_status, figures, notes, [(p, st) for _, p, st in written], where)


@contextlib.contextmanager
def _per_log_engine(job: CalibrationJob, logs: list[SensorLog]) -> Iterator[tuple[object, str]]:
    """(``per_log`` for :func:`calib.calibrate.calibrate`, where it runs): Dask workers for several laser logs
    (or whenever ``--scheduler`` names a cluster), each reading its log where it lives; else None (this process)."""
    distribute = job.sources is not None and (job.scheduler is not None or (job.workers != 0 and len(logs) > 1))
    if not distribute:
        yield None, "in this process"
        return
    from detcal.engine import LogSource, open_engine
    from calib.progress import progress

    handles = [LogSource.of(lg, p, fmt, opts, trim=True) for lg, (p, fmt, opts) in zip(logs, job.sources, strict=True)]
    with open_engine(job.workers, job.scheduler, len(logs)) as engine:
        yield engine.per_log(handles, [lg.name for lg in logs], progress), engine.label


def _check_run_folder(run_dir: Path, request: Request, force: bool) -> str:
    """``written``, ``replaced`` or ``unchanged`` (the folder holds a calibration of the same request); refuses others."""
    import os

    if not os.path.lexists(run_dir):
        return "written"
    if force:
        check_replaceable(run_dir, overwrite=True, directory=True)
        return "replaced"
    old = run_dir / "profile.yaml"
    try:
        same = run_dir.is_dir() and old.is_file() and same_request(Request.of(load_profile_file(old)), request)
    except Exception:  # noqa: BLE001  (an unreadable old profile: not the same request)
        same = False
    if not same:
        raise UsageError(f"{run_dir}: already exists (use --force to replace it)")
    check_replaceable(run_dir, overwrite=True, directory=True)  # it must be a run folder detcal wrote
    return "unchanged"


def run_validation(profile, logs: list[SensorLog], *, landmarks: Path | None, poses: str, out: Path, force: bool):
    """``detcal validate``: score ``profile`` on held-out logs and write the run folder; returns (validation, notes)."""
    from calib.truth import trim_to_truth
    from calib.validate import validate, write_validation_run

    check_replaceable(out, overwrite=force, directory=True)
    notes, kept = [], []
    for lg in logs:
        lg, dropped = trim_to_truth(lg)
        notes += [f"log {lg.name!r}: {n} {what} outside the ground truth's time span dropped" for what, n in dropped.items()]
        kept.append(lg)
    if profile.detector.kind == "plane3d":
        from calib.planes import validate_planes

        if len(kept) > 1:
            raise UsageError("validate one lidar log at a time")
        v = validate_planes(profile, kept[0])
    elif profile.detector.kind == "external":
        from calib.detlevel import validate_detections

        v = validate_detections(profile, kept)
    else:
        v = validate(profile, kept, landmarks_csv=landmarks, poses=poses)
    write_validation_run(v, out, overwrite=force)
    return v, notes
