"""The sweep folder of ``detcal slam sweep`` (:mod:`detcal.pipelines.sweep` runs the sweep): its plan, its run
folders, its tables, and the statistics of the tables.

The sweep folder is a container whose every entry is whole::

    config.yaml     the plan: settings, logs (name, input files, content fingerprint),
                    profiles (reference, sha256 of the text), every run (name, labels, frames)
    <run>/          one run folder per run (what ``detcal slam run`` writes, and task.yaml:
                    where the run ran, its wall and CPU seconds, the worker's peak memory)
    failed.yaml     the runs that failed in the last attempt, with their errors (gone once none did)
    runs.csv        one row per run: the labels and every metric but the timings
    summary.csv     mean and standard deviation of those metrics per setting
    paired.csv      settings that differ in one label (filter, P_D mode, particles, profile, variant), compared run
                    by run on the same log and seed: the mean difference of every metric, its
                    standard error and how often the first is lower (only when two settings differ so)
    timings.csv     per run: filter ms per step (wall, CPU) and the task's seconds, host, peak memory

* The folder is created with its plan in one step (built beside, renamed in).
* A run folder is built beside its name and moved in by one rename, after
  every file is written: a run is *done* when its folder is there and its
  config.yaml is the run the plan asks for. A killed sweep leaves whole run
  folders and hidden ``.part`` entries only (removed by the next write).
* The tables are written, each by one rename, once every run is done: their
  presence says the sweep is complete. Rows follow the plan's order and come
  from the run folders' metrics.yaml, so runs.csv and summary.csv are the
  same bytes whatever the engine, the number of workers, the order in which
  runs completed, or how many attempts the sweep took. The timings are apart
  (timings.csv, and ``ms`` in steps.csv): they are the only figures that vary.
* Running the same sweep again resumes it: the plan must be the same (else it
  is refused; ``--force`` starts the folder anew), done runs are skipped.
"""

from __future__ import annotations

import hashlib
import itertools
import os
from collections import Counter
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import pandas as pd
import yaml

from profiles.atomic import atomic_output, check_replaceable, written_by_detcal
from profiles.errors import UsageError

if TYPE_CHECKING:
    from detcal.pipelines.sweep import Failure, SweepJob

#: The plan's format tag (config.yaml of a sweep folder).
FORMAT = "detcal-sweep"
FORMAT_VERSION = 2  # 2: the label variant (slam sweep --vary) in every run; tables written with 10 digits
#: What varies between runs (the first columns of runs.csv). ``variant``: the settings a sweep varies besides these
#: (``detcal slam sweep --vary key=a,b``), written ``key=value`` (several joined by ``, ``); empty when none is varied.
LABELS = ("log", "profile", "filter", "pd_mode", "particles", "variant", "seed")
#: The labels of one setting: summary.csv has a row per setting (its runs over logs and seeds), the sweep table a column.
SETTING = ("profile", "filter", "pd_mode", "particles", "variant")
#: Metrics that are timings: they go to timings.csv, never to runs.csv or summary.csv.
TIMING_KEYS = ("ms_per_step_mean", "ms_per_step_median", "cpu_ms_per_step_mean")
#: The labels paired.csv compares settings by: two runs that differ in one of them and agree in every other label
#: (the same log and seed) are a pair.
COMPARED = ("filter", "pd_mode", "particles", "profile", "variant")


# ---------------------------------------------------------------------------- the plan and the folder


def _dump(data: dict) -> str:
    return yaml.safe_dump(data, sort_keys=False, default_flow_style=None, width=120)


def _normal(data):
    """``data`` as it reads back from YAML (tuples become lists, numpy scalars plain numbers)."""
    return yaml.safe_load(_dump(data))


def profile_digest(profile) -> str:
    from profiles.store import dump_profile

    return hashlib.sha256(dump_profile(profile).encode()).hexdigest()


def make_plan(jobs: list[SweepJob], settings: dict, logs: list[dict]) -> dict:
    """The sweep's config.yaml: the shared settings, the logs (as the caller describes them), the profiles, every run."""
    profs: dict[str, str] = {}
    for j in jobs:
        profs.setdefault(j.profile.ref, profile_digest(j.profile))
    return _normal(
        {
            "format": FORMAT,
            "version": FORMAT_VERSION,
            "settings": settings,
            "logs": logs,
            "profiles": [{"ref": r, "sha256": d} for r, d in profs.items()],
            "runs": [{"name": j.name, **{k: j.labels.get(k) for k in LABELS}, "frames": j.max_frames} for j in jobs],
        }
    )


