"""``detcal calibrate`` as one pipeline: logs in, a profile and its run folder out, written as one step.

1. The logs decide which calibration applies (:data:`METHODS`, one per
   detector kind: point clouds with plane truth, the plane detector
   (:mod:`calib.planes`); detection-level logs, P_D against range
   (:mod:`calib.detlevel`); laser scans, the circle detector and n_p
   (:mod:`calib.calibrate`)) and so which config schema the ``--config`` file
   must follow; a profile is validated by the method of its detector kind.
2. Scans and detection frames outside the ground truth's time span are
   dropped, and counted (:mod:`calib.truth`).
3. The request -- name@version, description, the inputs with their sha256
   and every parameter, including what the data decide (pose source, where
   the landmarks and sigma_r come from) -- is known before any work and is
   checked against the profile store and the run folder: an existing
   name@version made from another request is refused at once (unless
   ``force``), a bundled one is never shadowed, and an identical request is
   no conflict (the creation time and the command line are not content).
4. The calibration runs. Laser logs pass a gate (:func:`calib.calibrate.calibrate`'s
   ``quality_gate``): a ground truth failing its quality checks, or data too
   thin for the fits, stops it with the log, the failed figure and its
   threshold, before anything is written; ``accept_poor_ground_truth`` lets
   them through and the profile records that it did.
5. The run folder and the profile are prepared completely, then moved into
   place one after the other (:func:`profiles.atomic.atomic_outputs`): a
   profile in the store always has its run folder; a kill leaves only hidden
   ``.part`` entries, which a rerun removes.
"""

from __future__ import annotations

import contextlib
import dataclasses
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path

from calib.config import load_yaml_model
from detectors.sensor_log import SensorLog
from profiles.atomic import Output, atomic_outputs, check_replaceable
from profiles.errors import UsageError
from profiles.profile import NAME_RE, SEMVER_RE, InputRef
from profiles.registry import Registry
from profiles.store import Request, check_save, final_status, load_profile_file, looks_like_profile, same_content, same_request, write_profile_text
from profiles.version import __version__


@dataclass(kw_only=True)
class ProfileTarget:
    """The profile a calibration writes and its run folder."""

    name: str
    version: str
    description: str = ""
    profiles_dir: Path | None = None  # where the profile is saved (None: the user profile folder)
    out: Path | None = None  # run folder (default runs/calibrate_<name>@<version>)
    force: bool = False  # replace an existing run folder and profile version


@dataclass(kw_only=True)
class CalibrationJob:
    """Everything ``detcal calibrate`` was asked: the logs already read and where they came from, the profile to
    write, the settings, and where the per-log work runs."""

    logs: list[SensorLog]
    inputs: list[InputRef]  # the input files (logs, a landmark CSV) with their sha256
    target: ProfileTarget
    config: Path | None = None  # the --config file (None: the method's defaults)
    landmarks: Path | None = None  # a CSV or "cloud"
    poses: str | None = None
    command: str = ""  # the command as typed (recorded in the profile)
    range_sigma_given: bool = False
    # detection-level logs of several sensors: one profile per sensor too (None: yes when there are several sensors)
    per_sensor: bool | None = None
    # where each log came from, (path, format, reader options), so a worker can read it where it lives
    sources: list[tuple] | None = None
    workers: int | None = None  # --workers: Dask worker processes for the per-log work (0: this process)
    scheduler: str | None = None  # --scheduler: an existing Dask cluster
    # --accept-poor-ground-truth: laser logs whose ground truth fails its quality checks, or data too thin for the fits,
    # are calibrated anyway and the profile records it (default: refused, nothing written)
    accept_poor_ground_truth: bool = False


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


def _seed(logs: list[SensorLog]) -> int | None:
    seeds = {lg.source.get("seed") for lg in logs if lg.source.get("seed") is not None}
    return seeds.pop() if len(seeds) == 1 else None


