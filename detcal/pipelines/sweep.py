"""Monte Carlo sweeps: many SLAM runs over logs x profiles x settings x seeds, resumable, on any engine.

:class:`SweepRequest` is ``detcal slam sweep``: it checks every setting and
profile before any log is read, reads the logs once to check them and leaves
handles (:class:`detcal.engine.LogSource`) in the jobs, so each run reads its
log where it runs. Each job is one complete run (:func:`run_job`: filter,
evaluation, the run folder of :func:`detcal.reports.slam_run.write_slam_run`
rendered where the job runs and handed back as bytes). :func:`run_sweep` hands
the jobs to an engine (in turn in this process by default, or on Dask workers),
moves each run folder into the sweep folder as soon as its job completes, and
tabulates the runs once all are done (the folder and its tables:
:mod:`detcal.reports.sweep`).
"""

from __future__ import annotations

import contextlib
import itertools
import os
import shutil
import tempfile
import traceback
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from types import SimpleNamespace

import numpy as np

from calib.config import read_yaml_mapping, set_dotted
from detcal.pipelines.slam_run import OPTIONS, SettingsRequest, check_option, own_option, read_value, run_and_evaluate, run_record
from detcal.reports.slam_run import write_slam_run
from detcal.reports.sweep import (
    SETTING,
    by_evidence,
    check_run_names,
    install_run,
    is_number,
    make_plan,
    open_sweep,
    write_failed,
    write_tables,
)
from detectors.sensor_log import SensorLog
from profiles.atomic import MARKER
from profiles.errors import DataError, DetcalError, UsageError
from slam_runtime.config import SlamConfig

#: the settings that have their own option in the sweep: --vary refuses them
OWN_OPTIONS = {"--filter": "filter.kind", "--particles": "particles", "--pd-mode": "detection.pd_mode"}


@dataclass
class SweepJob:
    name: str  # the run folder's name inside the sweep folder
    log: object  # a SensorLog, or a handle whose load() returns it where the job runs
    profile: object  # profiles.profile.DetectorProfile
    config: SlamConfig
    seed: int
    labels: dict  # what varies: log, profile, filter, pd_mode, particles, variant, seed
    max_frames: int | None = None
    inputs: list[dict] = field(default_factory=list)  # the log's input files with their sha256 (recorded in config.yaml)

    def run_config(self) -> dict:
        """The run folder's config.yaml: what the run was (the same whoever runs it)."""
        return run_record(self.labels.get("log"), self.inputs, self.profile, self.seed, self.max_frames, self.config)


def _log_of(job: SweepJob) -> SensorLog:
    return job.log.load() if hasattr(job.log, "load") else job.log


def run_job(job: SweepJob) -> dict[str, bytes]:
    """One run where it is called: filter, evaluation and the run folder's files ({relative path: bytes})."""
    log = _log_of(job)
    res, labels = run_and_evaluate(log, job.profile, job.config, job.seed, frames=job.max_frames)
    with tempfile.TemporaryDirectory(prefix="detcal-run-") as tmp:
        out = Path(tmp) / job.name
        write_slam_run(log, res, out, job.run_config(), labels=labels)
        return {p.relative_to(out).as_posix(): p.read_bytes() for p in sorted(out.rglob("*")) if p.is_file() and p.name != MARKER}


class InTurn:
    """The default engine: every job in this process, in order (``detcal.engine`` offers Dask ones)."""

    workers = 0
    label = "in this process"

    def map_unordered(self, fn: Callable, args: list[tuple], keys: list[str]) -> Iterator[tuple[int, bool, object, dict]]:
        import time

        for i, a in enumerate(args):
            t0, c0 = time.perf_counter(), time.process_time()
            try:
                value = fn(*a)
            except KeyboardInterrupt:
                raise
            except Exception as exc:  # a failed run is recorded, the others go on  # noqa: BLE001
                yield i, False, exc, {}
            else:
                yield i, True, value, {"wall_s": time.perf_counter() - t0, "cpu_s": time.process_time() - c0}


@dataclass
class Failure:
    job: SweepJob
    error: str
    trace: str | None = None  # the traceback of an error that is not a detcal error (a bug), for failed.yaml

    def line(self) -> str:
        lb = self.job.labels
        var = f", {lb['variant']}" if lb.get("variant") else ""
        return (
            f"{self.job.name} (log {lb.get('log')}, profile {lb.get('profile')}, {lb.get('filter')}, {lb.get('pd_mode')}, "
            f"{lb.get('particles')} particles{var}, seed {lb.get('seed')}): {self.error}"
        )