def _same_run(folder: Path, job: SweepJob) -> bool:
    """True when ``folder`` is the whole run folder of ``job``."""
    if not written_by_detcal(folder, True) or not (folder / "metrics.yaml").is_file():
        return False
    try:
        return yaml.safe_load((folder / "config.yaml").read_text()) == _normal(job.run_config())
    except (OSError, yaml.YAMLError):
        return False


def check_run_names(jobs: list[SweepJob]) -> None:
    """Refuse two runs of one name (a setting given twice): each run is a folder of that name."""
    twice = sorted(n for n, k in Counter(j.name for j in jobs).items() if k > 1)
    if twice:
        raise UsageError(f"two runs of the sweep have the same name ({twice[0]}): a setting is given twice")


def open_sweep(folder: Path, plan: dict, jobs: list[SweepJob], *, force: bool = False) -> set[str]:
    """Create the sweep folder with its plan, or reopen one with the same plan; the names of the runs already done.

    ``force`` replaces an existing sweep folder (one detcal wrote) by an empty one.
    """
    folder = Path(folder)
    check_run_names(jobs)
    if force or not os.path.lexists(folder):
        with atomic_output(folder, overwrite=force, directory=True) as tmp:
            tmp.mkdir()
            (tmp / "config.yaml").write_text(_dump(plan))
        return set()
    if not written_by_detcal(folder, True):
        raise UsageError(f"{folder}: already exists (use --force to replace it)")
    try:
        old = yaml.safe_load((folder / "config.yaml").read_text())
    except (OSError, yaml.YAMLError):
        old = None
    if not isinstance(old, dict) or old.get("format") != FORMAT:
        raise UsageError(f"{folder}: already exists and is not a sweep detcal can resume (use --force to replace it)")
    if old.get("version") != plan["version"]:
        raise UsageError(
            f"{folder}: holds a sweep of another version of detcal's sweep format ({old.get('version')}, this detcal writes "
            f"{plan['version']}) and cannot be resumed (use --force to start it anew, or another --out)"
        )
    if old != plan:
        what = [k for k in ("settings", "logs", "profiles", "runs") if old.get(k) != plan.get(k)] or ["plan"]
        raise UsageError(
            f"{folder}: holds a sweep with other {', '.join(what)} (the same command resumes a sweep; use --force to start it anew, or another --out)"
        )
    done = set()
    for j in jobs:
        path = folder / j.name
        if _same_run(path, j):
            done.add(j.name)
        elif os.path.lexists(path):
            check_replaceable(path, overwrite=True, directory=True)  # an unfinished attempt detcal wrote is replaced; nothing else is
    return done


def _ours(_path: Path) -> bool:  # the tables of a sweep folder detcal opened
    return True


def _write_text(path: Path, text: str) -> None:
    with atomic_output(path, overwrite=True, owned=_ours) as tmp:
        tmp.write_text(text)


def install_run(folder: Path, job: SweepJob, files: dict[str, bytes], stats: dict) -> None:
    """Move one run folder into the sweep folder in one rename (built beside it first), with task.yaml."""
    with atomic_output(Path(folder) / job.name, overwrite=True, directory=True) as tmp:
        tmp.mkdir()
        for rel, data in files.items():
            p = tmp / rel
            p.parent.mkdir(parents=True, exist_ok=True)
            p.write_bytes(data)
        (tmp / "task.yaml").write_text(_dump({k: (round(v, 3) if isinstance(v, float) else v) for k, v in stats.items()}))


# ---------------------------------------------------------------------------- running


def write_failed(folder: Path, failed: list[Failure]) -> None:
    """failed.yaml: the runs that failed in this attempt with their errors (removed once none did)."""
    failed_file = Path(folder) / "failed.yaml"
    if failed:
        detail = {
            f.job.name: {**{k: f.job.labels.get(k) for k in LABELS}, "error": f.error, **({"traceback": f.trace} if f.trace else {})}
            for f in failed
        }
        _write_text(failed_file, _dump({"failed": detail, "rerun": "the same command completes only these runs"}))
    elif failed_file.exists():
        failed_file.unlink()