@dataclass
class Plan:
    """What a method's profile will record, known before any work: its parameters, those the data decide
    (``derived``: not part of the request), the per-sensor profiles' names, the simulator seed."""

    params: dict
    derived: tuple[str, ...] = ()
    members: list[str] = field(default_factory=list)
    seed: int | None = None


@dataclass(frozen=True)
class Method:
    """One way of calibrating a detector kind: the logs it takes, its ``--config`` schema, the plan of what its
    profile records (checking the job's options), the calibration itself (-> (calibration, where it ran)), its run
    folder, the validation of its profiles on held-out logs (``validate(profile, logs, *, landmarks, poses, drift,
    per_log)``), the settings of its config the command line's options of the same name set (``options``: fields of
    :class:`CalibrationJob`), and whether its per-log work runs on the engine (``distributed``: else in this process,
    where it takes milliseconds per log)."""

    takes: Callable[[list[SensorLog]], bool]
    config: Callable[[], type]
    plan: Callable[[CalibrationJob, list[SensorLog], object], Plan]
    run: Callable[[CalibrationJob, list[SensorLog], object, list[str]], tuple[object, str]]
    fill: Callable[[object, Path], list[str]]
    validate: Callable[..., object]
    options: tuple[str, ...] = ()
    distributed: bool = False


def _no_gate(job: CalibrationJob, what: str) -> None:
    if job.accept_poor_ground_truth:
        raise UsageError(f"--accept-poor-ground-truth applies to laser logs (a ground truth registered from the scans); {what} carry theirs")


# ---------------------------------------------------------------------------- planes in 3D clouds


def _planes_plan(job: CalibrationJob, logs, cfg) -> Plan:
    if job.landmarks is not None:
        raise UsageError("--landmarks: lidar logs carry their plane truth")
    _no_gate(job, "lidar logs with plane truth")
    if job.per_sensor:
        raise UsageError("--per-sensor applies to detection-level logs (lidar logs are pooled)")
    return Plan(cfg.model_dump(mode="json"), seed=_seed(logs))


def _planes_run(job: CalibrationJob, logs, cfg, notes):
    from calib.planes import calibrate_planes

    t = job.target
    return calibrate_planes(logs, cfg, name=t.name, version=t.version, description=t.description, input_refs=list(job.inputs), command=job.command), "in this process"


def _planes_validate(profile, logs, *, landmarks, poses, drift, per_log):
    from calib.planes import validate_planes

    if len(logs) > 1:
        raise UsageError("validate one lidar log at a time")
    return validate_planes(profile, logs[0], drift=drift)


def _fill_planes(cal, folder):
    from detcal.reports.plane_calibration import fill_plane_run

    return fill_plane_run(cal, folder)


# ---------------------------------------------------------------------------- detection-level logs


def _detections_plan(job: CalibrationJob, logs, cfg) -> Plan:
    from calib.detlevel import sensor_names

    if job.landmarks is not None:
        raise UsageError("--landmarks: detection-level logs carry their landmark truth")
    _no_gate(job, "detection-level logs")
    # the frame period and the identity audit follow from the inputs and the config: not part of the request
    derived = ("frame_period", "identity_remap")
    members = []
    if job.per_sensor and len(logs) < 2:
        raise UsageError("--per-sensor needs logs of at least two sensors (e.g. --robot 1 --robot 2)")
    if _per_sensor(job, logs):
        members = [f"{job.target.name}-{n}" for n in sensor_names(logs)]
    return Plan({k: v for k, v in cfg.model_dump(mode="json").items() if k not in derived}, derived, members)


def _per_sensor(job: CalibrationJob, logs) -> bool:
    """Per-sensor profiles beside the pooled one: as asked, else whenever there are several sensors (a fleet's
    sensors are rarely exchangeable: the pooled profile is the fallback, not the default)."""
    return job.per_sensor if job.per_sensor is not None else len(logs) > 1


