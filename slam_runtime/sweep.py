"""Monte Carlo sweeps: many SLAM runs over logs x profiles x settings x seeds, in parallel processes.

Each job is a complete run (its own folder, written by
:func:`slam_runtime.report.write_slam_run`); the sweep then tabulates every
run's metrics and averages them per setting. Jobs carry the log in memory (it
is pickled to the worker), so this module reads no files and never imports
``calib``.
"""

from __future__ import annotations

import os
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from detectors.logs import SensorLog
from slam_runtime.config import SlamConfig


@dataclass
class SweepJob:
    name: str  # the run folder's name inside the sweep folder
    log: SensorLog
    profile: object  # profiles.profile.DetectorProfile
    config: SlamConfig
    seed: int
    labels: dict  # what varies: log, profile, filter, pd_mode, particles, seed
    max_frames: int | None = None


def run_job(job: SweepJob, folder: Path) -> dict:
    """One run: filter, run folder, and the row for the sweep table."""
    from slam_runtime.labels import labelled_hooks
    from slam_runtime.report import write_slam_run
    from slam_runtime.run import MapOSPA, evaluate, run_slam

    m = job.config.metric
    hooks = (MapOSPA(job.log.landmarks.xy, m.ospa_c, m.ospa_p),) if job.log.landmarks is not None else ()
    labelled = labelled_hooks() if job.config.filter.kind != "rbphd" else ()
    res = run_slam(job.log, job.profile, job.config, job.seed, max_frames=job.max_frames, hooks=hooks + labelled)
    res.metrics = evaluate(job.log, res, m.ospa_c, m.ospa_p, job.config)
    cfg = {
        "log": job.labels.get("log"),
        "profile": job.profile.ref,
        "seed": job.seed,
        "frames": job.max_frames,
        "settings": job.config.model_dump(mode="json"),
    }
    write_slam_run(job.log, res, folder / job.name, cfg, overwrite=False, labels=labelled[0] if labelled else None)
    return {**job.labels, **{k: v for k, v in res.metrics.items() if not isinstance(v, str | dict)}}


def _work(args):
    job, folder = args
    return run_job(job, folder)


def run_sweep(jobs: list[SweepJob], folder: Path, workers: int | None = None) -> list[dict]:
    """Run ``jobs`` in ``workers`` processes (default: the CPU count); rows in job order."""
    workers = max(1, min(len(jobs), workers or os.cpu_count() or 1))
    if workers == 1:
        return [run_job(j, folder) for j in jobs]
    with ProcessPoolExecutor(workers) as ex:
        return list(ex.map(_work, [(j, folder) for j in jobs]))


def summarise(rows: list[dict], by: tuple[str, ...], labels: tuple[str, ...] = ()) -> list[dict]:
    """Mean and standard deviation of every numeric metric per group of ``by`` labels (``labels`` are not metrics)."""
    groups: dict[tuple, list[dict]] = {}
    for r in rows:
        groups.setdefault(tuple(r.get(k) for k in by), []).append(r)
    out = []
    for key, rs in groups.items():
        entry: dict = dict(zip(by, key, strict=True))
        entry["runs"] = len(rs)
        metrics = [k for k in rs[0] if k not in by and k not in labels and isinstance(rs[0][k], int | float) and not isinstance(rs[0][k], bool)]
        for k in metrics:
            vals = np.array([r[k] for r in rs if k in r], dtype=np.float64)
            entry[f"{k}_mean"] = float(vals.mean())
            entry[f"{k}_std"] = float(vals.std(ddof=1)) if vals.size > 1 else 0.0
        out.append(entry)
    return out