def write_tables(folder: Path, jobs: list[SweepJob], by: tuple[str, ...] = SETTING) -> tuple[list[dict], list[dict], list[dict], list[dict]]:
    """runs.csv, summary.csv, timings.csv and (when two settings differ in one label) paired.csv of a complete sweep;
    returns (rows, summary, paired, timings)."""
    folder = Path(folder)
    rows, timings = tables(folder, jobs)
    summary = summarise(rows, by, LABELS)
    pairs = paired(rows)
    for name, table in (("runs.csv", rows), ("summary.csv", summary), ("timings.csv", timings)):
        _write_text(folder / name, pd.DataFrame(table).to_csv(index=False, float_format="%.10g"))
    if pairs:
        _write_text(folder / "paired.csv", pd.DataFrame(pairs).to_csv(index=False, float_format="%.10g"))
    elif (folder / "paired.csv").exists():  # a table of an earlier attempt's plan cannot be left behind
        (folder / "paired.csv").unlink()
    return rows, summary, pairs, timings


def tables(folder: Path, jobs: list[SweepJob]) -> tuple[list[dict], list[dict]]:
    """(runs.csv rows, timings.csv rows) from the run folders, in the order of the jobs."""
    rows, timings = [], []
    for j in jobs:
        metrics = yaml.safe_load((folder / j.name / "metrics.yaml").read_text())
        task_file = folder / j.name / "task.yaml"
        task = yaml.safe_load(task_file.read_text()) if task_file.is_file() else {}
        labels = {k: j.labels.get(k) for k in LABELS}
        rows.append({**labels, **{k: v for k, v in metrics.items() if k not in TIMING_KEYS and not isinstance(v, str | dict)}})
        timings.append({"run": j.name, **{k: metrics.get(k) for k in TIMING_KEYS}, **{f"task_{k}": v for k, v in task.items()}})
    return rows, timings


def summarise(rows: list[dict], by: tuple[str, ...], labels: tuple[str, ...] = ()) -> list[dict]:
    """Mean and standard deviation of every numeric metric per group of ``by`` labels (``labels`` are not metrics)."""
    groups: dict[tuple, list[dict]] = {}
    for r in rows:
        groups.setdefault(tuple(r.get(k) for k in by), []).append(r)
    out = []
    for key, rs in groups.items():
        entry: dict = dict(zip(by, key, strict=True))
        entry["runs"] = len(rs)
        metrics = [k for k in rs[0] if k not in by and k not in labels and is_number(rs[0][k])]
        for k in metrics:
            vals = np.array([r[k] for r in rs if k in r], dtype=np.float64)
            entry[f"{k}_mean"] = float(vals.mean())
            entry[f"{k}_std"] = float(vals.std(ddof=1)) if vals.size > 1 else 0.0
        out.append(entry)
    return out


def is_number(v) -> bool:
    """Whether a value is a number: a metric's, in runs.csv (not a flag, a label or a missing value)."""
    return isinstance(v, int | float) and not isinstance(v, bool)


def _number(v) -> float:
    """A metric's value as a float; NaN for one a run does not have (None)."""
    return float(v) if is_number(v) else float("nan")


def _metric_keys(rows: list[dict], labels: tuple[str, ...]) -> list[str]:
    """The numeric metrics of runs.csv rows, in the first row's order (a metric some row lacks is left out)."""
    keys = [k for k, v in rows[0].items() if k not in labels and is_number(v)]
    return [k for k in keys if all(k in r for r in rows)]


