"""One SLAM run as the application makes it: its settings, the filter over a log, its evaluation, its run folder.

The settings of a run (:class:`SettingsRequest`): the ``--config`` file, or
without one the settings derived for the log and the profile (the defaults,
with the motion noise of a ``motion.yaml`` beside a calibration's
``profile.yaml``), with the command line's options and ``--set`` changes
applied before the one validation (:func:`calib.config.load_yaml_model`), so an
error names its option. ``detcal slam run`` and every run of a sweep go through
:func:`run_and_evaluate` (the filter with the evaluation hooks, then
:func:`slam_runtime.run.evaluate`) and
:func:`detcal.reports.slam_run.write_slam_run`; :class:`SlamRun` is the pipeline
of the command (run -> evaluate -> write, as kiss-icp's ``pipeline.run()``).
"""

from __future__ import annotations

import contextlib
import typing
from dataclasses import dataclass, field
from pathlib import Path

from calib.config import load_yaml_model, read_yaml_mapping
from detcal.reports.slam_run import write_slam_run
from detectors.sensor_log import SensorLog
from profiles.errors import UsageError
from slam_runtime.config import SlamConfig, with_filter, with_settings
from slam_runtime.labels import labelled_hooks
from slam_runtime.mapfilter import MAP_FILTERS
from slam_runtime.run import MapOSPA, SlamResult, evaluate, run_slam

#: The options that set one setting each (slam run, slam sweep, selfcal) and that setting; --set and --vary refuse
#: these settings and name the option instead.
OPTIONS = {"--filter": "filter.kind", "--particles": "particles", "--pd-mode": "detection.pd_mode", "--features": "features", "--poses": "poses"}


def choices(key: str) -> tuple | None:
    """The values the setting ``key`` (dotted) may take, when it is a choice (a Literal); None otherwise."""
    if key == "filter.kind":
        return MAP_FILTERS.names()
    model = SlamConfig
    *parents, last = key.split(".")
    for part in parents:
        model = model.model_fields[part].annotation
    args = typing.get_args(model.model_fields[last].annotation)
    return args if args and all(isinstance(a, str) for a in args) else None


def check_option(flag: str, value) -> None:
    """The one check of an option of :data:`OPTIONS`: one of its setting's choices, or a positive count."""
    if value is None:
        return
    key = OPTIONS[flag]
    allowed = choices(key)
    if allowed is not None and value not in allowed:
        raise UsageError(f"{flag}: expected one of {', '.join(allowed)}, got {value!r}")
    if isinstance(value, int) and not isinstance(value, bool) and value < 1:
        raise UsageError(f"{flag}: expected a positive integer, got {value}")


def read_value(text: str):
    """A setting's value as written on the command line, read as YAML (``1e-3`` as a number, ``.inf``, ``true``)."""
    from profiles import strict_yaml

    v = strict_yaml.load(text)
    if isinstance(v, str):  # (YAML 1.1 reads 1e-3 as text)
        with contextlib.suppress(ValueError):
            v = float(v)
    return v


def own_option(key: str, how: str, options: dict[str, str] | None = None, verb: str = "set") -> None:
    """Refuse a dotted setting ``key`` given by ``how`` (--set, --vary) that has its own option among ``options``
    (default :data:`OPTIONS`), naming the option."""
    for flag, own in (options or OPTIONS).items():
        if own == key or own.startswith(key + "."):
            again = " (repeat it)" if verb == "vary" else ""
            raise UsageError(f"{how} {key}: use {flag}{again} to {verb} {own}" + ("" if own == key else f", and name single settings under {key}"))


def parse_sets(specs: list[str] | None) -> dict[str, object]:
    """``--set KEY=VALUE`` options as {dotted path: value}."""
    import yaml

    out: dict[str, object] = {}
    for spec in specs or []:
        key, sep, text = spec.partition("=")
        key = key.strip()
        if not sep or not key or not text.strip():
            raise UsageError(f"--set: expected KEY=VALUE (e.g. filter.cap=600), got {spec!r}")
        own_option(key, "--set")
        if key in out:
            raise UsageError(f"--set {key}: given twice")
        try:
            out[key] = read_value(text.strip())
        except yaml.YAMLError:
            raise UsageError(f"--set {key}: cannot read the value {text.strip()!r}") from None
    return out


