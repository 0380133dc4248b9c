"""One SLAM run as the application makes it: the filter over a log, its evaluation, its run folder.

``detcal slam run`` and every run of a sweep go through :func:`run_and_evaluate`
(the filter with the evaluation hooks, then :func:`slam_runtime.run.evaluate`)
and :func:`detcal.reports.slam_run.write_slam_run`; :class:`SlamRun` is the
pipeline of the command (run -> evaluate -> write, as kiss-icp's
``pipeline.run()``).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from detcal.reports.slam_run import write_slam_run
from detectors.logs import SensorLog
from slam_runtime.config import SlamConfig
from slam_runtime.labels import labelled_hooks
from slam_runtime.mapfilter import MAP_FILTERS
from slam_runtime.run import MapOSPA, SlamResult, evaluate, run_slam


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