def _detections_run(job: CalibrationJob, logs, cfg, notes):
    from calib.detlevel import calibrate_detections
    from calib.drift import DriftConfig

    if job.workers or job.scheduler:
        notes.append("detection-level logs are calibrated in this process (their per-log work takes milliseconds); --workers and --scheduler are not used")
    t = job.target
    cal = calibrate_detections(
        logs, cfg, name=t.name, version=t.version, description=t.description, input_refs=list(job.inputs), command=job.command,
        per_sensor=_per_sensor(job, logs), exchange=DriftConfig() if len(logs) > 1 else None,
    )  # fmt: skip
    return cal, "in this process"


def _detections_validate(profile, logs, *, landmarks, poses, drift, per_log):
    from calib.detlevel import validate_detections

    return validate_detections(profile, logs, drift=drift)


def _fill_detections(cal, folder):
    from detcal.reports.detection_calibration import fill_detection_run

    return fill_detection_run(cal, folder)


# ---------------------------------------------------------------------------- laser scans


def _laser_plan(job: CalibrationJob, logs, cfg) -> Plan:
    from calib.calibrate import check_landmark_source, parameters

    if job.per_sensor:
        raise UsageError("--per-sensor applies to detection-level logs (laser logs are pooled)")
    check_landmark_source(logs, job.landmarks)  # before any registration: the mistake costs nothing here
    return Plan(parameters(logs, cfg, job.landmarks, job.range_sigma_given, accept_poor=job.accept_poor_ground_truth), seed=_seed(logs))


def _laser_run(job: CalibrationJob, logs, cfg, notes):
    from calib.calibrate import calibrate

    t = job.target
    with per_log_engine(logs, job.sources, job.workers, job.scheduler) as (per_log, where):
        cal = calibrate(
            logs, cfg, name=t.name, version=t.version, description=t.description, landmarks_csv=job.landmarks,
            input_refs=list(job.inputs), command=job.command, range_sigma_given=job.range_sigma_given, per_log=per_log,
            quality_gate="accept" if job.accept_poor_ground_truth else "refuse",
        )  # fmt: skip
    return cal, where


def _laser_validate(profile, logs, *, landmarks, poses, drift, per_log):
    from calib.validate import validate

    return validate(profile, logs, landmarks_csv=landmarks, poses=poses, drift=drift, per_log=per_log)


def _fill_laser(cal, folder):
    from detcal.reports.calibration import fill_calibration_run

    return fill_calibration_run(cal, folder)


def _config(module: str, name: str) -> Callable[[], type]:
    def get() -> type:
        import importlib

        return getattr(importlib.import_module(module), name)

    return get


#: The calibration methods by the detector kind of their profiles, tried in this order on the logs (the laser's last:
#: it takes any log with scans).
METHODS: Registry[Method] = Registry("calibration method")
METHODS.add("plane3d", Method(
    lambda logs: all(lg.clouds is not None and lg.scans is None and lg.detections is None for lg in logs),
    _config("calib.planes", "PlaneCalibConfig"), _planes_plan, _planes_run, _fill_planes, _planes_validate,
))  # fmt: skip
METHODS.add("external", Method(
    lambda logs: all(lg.scans is None and lg.detections is not None for lg in logs),
    _config("profiles.parameters", "DetectionCalibConfig"), _detections_plan, _detections_run, _fill_detections, _detections_validate,
))  # fmt: skip
METHODS.add("circle2d", Method(
    lambda logs: True, _config("profiles.parameters", "CalibrateConfig"), _laser_plan, _laser_run, _fill_laser, _laser_validate, ("poses",), True,
))  # fmt: skip


def trimmed(logs: list[SensorLog]) -> tuple[list[SensorLog], list[str]]:
    """The logs without the records outside their ground truth's time span, and a note per log that lost some."""
    from calib.truth import trim_to_truth

    notes, kept = [], []
    for lg in logs:
        lg, dropped = trim_to_truth(lg)
        notes += [f"log {lg.name!r}: {n} {what} outside the ground truth's time span dropped" for what, n in dropped.items()]
        kept.append(lg)
    return kept, notes


