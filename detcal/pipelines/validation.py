"""``detcal validate`` as one pipeline: a profile and held-out logs in, drift verdicts and a run folder out.

1. The profile's detector kind picks the validation (the calibration method
   of that kind, :data:`detcal.pipelines.calibrate.METHODS`); records outside
   each log's ground truth are dropped and counted.
2. Each log is labelled with the profile's detector and tested on its own
   (:mod:`calib.drift`: P_D, clutter, noise, gate coverage, each against the
   distribution its score would have if the profile were right for this log's
   own opportunities); with several logs (robots, days) they are also tested
   together. Laser logs do this per-log work on the engine
   (``--workers``/``--scheduler``, each log read where its task runs), as
   ``detcal calibrate`` does; detection-level logs take milliseconds each and
   are done here.
3. Holm over every test of every row, then the verdicts: each part's, each
   row's (its worst part) and the overall one (the worst row: a pooled row
   never hides a failing sensor).
4. The run folder is written whole or not at all (temp + rename).

The overall verdict maps to the command's exit code (:data:`EXIT_CODES`), so a
script can screen a fleet's logs without reading the report.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from calib.drift import DriftConfig
from detectors.sensor_log import SensorLog
from profiles.atomic import check_replaceable
from profiles.errors import UsageError
from profiles.profile import DetectorProfile

#: exit code of ``detcal validate`` per overall verdict; 1 (bad data) and 2 (usage) stay the errors' codes
EXIT_CODES = {"consistent": 0, "drifted": 3, "too little data": 4}


@dataclass(kw_only=True)
class ValidationJob:
    """Everything ``detcal validate`` was asked: the profile, the logs already read and where they came from, the
    drift settings, the run folder, and where the per-log work runs."""

    profile: DetectorProfile
    logs: list[SensorLog]
    out: Path
    drift: DriftConfig = field(default_factory=DriftConfig)
    landmarks: Path | None = None  # laser logs: a landmark CSV or "cloud"
    poses: str = "auto"
    force: bool = False
    sources: list[tuple] | None = None  # (path, format, reader options) per log, so a worker reads it where it lives
    workers: int | None = None
    scheduler: str | None = None


@dataclass
class ValidationOutcome:
    validation: object  # calib.validate.Validation
    run_folder: Path
    figures: list[str]
    notes: list[str]
    engine: str  # where the per-log work ran

    @property
    def verdict(self) -> str:
        return self.validation.drift.verdict

    @property
    def exit_code(self) -> int:
        return EXIT_CODES[self.verdict]


def run_validation(job: ValidationJob) -> ValidationOutcome:
    """Steps 1-4 of the module docstring."""
    from calib.validate import write_validation_run
    from detcal.pipelines.calibrate import METHODS, per_log_engine, trimmed

    check_replaceable(job.out, overwrite=job.force, directory=True)
    method = METHODS.get(job.profile.detector.kind, None)
    if method is None:
        raise UsageError(f"profile {job.profile.ref}: detcal has no calibration of {job.profile.detector.kind} detectors to validate it with")
    names = [lg.name for lg in job.logs]
    twice = sorted({n for n in names if names.count(n) > 1})
    if twice:  # each log is a row of the report, by its name
        raise UsageError(f"several logs are named {', '.join(map(repr, twice))}: validate logs of distinct names (a row of the report each)")
    kept, notes = trimmed(job.logs)
    if method.distributed:
        with per_log_engine(kept, job.sources, job.workers, job.scheduler) as (per_log, where):
            v = method.validate(job.profile, kept, landmarks=job.landmarks, poses=job.poses, drift=job.drift, per_log=per_log)
    else:
        if job.workers or job.scheduler:
            notes.append(f"{job.profile.kind} logs are validated in this process (their per-log work is light); --workers and --scheduler are not used")
        where = "in this process"
        v = method.validate(job.profile, kept, landmarks=job.landmarks, poses=job.poses, drift=job.drift, per_log=None)
    figures = write_validation_run(v, job.out, overwrite=job.force)
    return ValidationOutcome(v, job.out, figures, notes, where)