@dataclass
class SweepOutcome:
    folder: Path
    runs: int
    skipped: int  # done before this attempt
    ran: int  # done in this attempt
    failed: list[Failure]
    rows: list[dict] = field(default_factory=list)  # runs.csv (empty unless every run is done)
    summary: list[dict] = field(default_factory=list)
    paired: list[dict] = field(default_factory=list)  # paired.csv (:func:`paired`)
    timings: list[dict] = field(default_factory=list)

    @property
    def complete(self) -> bool:
        return not self.failed


def _failure(job: SweepJob, exc: BaseException) -> Failure:
    if isinstance(exc, DetcalError):
        return Failure(job, " ".join(str(exc).split()))
    return Failure(job, " ".join(f"{type(exc).__name__}: {exc}".split()), "".join(traceback.format_exception(exc)))


def run_sweep(
    jobs: list[SweepJob],
    folder: Path,
    engine=None,
    *,
    plan: dict | None = None,
    force: bool = False,
    done: set[str] | None = None,
    by: tuple[str, ...] = SETTING,
    progress=None,
) -> SweepOutcome:
    """Run the jobs not done yet on ``engine``, each run folder moved in as its job completes; the tables once all are done.

    engine: an object with ``map_unordered(fn, args, keys)`` yielding ``(index, ok,
    result or exception, stats)`` as jobs complete (default :class:`InTurn`; :mod:`detcal.engine` offers Dask ones).
    A failed job is recorded (failed.yaml, :attr:`SweepOutcome.failed`) and the
    others go on; running the sweep again does only what is missing. ``done``:
    what :func:`open_sweep` returned when the caller opened the folder itself
    (to check it before starting an engine).
    """
    folder = Path(folder)
    names = [j.name for j in jobs]  # (checked distinct by open_sweep, which opened the folder)
    if done is None:
        done = open_sweep(folder, plan if plan is not None else make_plan(jobs, {}, []), jobs, force=force)
    todo = [j for j in jobs if j.name not in done]
    engine = engine or InTurn()
    failures: list[Failure] = []
    if todo:
        it = engine.map_unordered(run_job, [(j,) for j in todo], [f"run-{j.name}" for j in todo])
        if progress is not None:
            it = progress(it, len(todo), f"sweep {engine.label}")
        for i, ok, value, stats in it:
            if ok:
                install_run(folder, todo[i], value, stats)
            else:
                failures.append(_failure(todo[i], value))
    outcome = SweepOutcome(folder, len(jobs), len(done), len(todo) - len(failures), sorted(failures, key=lambda f: names.index(f.job.name)))
    write_failed(folder, outcome.failed)
    if not outcome.failed:
        outcome.rows, outcome.summary, outcome.paired, outcome.timings = write_tables(folder, jobs, by)
    return outcome


def variants(specs: list[str] | None) -> list[tuple[str | None, dict]]:
    """The --vary options as [(label, {dotted key: value})], every combination of their values (one (None, {})
    without the option). A value is read as YAML; the label keeps it as written (``filter.survival=0.99``)."""
    import yaml

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
        own_option(key, "--vary", OWN_OPTIONS, verb="vary")
        for other in seen:
            if other.startswith(key + ".") or key.startswith(other + "."):
                raise UsageError(f"--vary {key}: overlaps --vary {other} (vary single settings, not a group and a setting in it)")
        if key in seen:
            raise UsageError(f"--vary {key}: given twice (list its values in one option: {key}=V1,V2)")
        seen.add(key)
        axis, same = [], set()
        for t in tokens:
            try:
                v = read_value(t)
            except yaml.YAMLError:
                raise UsageError(f"--vary {key}: cannot read the value {t!r}") from None
            if isinstance(v, dict | list):
                raise UsageError(f"--vary {key}: {t!r} is not a single value (vary one setting at a time)")
            ident = ("number", v) if is_number(v) else (type(v).__name__, v)  # (1 and 1.0 are one value; true is not 1)
            if ident not in same:
                same.add(ident)
                axis.append((key, t, v))
        axes.append(axis)
    return [(", ".join(f"{k}={t}" for k, t, _ in combo), {k: v for k, _, v in combo}) for combo in itertools.product(*axes)]


