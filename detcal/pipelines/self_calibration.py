"""``detcal selfcal``: run SLAM, measure the detector (and the odometry's biases) against the run's own map and
trajectory, run again with what was measured, until the profile stops changing.

:func:`self_calibration` is the loop; the measuring is injected (``measure``:
:func:`calib.map_calibration.self_calibrate`), so the loop only alternates the two steps
and keeps the history. A vehicle model with biases (``VehicleModel.biases``:
the Ackermann model's steering offset and speed scale) has them measured too
and carried into the next run's settings. :class:`SelfCalibrationRequest` is
the command: checks, the loop, the run folder and the profile written in one
step.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from detcal.pipelines.slam_run import SettingsRequest
from detectors.sensor_log import SensorLog
from profiles.errors import UsageError
from profiles.override import updated
from profiles.profile import NAME_RE, SEMVER_RE
from slam_runtime.config import SlamConfig, with_settings
from slam_runtime.run import SlamResult, build, evaluate, run_slam
from slam_runtime.sources import control_rows, delayed
from slam_runtime.vehicle import VEHICLE_MODELS


@dataclass
class Iteration:
    index: int
    profile: object  # the profile the SLAM run used
    config: SlamConfig  # the settings it used
    result: SlamResult
    measured: object  # the profile measured against this run
    summary: dict  # what the measurement reported
    bias: dict = field(default_factory=dict)  # odometry biases measured against this run
    change: float = float("nan")  # largest change of the measured profile from the one the run used
    next_config: SlamConfig | None = None  # the settings with the measured biases, for the next run


def frame_controls(log: SensorLog) -> list[tuple[np.ndarray, np.ndarray]]:
    """Per frame, its control rows and durations (frame 0: none)."""
    out = []
    for fr in log.frames():
        if fr.index == 0:
            out.append((np.zeros((0, log.odometry.values.shape[1])), np.zeros(0)))
        else:
            out.append(control_rows(log, fr.odometry))
    return out


def self_calibration(
    log: SensorLog,
    profile,
    cfg: SlamConfig,
    seed: int,
    measure: Callable,
    change: Callable,
    *,
    iterations: int = 5,
    tolerance: float = 0.02,
    biases: bool = True,
    average_from: int | None = None,
    progress=None,
) -> list[Iteration]:
    """Alternate SLAM and measurement.

    measure(log, trajectory (T, 3), map_xy (K, 2), map_w (K,), prior profile, iteration) -> (profile, summary),
    given the best particle's trajectory and its whole map with the weights;
    change(new profile, old profile) -> float. Stops after ``iterations`` runs, or
    when the measured profile changes by less than ``tolerance`` (and the vehicle model's biases by less than their
    ``settled`` amounts). The last iteration's measured profile is the result.

    ``average_from`` K (Polyak-Ruppert averaging): from iteration K on, the next run's
    odometry biases are the mean of those measured in iterations K..k (``Iteration.bias``
    keeps each run's own), as ``measure`` is expected to average its profiles from K on;
    each run's map is a random draw, so the plain iteration scatters about its fixed
    point by the run-to-run spread and only the average settles.
    """
    if average_from is not None and average_from < 0:
        raise ValueError(f"average_from must be a non-negative iteration, got {average_from}")
    history: list[Iteration] = []
    model = build(log, profile, cfg).vehicle
    group = next(n for n, c in VEHICLE_MODELS.items() if isinstance(model, c))
    controls = frame_controls(delayed(log, model.delay)) if biases and model.biases else None
    for k in range(iterations):
        res = run_slam(log, profile, cfg, seed, progress=progress)
        res.metrics = evaluate(log, res, cfg.metric.ospa_c, cfg.metric.ospa_p, cfg)
        vehicle = build(log, profile, cfg).vehicle
        traj = vehicle.pose(np.asarray(res.trajectory))
        measured, summary = measure(log, traj, res.map_all_xy, res.map_all_w, profile, k)
        it = Iteration(k, profile, cfg, res, measured, summary, change=change(measured, profile))
        new_cfg = cfg
        settled = True
        if controls is not None:
            it.bias = vehicle.fit_biases(controls, traj)
            # measured from the raw odometry: absolute values, not corrections of the last ones
            first = k if average_from is None else min(average_from, k)  # the runs whose biases are averaged: first..k
            runs = [h.bias for h in history[first:]] + [it.bias]
            new_cfg = with_settings(cfg, {f"motion.{group}.{b}": float(np.mean([r[b] for r in runs])) for b in vehicle.biases})
            old, new = getattr(cfg.motion, group), getattr(new_cfg.motion, group)
            settled = all(abs(getattr(new, b) - getattr(old, b)) < tol for b, tol in vehicle.settled.items())
        it.next_config = new_cfg
        history.append(it)
        steady = it.change < tolerance and settled
        profile, cfg = measured, new_cfg
        if steady:
            break
    return history


@dataclass(kw_only=True)
class SelfCalibrationRequest:
    """``detcal selfcal``: a detection-level log, the starting profile, the SLAM settings and the loop's options,
    the profile to write (name, version, folder) and the run folder."""

    log_path: Path
    read: Callable[[Path], SensorLog]  # reads the log as the command's reader options say
    profile: str  # the starting profile: name, name@version or a file
    settings: SettingsRequest
    iterations: int = 5
    tolerance: float = 0.02
    average_from: int | None = None
    seed: int = 0
    name: str | None = None  # (default: <log name>-selfcal)
    version: str = "1.0.0"
    out: Path | None = None  # (default: runs/selfcal_<name>@<version>)
    profiles_dir: Path | None = None
    force: bool = False
    command: str = ""  # the command as typed (recorded in the profile)
    inputs: Callable[[Path, SensorLog], list] = field(default=lambda p, lg: [])  # a log's input files with their sha256

    def __post_init__(self) -> None:
        if self.iterations < 1:
            raise UsageError(f"--iterations: expected a positive integer, got {self.iterations}")
        if self.seed < 0:
            raise UsageError(f"--seed: expected a non-negative integer, got {self.seed}")
        n, k = self.iterations, self.average_from
        if k is not None and n < 2:
            raise UsageError(f"--average-from: averaging needs at least two runs, so --iterations 2 or more (got --iterations {n})")
        if k is not None and not 0 <= k <= n - 2:
            raise UsageError(f"--average-from: expected an iteration from 0 to {n - 2} (--iterations {n}: at least two runs to average), got {k}")
        if not 0 < self.tolerance < float("inf"):
            raise UsageError(f"--tolerance: expected a positive number, got {self.tolerance}")
        if not SEMVER_RE.match(self.version):
            raise UsageError(f"--version: {self.version!r} is not MAJOR.MINOR.PATCH")

    def run(self, progress=None, fresh=None) -> dict:
        """Check the inputs, decide both outputs, run the loop, write the run folder and the profile in one step;
        the summary a person reads. ``fresh(target, force, ...)``: the command's check of an output it may replace."""
        from calib.map_calibration import SelfCalConfig, pool_self_calibrations, profile_change, self_calibrate
        from detcal.reports.self_calibration import fill_selfcal_run
        from detcal.reports.slam_run import write_slam_run
        from calib.io.common import file_digest
        from profiles.atomic import Output, atomic_outputs
        from profiles.profile import InputRef
        from profiles.store import check_new_version, looks_like_profile, profile_path, resolve, write_profile_text
        from slam_runtime.run import check_inputs

        cfg, _ = self.settings.settings()
        start = resolve(self.profile)
        if start.pd.covariate != "range":
            raise UsageError(f"profile {start.ref}: self-calibration measures P_D against range; this profile has a {start.pd.covariate} table")
        log = self.read(self.log_path)
        if log.detections is None or log.scans is not None:
            raise UsageError(f"{log.name}: self-calibration takes a detection-level log (detections, no scans)")
        check_inputs(log, start)
        cfg = self.settings.derived(log, start)[0]  # (the settings the log and the profile give where the request gives none)
        name = self.name or f"{log.name.lower().replace('_', '-')}-selfcal"
        if not NAME_RE.match(name):
            raise UsageError(f"--name: {name!r} must match [a-z0-9][a-z0-9._-]*")
        target = self.out or Path("runs") / f"selfcal_{name}@{self.version}"
        start_file = profile_path(self.profile)  # given by name, it is still a file --force must not replace
        fresh(target, self.force, inputs=[self.log_path, start_file, self.settings.config])  # both outputs decided before any work
        saved, status = check_new_version(name, self.version, self.profiles_dir, force=self.force)
        fresh(saved, self.force, directory=False, owned=looks_like_profile, inputs=[start_file])
        # the log's files, and the starting profile and SLAM config with their digests: the command names them by path,
        # and a rebuild from the provenance must find the same ones (detcal profile rebuild compares the bytes)
        refs = self.inputs(self.log_path, log) + [
            InputRef(name=f.name, sha256=file_digest(f)) for f in (start_file, self.settings.config) if f is not None and Path(f).is_file()
        ]
        scfg, cals, k0 = SelfCalConfig(), [], self.average_from

        def recorded(p):
            # what rebuilds it: the profile the loop started from (each iteration's prior has the output's own
            # name@version) and the filter's seed (--seed 0 included)
            return updated(p, {"provenance.parameters.prior": start.ref, "provenance.seed": self.seed})

        def measure(lg, traj, map_xy, map_w, prior, k):
            c = self_calibrate(
                lg, traj, map_xy, map_w, prior, scfg, name=name, version=self.version, run=f"iteration {k} of this self-calibration",
                iteration=k, input_refs=refs, command=self.command, mount_yaw=cfg.mount_yaw,
            )  # fmt: skip
            if k0 is None or k < k0:
                return recorded(c.profile), c.summary
            cals.append(c)  # only the runs that are averaged are kept (their pairs and detections)
            pooled = pool_self_calibrations(cals, scfg, iterations=list(range(k0, k + 1)))
            return recorded(pooled), {**c.summary, "averaged_runs": k + 1 - k0, "averaged_false_alarms_per_frame": pooled.clutter.rate}

        history = self_calibration(
            log, start, cfg, self.seed, measure, profile_change, iterations=self.iterations, tolerance=self.tolerance, average_from=k0, progress=progress
        )  # fmt: skip
        last, final = history[-1], history[-1].measured
        record = {"log": self.log_path.name, "inputs": [r.model_dump() for r in refs], "profile": last.profile.ref, "seed": self.seed,
                  "settings": last.config.model_dump(mode="json")}  # fmt: skip
        outputs = [Output(target, directory=True, overwrite=self.force), Output(saved, overwrite=self.force, owned=looks_like_profile)]
        with atomic_outputs(outputs) as (run_tmp, prof_tmp):  # the run folder and the profile in one step
            run_tmp.mkdir()
            fill_selfcal_run(log, history, run_tmp, last_run=lambda folder: write_slam_run(log, last.result, folder, record))
            write_profile_text(final, prof_tmp)
        return self._summary(log, history, target, saved, "written" if status == "write" else "replaced")

    def _summary(self, log, history: list[Iteration], target: Path, saved: Path, status: str) -> dict:
        last, final, k0 = history[-1], history[-1].measured, self.average_from
        cfg_next = last.next_config or last.config  # the biases slam.yaml holds (averaged with --average-from)
        vehicle = build(log, last.profile, cfg_next).vehicle
        group = next(n for n, c in VEHICLE_MODELS.items() if isinstance(vehicle, c))
        return {
            "log": log.name,
            "profile": f"{final.ref} ({status}: {saved})",
            "run folder": str(target),
            "iterations": len(history),
            # with averaging the change of the average shrinks as 1/n whatever the runs do: it settles; its precision is the s.e. below
            ("converged" if k0 is None else "average settled (moved < tolerance)"): bool(last.change < self.tolerance),
            **(_spread(history[k0:]) if k0 is not None and len(history) > k0 + 1 else {}),
            "last change": last.change,
            **{k: v for k, v in last.result.metrics.items() if k.startswith(("trajectory_rmse", "odometry_rmse", "ms_per_step_median"))},
            **({label: getattr(getattr(cfg_next.motion, group), b) for b, label in vehicle.biases.items()} if last.bias else {}),
            "P_D table": ", ".join(f"{e:g}:{v:.2f}" for e, v in zip(final.pd.edges[:-1], final.pd.pd, strict=True)),
        }


def _spread(runs: list[Iteration]) -> dict:
    """What the averaged runs measured one by one: the mean with its standard error (the runs' sd / sqrt(n)),
    the precision of the average, which the change between consecutive averages (shrinking as 1/n) is not."""
    out = {"averaged runs": len(runs)}
    for key, label in (("false_alarms_per_frame", "false alarms per frame"), ("range_sigma_m", "range noise [m]")):
        x = np.array([it.summary[key] for it in runs], dtype=float)
        out[f"{label}, runs' mean +- s.e."] = f"{x.mean():.4g} +- {x.std(ddof=1) / np.sqrt(x.size):.2g}"
    return out