@dataclass
class SettingsRequest:
    """The settings a command was asked for: a settings file (None: derived), the options of :data:`OPTIONS` (None:
    not given) and ``--set`` changes."""

    config: Path | None = None
    filter: str | None = None
    particles: int | None = None
    pd_mode: str | None = None
    features: str | None = None
    poses: str | None = None
    sets: dict = field(default_factory=dict)

    def __post_init__(self) -> None:
        for flag, value in self.options().items():
            check_option(flag, value)

    def options(self) -> dict[str, object]:
        return {"--filter": self.filter, "--particles": self.particles, "--pd-mode": self.pd_mode, "--features": self.features, "--poses": self.poses}

    def settings(self, profile_file: Path | None = None) -> tuple[SlamConfig, Path | None]:
        """The validated settings, and the motion.yaml they were derived from (None: a --config file or the defaults).

        Without a settings file, a calibration's ``motion.yaml`` beside the profile's ``profile.yaml`` gives the motion
        noise (the vehicle model measured on the calibration's logs)."""
        base = self._base(profile_file)
        motion = base if self.config is None else None
        given = {OPTIONS[f]: v for f, v in self.options().items() if v is not None and f != "--filter"}
        flags = {OPTIONS[f]: f for f in OPTIONS} | {k: f"--set {k}" for k in self.sets}
        # --filter's own settings (--set filter.x=...) apply to the filter it names, after the change of kind
        own = {k: v for k, v in self.sets.items() if k.startswith("filter.")} if self.filter is not None else {}
        cfg = load_yaml_model(SlamConfig, base, {**given, **{k: v for k, v in self.sets.items() if k not in own}}, flags)
        cfg = with_filter(cfg, self.filter)
        return (with_settings(cfg, own) if own else cfg), motion


    def _base(self, profile_file: Path | None) -> Path | None:
        """The settings file: --config, else a calibration's motion.yaml beside the profile's profile.yaml, else None."""
        if self.config is None and profile_file is not None and profile_file.name == "profile.yaml":
            if (profile_file.parent / "motion.yaml").is_file():
                return profile_file.parent / "motion.yaml"
        return self.config

    def given_keys(self, profile_file: Path | None = None) -> set[str]:
        """The dotted settings this request gives: the settings file's (every leaf), the options' and --set's."""
        base = self._base(profile_file)
        keys = set(_leaves(read_yaml_mapping(base))) if base is not None else set()
        return keys | {OPTIONS[f] for f, v in self.options().items() if v is not None} | set(self.sets)

    def derived(self, log: SensorLog, profile, profile_file: Path | None = None) -> tuple[SlamConfig, Path | None, dict[str, str]]:
        """:meth:`settings` with what the log and the profile give for the settings not given
        (:func:`slam_runtime.defaults.derived`), and {group: where it came from}."""
        from slam_runtime.defaults import derived

        cfg, motion = self.settings(profile_file)
        cfg, why = derived(cfg, log, profile, self.given_keys(profile_file))
        return cfg, motion, why


def _leaves(data: dict, prefix: str = ""):
    """The dotted keys of a nested mapping's leaves (an empty group counts as a leaf)."""
    for k, v in data.items():
        key = f"{prefix}{k}"
        if isinstance(v, dict) and v:
            yield from _leaves(v, key + ".")
        else:
            yield key


def evaluation_hooks(log: SensorLog, cfg: SlamConfig) -> tuple:
    """The per-step figures that need the truth: map OSPA against the log's landmarks, or against its landmark
    planes (every 5th step: the planes' truth is ray-traced) when it has plane truth and a ground-truth path."""
    m = cfg.metric
    if cfg.features == "planes" and log.planes is not None and "ground_truth" in log.reference:
        from slam_runtime.plane_features import plane_distance
        from slam_runtime.plane_metrics import landmark_truth

        return (MapOSPA(landmark_truth(log, length=m.plane_length)[0], m.ospa_c, m.ospa_p, every=5, distance=plane_distance),)
    return (MapOSPA(log.landmarks.xy, m.ospa_c, m.ospa_p),) if log.landmarks is not None else ()


def run_and_evaluate(log: SensorLog, profile, cfg: SlamConfig, seed: int, *, frames: int | None = None, progress=None):
    """(result with its metrics, the label history of a labelled filter or None): the run and its evaluation."""
    labelled = labelled_hooks() if MAP_FILTERS.get(cfg.filter.kind).labelled else ()
    res = run_slam(log, profile, cfg, seed, progress=progress, max_frames=frames, hooks=evaluation_hooks(log, cfg) + labelled)
    res.metrics = evaluate(log, res, cfg.metric.ospa_c, cfg.metric.ospa_p, cfg)
    return res, (labelled[0] if labelled else None)


def run_record(log_file: str | None, inputs: list[dict], profile, seed: int, frames: int | None, cfg: SlamConfig) -> dict:
    """A run folder's config.yaml: what the run was (the same whoever runs it, wherever)."""
    return {"log": log_file, "inputs": list(inputs), "profile": profile.ref, "seed": seed, "frames": frames, "settings": cfg.model_dump(mode="json")}


@dataclass
class SlamRun:
    """``detcal slam run``: a log read, a profile resolved, settings validated; :meth:`run` writes the run folder."""

    log: SensorLog
    log_file: str  # the log's file name (recorded)
    inputs: list[dict]  # the log's input files with their sha256
    profile: object
    config: SlamConfig
    seed: int
    out: Path
    frames: int | None = None
    force: bool = False
    result: SlamResult | None = field(default=None, init=False)

    def run(self, progress=None) -> SlamResult:
        res, labels = run_and_evaluate(self.log, self.profile, self.config, self.seed, frames=self.frames, progress=progress)
        record = run_record(self.log_file, self.inputs, self.profile, self.seed, self.frames, self.config)
        write_slam_run(self.log, res, self.out, record, overwrite=self.force, labels=labels)
        self.result = res
        return res