def paired(rows: list[dict], compared: tuple[str, ...] = COMPARED, labels: tuple[str, ...] = LABELS) -> list[dict]:
    """Paired differences between the settings of a sweep (paired.csv).

    For every label of ``compared`` that takes two or more values, every two of its values a, b (in the order
    of the rows, the plan's) and every combination of the other labels' values: the runs of a and of b that
    agree in every other label (the same log and seed) are pairs. Per metric (one row each): the number of
    pairs with both values finite, the mean of a - b, its standard error (the differences' standard deviation
    over sqrt(pairs); 0 for one pair) and the pairs in which a is lower. A pair's runs share the log's data and
    the seed, so what a log does to both settings cancels. Empty when no label of ``compared`` varies."""
    if not rows:
        return []
    metrics = _metric_keys(rows, labels)
    out = []
    for lab in compared:
        values = list(dict.fromkeys(r.get(lab) for r in rows))
        if len(values) < 2:
            continue
        rest = [k for k in labels if k != lab]
        by_key: dict[tuple, dict] = {}
        for r in rows:  # (two logs of one name are two runs with the same labels: paired in turn, not overwritten)
            by_key.setdefault(tuple(r.get(k) for k in rest), {}).setdefault(r.get(lab), []).append(r)
        fixed = [rest.index(k) for k in compared if k != lab]  # the other compared labels, as positions in a key
        for a, b in itertools.combinations(values, 2):
            groups: dict[tuple, list[tuple[dict, dict]]] = {}
            for key, runs in by_key.items():
                if a in runs and b in runs:
                    groups.setdefault(tuple(key[i] for i in fixed), []).extend(zip(runs[a], runs[b], strict=False))
            for ctx, pairs in groups.items():
                head = {"varies": lab, "a": a, "b": b, **dict(zip((rest[i] for i in fixed), ctx, strict=True))}
                out.extend({**head, **stats} for stats in _differences(pairs, metrics))
    return out


def _differences(pairs: list[tuple[dict, dict]], metrics: list[str]) -> list[dict]:
    """Per metric with a finite difference in some pair: the pairs, mean a - b, its standard error, pairs a is lower."""
    out = []
    for m in metrics:
        d = np.array([_number(ra[m]) - _number(rb[m]) for ra, rb in pairs], dtype=np.float64)
        d = d[np.isfinite(d)]
        if d.size:
            se = float(d.std(ddof=1) / np.sqrt(d.size)) if d.size > 1 else 0.0
            out.append({"metric": m, "pairs": int(d.size), "mean_difference": float(d.mean()), "standard_error": se, "a_lower": int((d < 0).sum())})
    return out


def by_evidence(rows: list[dict]) -> list[dict]:
    """The values of a sweep's varied settings (label ``variant``) ranked by the runs' log evidence, per profile, filter,
    P_D mode and particle count: the likeliest (the largest mean log p(Z) over its runs, i.e. the largest joint
    evidence of the logs and seeds) and its lead over the next, paired by log and seed (mean, standard error, pairs
    in which it is higher). The evidence compares settings of the filter's model; a setting that changes which
    measurements the filter takes, or the profile's clutter model, changes the quantity itself."""
    fixed = tuple(k for k in SETTING if k != "variant")
    groups: dict[tuple, dict[object, list[dict]]] = {}
    for r in rows:
        if is_number(r.get("log_evidence")) and np.isfinite(r["log_evidence"]):
            groups.setdefault(tuple(r.get(k) for k in fixed), {}).setdefault(r.get("variant"), []).append(r)
    out = []
    for key, by_var in groups.items():
        means = {v: float(np.mean([r["log_evidence"] for r in rs])) for v, rs in by_var.items()}
        ranked = sorted(means, key=lambda v: -means[v])  # (stable: ties keep the plan's order)
        best = ranked[0]
        entry = {**dict(zip(fixed, key, strict=True)), "best": best, "best_mean": means[best], "means": means, "next": None}
        if len(ranked) > 1:
            nxt = ranked[1]
            runs: dict[tuple, dict[object, list[dict]]] = {}
            for v in (best, nxt):
                for r in by_var[v]:
                    runs.setdefault((r.get("log"), r.get("seed")), {}).setdefault(v, []).append(r)
            # next - best, so that _differences' "a lower" counts the pairs in which the likeliest is higher
            pairs = [p for rs in runs.values() for p in zip(rs.get(nxt, []), rs.get(best, []), strict=False)]
            d = _differences(pairs, ["log_evidence"])
            entry.update(next=nxt, pairs=0, lead=float("nan"), lead_se=0.0, lead_higher=0)
            if d:
                entry.update(pairs=d[0]["pairs"], lead=-d[0]["mean_difference"], lead_se=d[0]["standard_error"], lead_higher=d[0]["a_lower"])
        out.append(entry)
    return out
