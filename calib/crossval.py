"""``detcal validate --cv robots|time``: cross-validation of the whole calibration.

Each fold calibrates on some data and validates on the rest (:mod:`calib.validate`):

* ``robots`` -- leave one sensor out: every log (a robot of a UTIAS dataset, a
  laser log) is held out once and the profile is calibrated on the others.
  This asks whether a pooled profile transfers to a sensor it has never seen.
  With ``adapt`` seconds, the held-out sensor's first ``adapt`` seconds join the
  calibration as a sensor of its own and its partially pooled profile
  (:mod:`calib.pdmodels`) is scored beside the pooled one on the rest of its
  log: what a short calibration run buys a new robot;
* ``time`` -- every log is cut at the middle of its frames; the first halves
  calibrate and the second halves validate, then the other way round. With
  several detection-level sensors each sensor's own (partially pooled) profile
  is scored beside the pooled one.

Every fold is a row of the table (one row per held-out log and profile), and a
reliability figure. Means over folds are in the summary, with the false-alarm
error pooled over every held-out frame.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path
from typing import Literal

import numpy as np
import pandas as pd

from calib.config import dump_yaml
from calib.io.atomic import atomic_output
from calib.validate import GZ, Validation, _plain, plot_reliability
from detectors.sensor_log import Detections, Odometry, ScanBatch, SensorLog
from profiles.errors import UsageError
from profiles.override import updated

HALF = ("1st", "2nd")
TABLE_COLUMNS = (
    "fold", "train", "test", "profile", "pairs_informative", "ece", "ece_if_calibrated", "ece_if_calibrated_blocks", "brier", "loglik_per_pair",
    "frames", "false_alarms_per_frame_observed", "false_alarms_per_frame_predicted", "false_alarm_relative_error",
    "false_alarm_relative_error_ci95_low", "false_alarm_relative_error_ci95_high", "clutter_chi2_p_value",
    "clutter_dispersion", "true_detections", "hotelling_coverage", "frame_period_s",
    "verdict", "drift", "pd_p_value", "clutter_p_value", "noise_p_value", "coverage_p_value",
)
TEXT_COLUMNS = ("verdict", "drift")


def frame_stamps(log: SensorLog) -> np.ndarray:
    if log.scans is not None:
        return log.scans.stamp
    if log.detections is not None:
        return log.detections.frame_stamp
    raise UsageError(f"log {log.name!r} has neither scans nor detections to cut")


def time_slice(log: SensorLog, start: int, stop: int, suffix: str) -> SensorLog:
    """The frames of ``log`` with stamp in [start, stop) ns, the odometry rows in that span, all else whole.

    Reference poses and landmarks stay whole: they are truth, needed to
    interpolate the poses at the slice's edges.
    """
    scans = odometry = detections = None
    if log.scans is not None:
        w = (log.scans.stamp >= start) & (log.scans.stamp < stop)
        s = log.scans
        scans = ScanBatch(
            s.stamp[w], s.ranges[w], None if s.intensities is None else s.intensities[w], None if s.odom_pose is None else s.odom_pose[w]
        )
    if log.detections is not None:
        d = log.detections
        keep = (d.frame_stamp >= start) & (d.frame_stamp < stop)
        new_index = np.cumsum(keep) - 1
        rows = keep[d.frame]
        detections = Detections(
            d.frame_stamp[keep], new_index[d.frame[rows]], d.range[rows], d.bearing[rows], {k: v[rows] for k, v in d.descriptors.items()}
        )
    if log.odometry is not None:
        o = log.odometry
        w = (o.stamp >= start) & (o.stamp < stop)
        odometry = Odometry(o.kind, o.stamp[w], o.values[w], o.sigma)
    return replace(log, name=f"{log.name}_{suffix}", scans=scans, detections=detections, odometry=odometry, clouds=None)


def halves(log: SensorLog) -> tuple[SensorLog, SensorLog]:
    """(first half, second half) of a log, cut at the middle of its frames' time span."""
    fs = frame_stamps(log)
    if fs.size < 4:
        raise UsageError(f"log {log.name!r} has too few frames to cut in halves")
    mid = int(fs[0] + (fs[-1] - fs[0]) // 2)
    return time_slice(log, int(fs[0]), mid, "first"), time_slice(log, mid, int(fs[-1]) + 1, "second")


@dataclass
class FoldResult:
    fold: str
    train: list[str]
    test: str
    profile: str  # "pooled" or "own"
    validation: Validation


@dataclass
class CrossValidation:
    kind: str
    folds: list[FoldResult]
    table: pd.DataFrame
    summary: dict


def _row(f: FoldResult) -> dict:
    s = f.validation.summary
    row = {"fold": f.fold, "train": "+".join(f.train), "test": f.test, "profile": f.profile}
    for c in TABLE_COLUMNS[4:]:
        if c.endswith(("_ci95_low", "_ci95_high")):
            base, end = c.rsplit("_", 1)
            row[c] = s.get(base, [np.nan, np.nan])[0 if end == "low" else 1]
        else:
            v = s.get(c, np.nan)
            row[c] = v if c in TEXT_COLUMNS else (np.nan if isinstance(v, list | str) else v)
    return row


def summarise(kind: str, folds: list[FoldResult]) -> tuple[pd.DataFrame, dict]:
    table = pd.DataFrame([_row(f) for f in folds], columns=list(TABLE_COLUMNS))
    summary: dict = {"cv": kind, "folds": len({f.fold for f in folds})}
    for prof in dict.fromkeys(table["profile"]):
        t = table[table["profile"] == prof]
        fr = t["frames"].to_numpy(float)
        obs = (t["false_alarms_per_frame_observed"].to_numpy(float) * fr).sum()
        pred = (t["false_alarms_per_frame_predicted"].to_numpy(float) * fr).sum()
        summary[prof] = {
            "rows": len(t),
            "mean_ece": float(t["ece"].mean()),
            "max_ece": float(t["ece"].max()),
            "mean_ece_if_calibrated": float(t["ece_if_calibrated"].mean()),
            "mean_ece_if_calibrated_blocks": float(t["ece_if_calibrated_blocks"].mean()),
            "mean_brier": float(t["brier"].mean()),
            "mean_loglik_per_pair": float(t["loglik_per_pair"].mean()),
            "mean_abs_false_alarm_error": float(t["false_alarm_relative_error"].abs().mean()),
            "max_abs_false_alarm_error": float(t["false_alarm_relative_error"].abs().max()),
            "pooled_false_alarm_error": float(obs / pred - 1) if pred > 0 else float("nan"),
        }
        summary[prof]["verdicts"] = {str(k): int(v) for k, v in t["verdict"].value_counts().sort_index().items()}
        if t["hotelling_coverage"].notna().any():
            summary[prof]["mean_hotelling_coverage"] = float(t["hotelling_coverage"].mean())
    return table, summary


# ------------------------------------------------------------------------------------------ drivers


def _detection_folds(logs, kind, cfg, adapt: float | None) -> list[FoldResult]:
    from calib.detlevel import calibrate_detections, sensor_id, validate_detections

    out: list[FoldResult] = []
    if kind == "robots":
        if len(logs) < 2:
            raise UsageError("--cv robots needs at least two logs (sensors)")
        for k, test in enumerate(logs):
            train = [lg for j, lg in enumerate(logs) if j != k]
            tag = sensor_id(test)
            if adapt:
                fs = frame_stamps(test)
                cut = int(fs[0] + round(adapt * 1e9))
                if cut >= fs[-1]:
                    raise UsageError(f"--adapt {adapt:g} s is longer than log {test.name!r}")
                head = time_slice(test, int(fs[0]), cut, "adapt")
                rest = time_slice(test, cut, int(fs[-1]) + 1, "rest")
                cal = calibrate_detections([*train, head], cfg, name="cv", version="0.0.0", per_sensor=True)
                names = [sensor_id(lg) for lg in train]
                out.append(FoldResult(tag, names, f"{tag}:rest", "pooled", validate_detections(cal.profile, [rest])))
                out.append(FoldResult(tag, names + [f"{tag}:{adapt:g}s"], f"{tag}:rest", "own", validate_detections(cal.members[-1], [rest])))
            else:
                cal = calibrate_detections(train, cfg, name="cv", version="0.0.0")
                out.append(FoldResult(tag, [sensor_id(lg) for lg in train], tag, "pooled", validate_detections(cal.profile, [test])))
        return out
    parts = [halves(lg) for lg in logs]
    for direction, (a, b) in (("1st->2nd", (0, 1)), ("2nd->1st", (1, 0))):
        train = [p[a] for p in parts]
        cal = calibrate_detections(train, cfg, name="cv", version="0.0.0", per_sensor=len(logs) > 1)
        names = [f"{sensor_id(lg)}:{HALF[a]}" for lg in logs]
        for k, p in enumerate(parts):
            test = f"{sensor_id(logs[k])}:{HALF[b]}"
            out.append(FoldResult(direction, names, test, "pooled", validate_detections(cal.profile, [p[b]])))
            if cal.members:
                out.append(FoldResult(direction, names, test, "own", validate_detections(cal.members[k], [p[b]])))
    return out


def _laser_folds(logs, kind, cfg, landmarks_csv, poses) -> list[FoldResult]:
    from calib.calibrate import calibrate
    from calib.validate import validate

    out: list[FoldResult] = []
    if kind == "robots":
        if len(logs) < 2:
            raise UsageError("--cv robots needs at least two logs (sensors)")
        for k, test in enumerate(logs):
            train = [lg for j, lg in enumerate(logs) if j != k]
            cal = calibrate(train, cfg, name="cv", version="0.0.0", landmarks_csv=landmarks_csv)
            v = validate(cal.profile, test, landmarks_csv=landmarks_csv, poses=poses)
            out.append(FoldResult(test.name, [lg.name for lg in train], test.name, "pooled", v))
        return out
    parts = [halves(lg) for lg in logs]
    for direction, (a, b) in (("1st->2nd", (0, 1)), ("2nd->1st", (1, 0))):
        train = [p[a] for p in parts]
        cal = calibrate(train, cfg, name="cv", version="0.0.0", landmarks_csv=landmarks_csv)
        for lg, p in zip(logs, parts, strict=True):
            v = validate(cal.profile, p[b], landmarks_csv=landmarks_csv, poses=poses)
            out.append(FoldResult(direction, [f"{x.name}:{HALF[a]}" for x in logs], f"{lg.name}:{HALF[b]}", "pooled", v))
    return out


def cross_validate(
    logs: list[SensorLog],
    kind: Literal["robots", "time"],
    *,
    config=None,
    adapt: float | None = None,
    landmarks_csv: Path | None = None,
    poses: str = "auto",
) -> CrossValidation:
    """Cross-validate the calibration of ``logs``: detection-level logs or laser logs (not mixed).

    ``config``: a :class:`calib.detlevel.DetectionCalibConfig` or a
    :class:`calib.calibrate.CalibrateConfig` (defaults when None).
    """
    if kind not in ("robots", "time"):
        raise UsageError(f"--cv: expected robots or time, got {kind!r}")
    detection = [lg.scans is None and lg.detections is not None for lg in logs]
    if any(detection) and not all(detection):
        raise UsageError("cross-validate laser logs and detection-level logs separately")
    if adapt is not None and (kind != "robots" or not all(detection)):
        raise UsageError("--adapt applies to --cv robots on detection-level logs")
    if all(detection):
        from calib.detlevel import DetectionCalibConfig

        folds = _detection_folds(logs, kind, config or DetectionCalibConfig(), adapt)
    else:
        from calib.calibrate import CalibrateConfig

        cfg = config or CalibrateConfig()
        if poses != "auto":
            cfg = updated(cfg, {"poses": poses})
        folds = _laser_folds(logs, kind, cfg, landmarks_csv, poses)
    table, summary = summarise(kind, folds)
    summary["logs"] = [lg.name for lg in logs]
    if adapt:
        summary["adapt_s"] = adapt
    return CrossValidation(kind, folds, table, summary)


def plot_folds(cv: CrossValidation, path: Path) -> None:
    """ECE and false-alarm error (with its interval) of every fold row."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    t = cv.table
    labels = [f"{r.fold}\n{r.test}\n{r.profile}" for r in t.itertuples()]
    x = np.arange(len(t))
    fig, (ax, ax2) = plt.subplots(2, 1, figsize=(max(8, 1.1 * len(t)), 8), dpi=100, sharex=True)
    ax.bar(x, t["ece"], color=np.where(t["profile"] == "own", "tab:green", "tab:blue"))
    ax.plot(x, t["ece_if_calibrated"], "k_", ms=18, mew=2, label="ECE a calibrated model would show (noise)")
    ax.set_ylabel("ECE (informative pairs)")
    ax.legend(fontsize=8)
    ax.grid(alpha=0.3, axis="y")
    e = 100 * t["false_alarm_relative_error"].to_numpy(float)
    lo = 100 * t["false_alarm_relative_error_ci95_low"].to_numpy(float)
    hi = 100 * t["false_alarm_relative_error_ci95_high"].to_numpy(float)
    ax2.errorbar(x, e, yerr=[np.maximum(e - lo, 0), np.maximum(hi - e, 0)], fmt="o", capsize=4, color="tab:red")
    ax2.axhline(0, color="k", lw=0.8)
    ax2.axhspan(-5, 5, color="tab:green", alpha=0.15, label="+-5 %")
    ax2.set_ylabel("false alarms: observed / predicted - 1 [%]")
    ax2.legend(fontsize=8)
    ax2.grid(alpha=0.3, axis="y")
    ax2.set_xticks(x, labels, fontsize=7)
    fig.suptitle(f"cross-validation ({cv.kind}): {len(t)} fold rows", fontsize=10)
    fig.tight_layout()
    fig.savefig(path, metadata={"Software": None})
    plt.close(fig)


def write_cv_run(cv: CrossValidation, out: Path, *, overwrite: bool = False) -> list[str]:
    """folds.csv, summary.yaml, folds.png and one reliability figure per fold row."""
    figures = ["folds.png"]
    with atomic_output(out, overwrite=overwrite, directory=True) as tmp:
        tmp.mkdir()
        cv.table.to_csv(tmp / "folds.csv", index=False, float_format="%.9g")
        (tmp / "summary.yaml").write_text(dump_yaml(_plain(cv.summary)))
        plot_folds(cv, tmp / "folds.png")
        for i, f in enumerate(cv.folds):
            name = f"fold{i + 1:02d}_{f.profile}.png"
            plot_reliability(f.validation, tmp / name, title=f"fold {f.fold}: trained on {', '.join(f.train)}; tested on {f.test} ({f.profile} profile)")
            f.validation.pairs.to_csv(tmp / f"fold{i + 1:02d}_{f.profile}_pairs.csv.gz", index=False, float_format="%.9g", compression=GZ)
            figures.append(name)
    return figures