@dataclass
class SweepRequest:
    """``detcal slam sweep``: what to cross (logs, profiles, filters, P_D modes, particle counts, varied settings,
    seeds), the shared settings, where the runs go and where they run."""

    logs: list[Path]
    read: Callable[[Path], SensorLog]  # reads a log as the command's reader options say (refusing an empty one)
    fmt: str | None  # the reader options again, for the handles the runs read their logs with
    read_options: object
    profiles: list[str]
    settings: SettingsRequest  # --config and --poses, and the first --particles (the islands check)
    seeds: list[int]
    out: Path
    filters: list[str] | None = None
    pd_modes: list[str] | None = None
    particles: list[int] | None = None
    vary: list[str] | None = None
    frames: int | None = None
    workers: int | None = None
    scheduler: str | None = None
    force: bool = False
    inputs: Callable[[Path, SensorLog], list] = field(default=lambda p, lg: [])  # a log's input files with their sha256
    write_config: Path | None = None  # --write-config: the likeliest variant's settings file (written after the runs)
    jobs: list[SweepJob] = field(default_factory=list, init=False)
    plan: dict = field(default_factory=dict, init=False)
    varied: list = field(default_factory=list, init=False)
    _base_mapping: dict = field(default_factory=dict, init=False)

    def prepare(self) -> None:
        """Check everything and make the jobs and the plan; no run starts and nothing is written."""
        from detcal.engine import LogSource, check_options
        from profiles.store import resolve
        from slam_runtime.config import override, with_filter, with_settings
        from slam_runtime.defaults import derived
        from slam_runtime.run import check_features, check_inputs, check_poses

        # the settings file as the runs read it (the plan's particle count; --write-config's start, so that an edit
        # during a long sweep does not reach the written file)
        self._base_mapping = read_yaml_mapping(self.settings.config) if self.settings.config is not None else {}
        modes = list(dict.fromkeys(self.pd_modes or ["profile", "constant"]))
        for m in modes:
            check_option("--pd-mode", m)
        base, _ = self.settings.settings()
        kinds = list(dict.fromkeys(self.filters or [base.filter.kind]))
        for f in kinds:
            check_option("--filter", f)
        counts = list(dict.fromkeys(self.particles or [base.particles]))
        if min(counts) < 1:
            raise UsageError(f"--particles: expected positive integers, got {counts}")
        self.varied = variants(self.vary)
        configs = {}  # (filter, variant) -> its settings, each checked before any log is read
        for f in kinds:
            fcfg = with_filter(base, f)
            plain = fcfg.model_dump()
            for key in self.varied[0][1]:  # (every variant has the same keys) a group's whole value would replace the settings
                node = plain  # in it, which other labels name
                for part in key.split("."):
                    node = node.get(part) if isinstance(node, dict) else None
                if isinstance(node, dict):
                    raise UsageError(f"--vary {key}: a group of settings; vary the single settings in it (e.g. {key}.{next(iter(node))})")
            for label, changes in self.varied:
                try:
                    configs[f, label] = with_settings(fcfg, changes)
                except UsageError as exc:
                    raise UsageError(f"--vary {label}, for filter {f}: {exc}") from None
        checked = {c.poses: c for c in configs.values()}  # (a varied setting may put the runs on the truth's poses)
        if self.write_config is not None:
            self._check_write_config(modes, kinds, counts)
        if self.frames is not None and self.frames < 1:
            raise UsageError(f"--frames: expected a positive integer, got {self.frames}")
        check_options(self.workers, self.scheduler)
        profs = [resolve(r) for r in dict.fromkeys(self.profiles)]
        for (_, label), c in configs.items():  # every run's features against every profile, before any log is read
            for prof in profs:
                try:
                    check_features(prof, c, planes="features: planes (in --config or --vary)")
                except UsageError as exc:
                    raise UsageError(f"--vary {label}: {exc}" if label is not None else str(exc)) from None
        sources, described = [], []
        for p in self.logs:
            log = self.read(p)
            for prof in profs:
                check_inputs(log, prof)
            for c in checked.values():  # a log the runs could not be put on the truth of is refused before any run
                check_poses(log, c, self.frames)
            src = LogSource.of(log, p, self.fmt, self.read_options)
            refs = [r.model_dump() for r in self.inputs(p, log)]
            # what the settings derive from a log (slam_runtime.defaults) needs its odometry and vehicle only
            sources.append((src, refs, SimpleNamespace(odometry=log.odometry, vehicle=log.vehicle)))
            described.append({"name": log.name, "file": p.name, "inputs": refs, "fingerprint": src.fingerprint})
            del log  # the runs read it where they run
        self.jobs = []
        given = self.settings.given_keys() | {k for _, changes in self.varied for k in changes}
        for i, (src, refs, odo) in enumerate(sources):
            for prof, f, m, n, (v, (label, _)) in itertools.product(profs, kinds, modes, counts, enumerate(self.varied)):
                cfg = override(configs[f, label], particles=n, **{"detection.pd_mode": m})
                cfg = derived(cfg, odo, prof, given)[0]  # the settings no option, file or variant gives, from the log
                tag = f"_v{v}" if self.vary else ""
                for sd in self.seeds:
                    name = f"{i:02d}_{src.name}_{prof.ref}_{f}_{m}_p{n}{tag}_s{sd}"
                    labels = {"log": src.name, "profile": prof.ref, "filter": f, "pd_mode": m, "particles": n, "variant": label, "seed": sd}
                    self.jobs.append(SweepJob(name, src, prof, cfg, sd, labels, self.frames, refs))
        # the plan records the config's own particle count, as before --particles met the islands check: each run holds
        # its own, and a sweep then resumes whatever order --particles comes in
        own = int(self._base_mapping.get("particles", SlamConfig.model_fields["particles"].default))
        self.plan = make_plan(self.jobs, {**base.model_dump(mode="json"), "particles": own}, described)

    def _check_write_config(self, modes: list[str], kinds: list[str], counts: list[int]) -> None:
        """--write-config needs varied settings to choose among and one setting of everything else (the evidence ranks
        the variants within one profile, filter, P_D mode and particle count), and a file name not taken."""
        target = self.write_config
        if len(self.varied) < 2:
            raise UsageError("--write-config: nothing to choose; give --vary KEY=V1,V2,... (the likeliest value is written)")
        several = [f"{what} {', '.join(map(str, vals))}" for what, vals in (
            ("profiles", list(dict.fromkeys(self.profiles))), ("filters", kinds), ("P_D modes", modes), ("particle counts", counts),
        ) if len(vals) > 1]  # fmt: skip
        if several:
            hint = "; give one --pd-mode (without it the sweep runs both)" if len(modes) > 1 and self.pd_modes is None else ""
            raise UsageError(f"--write-config: the sweep ranks its variants for each of several {'; '.join(several)}: sweep one at a time{hint}")
        if os.path.lexists(target):
            raise UsageError(f"--write-config: {target} exists; remove it or name another file (a settings file is never overwritten)")
        if not target.parent.is_dir():
            raise UsageError(f"--write-config: no folder {target.parent} to write {target.name} in")

    def write_likeliest(self, rows: list[dict]) -> dict:
        """Write ``write_config``: the settings file the runs started from (``--config``'s mapping, comments not kept),
        the options the sweep was given (``--filter``, ``--particles``, ``--pd-mode``, ``--poses``) and the varied
        settings at the likeliest variant's values (:func:`detcal.reports.sweep.by_evidence`), under a header that
        names the choice and every variant's mean log evidence. ``detcal slam run --config`` with it on the same log and
        seed repeats the likeliest variant's run (the settings no file gives are derived from the log as in the sweep).
        Returns the ranking's entry."""
        import yaml

        from profiles.atomic import atomic_output

        bad = [r for r in rows if not (is_number(r.get("log_evidence")) and np.isfinite(float(r["log_evidence"])))]
        if bad:  # (every variant is then ranked on the same logs and seeds)
            r = bad[0]
            raise DataError(
                f"--write-config: {len(bad)} of {len(rows)} runs recorded no finite log evidence (the first: {r.get('variant')}, log"
                f" {r.get('log')}, seed {r.get('seed')}), so the variants cannot be ranked; {self.write_config} not written"
            )
        (rank,) = by_evidence(rows)
        label, changes = next((lb, ch) for lb, ch in self.varied if lb == rank["best"])
        job = next(j for j in self.jobs if j.labels["variant"] == label)
        mapping = _plain(self._base_mapping)  # (a copy that shares nothing: YAML aliases would share one group)
        if self.filters:  # the filter's section as the runs had it (--filter changes the kind and its options)
            mapping["filter"] = {"kind": job.config.filter.kind, **job.config.filter.model_dump(mode="json", exclude_defaults=True)}
        given = {  # the options given, by flag
            "--filter": self.filters and job.labels["filter"],
            "--particles": self.particles and job.labels["particles"],
            "--pd-mode": self.pd_modes and job.labels["pd_mode"],
            "--poses": self.settings.poses,
        }
        options = {flag: v for flag, v in given.items() if v}
        for key, value in [*((OPTIONS[flag], v) for flag, v in options.items()), *changes.items()]:
            set_dotted(mapping, key, value)
        logs = ", ".join(dict.fromkeys(j.labels["log"] for j in self.jobs))
        frames = f"; first {self.frames} frames" if self.frames else ""
        rest = self.settings.config.name if self.settings.config is not None else "no settings file"
        head = [
            f"Written by detcal slam sweep --write-config: of {len(rank['means'])} variants the likeliest by the mean log evidence of its runs",
            f"(log p(Z), no ground truth; logs {logs}; seeds {', '.join(map(str, self.seeds))}{frames}): {label}.",
            f"Lead over the next ({rank['next']}): {rank['lead']:.1f} +- {rank['lead_se']:.1f} nats, higher in {rank['lead_higher']}"
            f" of {rank['pairs']} pairs.",
            "Mean log evidence [nats] of each variant:",
            *(f"  {v}: {m:.1f}" for v, m in rank["means"].items()),
            f"The rest: {rest}" + "".join(f", {flag} {v}" for flag, v in options.items()) + f"; profile {job.profile.ref}"
            + "; settings no file gives are derived from the log and the profile at run time"
            + (f" (to repeat one of the sweep's runs, give --frames {self.frames} too)." if self.frames else "."),
        ]
        text = "".join(f"# {line}\n" for line in head) + yaml.safe_dump(mapping, sort_keys=False, default_flow_style=False)
        with atomic_output(self.write_config, overwrite=False) as tmp:
            tmp.write_text(text)
        return rank

    def run(self, progress=None) -> tuple[SweepOutcome, str]:
        """Open (or resume) the sweep folder, run what is missing on the engine; (outcome, where it ran)."""
        from detcal.engine import InProcess, open_engine

        if self.force:  # checked before any worker starts; the old sweep is replaced only once the engine is up
            check_run_names(self.jobs)
            made, done = False, None
        else:
            made = not os.path.lexists(self.out)
            done = open_sweep(self.out, self.plan, self.jobs)  # checked (and created) before any worker starts
        todo = len(self.jobs) - len(done or ())
        engine_cm = open_engine(self.workers, self.scheduler, todo) if todo else contextlib.nullcontext(InProcess())
        with contextlib.ExitStack() as stack:
            try:
                engine = stack.enter_context(engine_cm)
            except BaseException:
                if made:  # the cluster refused before any run: leave no empty sweep folder behind
                    shutil.rmtree(self.out, ignore_errors=True)
                raise
            if done is None:
                done = open_sweep(self.out, self.plan, self.jobs, force=True)
            res = run_sweep(self.jobs, self.out, engine, done=done, progress=progress)
            return res, engine.label

    @staticmethod
    def refuse_failures(res: SweepOutcome) -> None:
        """A DataError naming the failed runs and where the others are (the command's exit code 1)."""
        if res.failed:
            raise DataError(
                f"{len(res.failed)} of {res.runs} runs failed ({', '.join(f.job.name for f in res.failed)}; listed in "
                f"{res.folder / 'failed.yaml'}); the {res.skipped + res.ran} others are in {res.folder}: run the same command again "
                "to complete only the missing ones"
            )


def _plain(node: object) -> object:
    """A copy of a YAML document's mappings and lists that shares no container (copy.deepcopy keeps the aliases)."""
    if isinstance(node, dict):
        return {k: _plain(v) for k, v in node.items()}
    if isinstance(node, list):
        return [_plain(v) for v in node]
    return node