def run_calibration(job: CalibrationJob) -> CalibrationOutcome:
    """Steps 1-5 of the module docstring."""
    t = job.target
    check_name(t.name, t.version)
    run_dir = t.out or Path("runs") / f"calibrate_{t.name}@{t.version}"
    logs, notes = trimmed(job.logs)
    method = next(m for m in METHODS.values() if m.takes(logs))
    cfg = load_yaml_model(method.config(), job.config, {k: getattr(job, k) for k in method.options})
    plan = method.plan(job, logs, cfg)
    request = Request(t.name, t.version, t.description, list(job.inputs), plan.params, __version__, plan.seed, plan.derived)
    for ref in [t.name, *plan.members]:  # every profile this calibration will write, before any work
        check_save(dataclasses.replace(request, name=ref), t.profiles_dir, force=t.force)
    run_plan = _check_run_folder(run_dir, request, t.force)
    cal, where = method.run(job, logs, cfg, notes)  # ---- the work
    profile = cal.profile
    if Request.of(profile, plan.derived) != request:  # the request said what the work would record
        raise RuntimeError(f"calibration recorded other parameters than planned ({profile.provenance.parameters} != {plan.params})")
    path, status = final_status(profile, t.profiles_dir, t.force, plan.derived)
    written = [(m, *final_status(m, t.profiles_dir, t.force, plan.derived)) for m in cal.members] if plan.members else []
    if run_plan == "unchanged" and not same_content(load_profile_file(run_dir / "profile.yaml", notify=False), profile):
        raise UsageError(f"{run_dir}: holds a calibration of {profile.ref} with other content; use --force or another --out")
    outputs, writers = [], []
    if run_plan != "unchanged":
        outputs.append(Output(run_dir, directory=True, overwrite=t.force))
        writers.append(lambda tmp: method.fill(cal, tmp))
    for prof, p_path, p_status in [(profile, path, status), *written]:  # the profiles last: one in the store has its run folder
        if p_status in ("written", "replaced"):
            outputs.append(Output(p_path, overwrite=t.force, owned=looks_like_profile))
            writers.append(lambda tmp, prof=prof: write_profile_text(prof, tmp))
    figures: list[str] = []
    if outputs:
        with atomic_outputs(outputs) as tmps:
            for w, tmp in zip(writers, tmps, strict=True):
                got = w(tmp)
                if isinstance(got, list):
                    figures = got
    return CalibrationOutcome(profile, cal.summary, path, status, run_dir, run_plan, figures, notes, [(p, st) for _, p, st in written], where)


@contextlib.contextmanager
def per_log_engine(logs: list[SensorLog], sources: list[tuple] | None, workers: int | None, scheduler: str | None) -> Iterator[tuple[object, str]]:
    """(``per_log`` for :func:`calib.calibrate.calibrate` and :func:`calib.validate.validate`, where it runs): Dask
    workers for several laser logs (or whenever ``scheduler`` names a cluster), each reading its log where it lives
    (``sources``: (path, format, reader options) per log); else None (this process)."""
    distribute = sources is not None and (scheduler is not None or (workers != 0 and len(logs) > 1))
    if not distribute:
        yield None, "in this process"
        return
    from detcal.engine import LogSource, open_engine
    from calib.progress import progress

    handles = [LogSource.of(lg, p, fmt, opts, trim=True) for lg, (p, fmt, opts) in zip(logs, sources, strict=True)]
    with open_engine(workers, scheduler, len(logs)) as engine:
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
        same = run_dir.is_dir() and old.is_file() and same_request(Request.of(load_profile_file(old, notify=False)), request)
    except Exception:  # noqa: BLE001  (an unreadable old profile: not the same request)
        same = False
    if not same:
        raise UsageError(f"{run_dir}: already exists (use --force to replace it)")
    check_replaceable(run_dir, overwrite=True, directory=True)  # it must be a run folder detcal wrote
    return "unchanged"
