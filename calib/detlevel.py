"""Calibration and validation of detection-level logs with truth (UTIAS MRCLAM's camera).

Such a log carries detections (range, bearing, an identity such as a barcode)
but no raw scans, so P_D cannot go through n_p: it is fitted against range
(thesis eq. 6.2 with the covariate changed). The steps:

* **camera epochs**: the log only lists frames that detected something, so the
  opportunities to detect are rebuilt as a regular grid at the camera's frame
  period (the median gap between consecutive detection frames when gaps under
  0.5 s are considered; 0.24 s on UTIAS), each detection frame snapped to the
  nearest epoch;
* **expected landmarks**: at every epoch the true vehicle pose (Vicon) gives
  each landmark's range and bearing; a landmark is expected when it is inside
  the field of view (|bearing| <= fov / 2, range <= range_max), both estimated
  from the true detections (their 99.5 % quantiles) unless given;
* **labels**: a detection whose identity is a landmark and whose measured
  position is within the gate of that landmark's true position is a true
  detection; every other detection (other robots, unknown barcodes, misplaced
  landmark readings) is a false alarm;
* **fits**: P_D per range bin with Wilson intervals and the clamping rules;
  Poisson clutter per epoch with Pearson's test; kappa over range x bearing.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pandas as pd
from pydantic import BaseModel, ConfigDict, Field

from calib import __version__
from calib.calibrate import created_now
from calib.io.common import index_of
from calib.fits import ClutterFit, PdFitConfig, clutter_params, fit_clutter, fit_pd_table
from calib.validate import Validation, reliability
from detectors.geometry import compose, interpolate_poses
from detectors.logs import SensorLog
from profiles.errors import DataError, UsageError
from profiles.profile import DetectorProfile, DetectorSpec, InputRef, Provenance
from profiles.schema import MeasurementNoise, SensorModel

TARGET_LANDMARK = 1


class DetectionCalibConfig(BaseModel):
    model_config = ConfigDict(extra="forbid")
    gate: float = Field(default=1.0, gt=0.0, description="true detection: within this of the landmark [m]")
    frame_period: float | None = Field(default=None, gt=0.0, description="camera frame period [s] (default: estimated)")
    fov: float | None = Field(default=None, gt=0.0, description="field of view [rad] (default: from the true detections)")
    range_max: float | None = Field(default=None, gt=0.0, description="[m] (default: from the true detections)")
    quantile: float = Field(default=0.995, gt=0.5, lt=1.0)
    # no zero clamp: inside the field of view a low P_D is real, not a sign of being out of view
    # (on UTIAS robots 1-3 -> 4-5 the thesis's clamp below 0.1 raised the ECE from 0.046 to 0.053)
    pd: PdFitConfig = PdFitConfig(min_count=50, range_bin=0.25, zero_below=0.0)


def frame_period(logs: list[SensorLog]) -> float:
    gaps = np.concatenate([np.diff(lg.detections.frame_stamp) / 1e9 for lg in logs])
    gaps = gaps[(gaps > 0.05) & (gaps < 0.5)]
    if gaps.size < 10:
        raise DataError("too few detection frames to estimate the camera's frame period; pass frame_period")
    return float(np.median(gaps))


def _need(log: SensorLog) -> None:
    if log.detections is None:
        raise DataError(f"log {log.name!r} has no detections")
    if log.landmarks is None or "ground_truth" not in log.reference:
        raise DataError(f"log {log.name!r} needs landmark truth and ground-truth poses for a detection-level calibration")
    from calib.truth import check_within_truth

    check_within_truth(log)  # a detection outside the truth's time span would get a clamped, wrong pose
    if "subject" not in log.detections.descriptors:
        raise DataError(f"log {log.name!r}: detections carry no identity (descriptor 'subject')")


def true_detections(log: SensorLog, gate: float) -> pd.DataFrame:
    """One row per detection: range, bearing, frame stamp, landmark index or -1, and whether it is true."""
    d = log.detections
    ref = log.reference["ground_truth"]
    stamp = d.frame_stamp[d.frame]
    pose = interpolate_poses(ref.stamp, ref.poses, stamp)
    m = log.sensor.mount if log.sensor is not None else None
    sp = pose if m is None else compose(pose, np.array([m.x, m.y, m.theta]))
    world = compose(sp, np.column_stack([d.range * np.cos(d.bearing), d.range * np.sin(d.bearing), np.zeros(len(d))]))
    lm = index_of(np.asarray(d.descriptors["subject"], dtype=np.int64), log.landmarks.ids)
    dist = np.where(lm >= 0, np.hypot(*(world[:, :2] - log.landmarks.xy[np.maximum(lm, 0)]).T), np.inf)
    rel = log.landmarks.xy[np.maximum(lm, 0)] - sp[:, :2]
    r_hat = np.hypot(rel[:, 0], rel[:, 1])
    b_hat = np.arctan2(rel[:, 1], rel[:, 0]) - sp[:, 2]
    true = dist <= gate
    return pd.DataFrame(
        {
            "stamp": stamp,
            "range": d.range,
            "bearing": d.bearing,
            "landmark_index": lm,
            "true": true,
            "range_residual": np.where(true, d.range - r_hat, np.nan),
            "bearing_residual": np.where(true, np.mod(d.bearing - b_hat + np.pi, 2 * np.pi) - np.pi, np.nan),
        }
    )


def fit_noise(dets: pd.DataFrame) -> MeasurementNoise | None:
    """Robust spread (1.4826 MAD) and median bias of the true detections' range and bearing residuals."""
    t = dets[dets["true"]]
    if len(t) < 10:
        return None
    out = {}
    for col, key in (("range_residual", "range"), ("bearing_residual", "bearing")):
        x = t[col].to_numpy()
        med = float(np.median(x))
        out[f"{key}_bias"] = med
        out[f"{key}_sigma"] = max(float(1.4826 * np.median(np.abs(x - med))), 1e-6)
    return MeasurementNoise(**out, samples=len(t))


def _epochs(log: SensorLog, period: float) -> tuple[np.ndarray, np.ndarray]:
    fs = log.detections.frame_stamp
    p = int(round(period * 1e9))
    epochs = np.arange(fs[0], fs[-1] + p, p, dtype=np.int64)
    idx = np.clip(np.rint((fs - fs[0]) / p).astype(np.int64), 0, epochs.size - 1)
    return epochs, idx


def label_epochs(log: SensorLog, cfg: DetectionCalibConfig, period: float, fov: float, range_max: float):
    """(pairs, false alarms per epoch): one pair per (epoch, landmark in view) with range, bearing, detected."""
    dets = true_detections(log, cfg.gate)
    epochs, f_epoch = _epochs(log, period)
    d_epoch = f_epoch[log.detections.frame]
    ref = log.reference["ground_truth"]
    pose = interpolate_poses(ref.stamp, ref.poses, epochs)
    m = log.sensor.mount if log.sensor is not None else None
    sp = pose if m is None else compose(pose, np.array([m.x, m.y, m.theta]))
    rel = log.landmarks.xy[None, :, :] - sp[:, None, :2]
    rng = np.hypot(rel[..., 0], rel[..., 1])
    brg = np.mod(np.arctan2(rel[..., 1], rel[..., 0]) - sp[:, None, 2] + np.pi, 2 * np.pi) - np.pi
    view = (np.abs(brg) <= fov / 2) & (rng <= range_max)
    seen = np.zeros(rng.shape, dtype=bool)
    t = dets["true"].to_numpy()
    seen[d_epoch[t], dets["landmark_index"].to_numpy()[t]] = True
    e, lm = np.nonzero(view)
    pairs = pd.DataFrame({"epoch": e, "landmark": log.landmarks.ids[lm], "range": rng[e, lm], "bearing": brg[e, lm], "detected": seen[e, lm]})
    fa = np.bincount(d_epoch[~t], minlength=epochs.size)
    return pairs, fa, dets


@dataclass
class DetectionCalibration:
    profile: DetectorProfile
    pairs: pd.DataFrame
    clutter: ClutterFit
    summary: dict


def calibrate_detections(
    logs: list[SensorLog], cfg: DetectionCalibConfig, *, name: str, version: str, description: str = "", input_refs=None, command: str = ""
) -> DetectionCalibration:
    for lg in logs:
        _need(lg)
    period = cfg.frame_period or frame_period(logs)
    truths = pd.concat([true_detections(lg, cfg.gate) for lg in logs], ignore_index=True)
    tt = truths[truths["true"]]
    if len(tt) < 20:
        raise DataError("fewer than 20 true detections: cannot estimate the field of view")
    fov = cfg.fov or float(2 * np.quantile(np.abs(tt["bearing"]), cfg.quantile))
    rmax = cfg.range_max or float(np.quantile(tt["range"], cfg.quantile))
    parts = [label_epochs(lg, cfg, period, fov, rmax) for lg in logs]
    pairs = pd.concat([p.assign(log=k) for k, (p, _, _) in enumerate(parts)], ignore_index=True)
    counts = np.concatenate([fa for _, fa, _ in parts])
    table = fit_pd_table(pairs["range"].to_numpy(), pairs["detected"].to_numpy(), "range", cfg.pd)
    clut = fit_clutter(counts)
    sensor = SensorModel(kind="camera", fov=fov, range_max=rmax, mount=logs[0].sensor.mount if logs[0].sensor else SensorModel().mount)
    profile = DetectorProfile(
        name=name,
        version=version,
        description=description,
        detector=DetectorSpec(kind="external", association_gate=cfg.gate),
        sensor=sensor,
        pd=table,
        clutter=clutter_params(clut, "range_bearing", fov * rmax),
        noise=fit_noise(truths),
        provenance=Provenance(
            inputs=input_refs or [],
            detcal_version=__version__,
            command=command,
            parameters={**cfg.model_dump(mode="json"), "frame_period": period},
            created=created_now(),
        ),
    )
    summary = {
        "logs": [lg.name for lg in logs],
        "frame_period_s": period,
        "epochs": int(counts.size),
        "fov_deg": float(np.degrees(fov)),
        "range_max_m": rmax,
        "true_detections": int(sum(int(d["true"].sum()) for _, _, d in parts)),
        "false_detections": int(counts.sum()),
        "landmark_epoch_pairs": len(pairs),
        "pd_overall": float(pairs["detected"].mean()),
        "clutter_rate_per_epoch": clut.rate,
        "clutter_p_value": clut.p_value,
        "clutter_dispersion": clut.dispersion,
    }
    return DetectionCalibration(profile, pairs, clut, summary)


def validate_detections(profile: DetectorProfile, logs: list[SensorLog]) -> Validation:
    if profile.pd.covariate != "range":
        raise UsageError(f"profile {profile.ref} has a {profile.pd.covariate} P_D table; a detection-level log needs a range table")
    for lg in logs:
        _need(lg)
    period = float(profile.provenance.parameters.get("frame_period") or frame_period(logs))
    cfg = DetectionCalibConfig(gate=profile.detector.association_gate)
    fov, rmax = profile.sensor.fov, profile.sensor.range_max
    if fov is None or rmax is None:
        raise DataError(f"profile {profile.ref}: the sensor has no fov or range_max")
    parts = [label_epochs(lg, cfg, period, fov, rmax) for lg in logs]
    pairs = pd.concat([p.assign(log=k) for k, (p, _, _) in enumerate(parts)], ignore_index=True)
    counts = np.concatenate([fa for _, fa, _ in parts])
    pred = profile.pd.lookup(pairs["range"].to_numpy())
    obs = pairs["detected"].to_numpy()
    ece, bins = reliability(pred, obs)
    pairs = pairs.assign(predicted=pred, observed=obs)
    rate = float(counts.mean())
    summary = {
        "profile": profile.ref,
        "logs": [lg.name for lg in logs],
        "epochs": int(counts.size),
        "pairs_in_view": len(pairs),
        "ece": ece,
        "detections_observed": int(obs.sum()),
        "detections_predicted": float(pred.sum()),
        "false_alarms_per_scan_observed": rate,
        "false_alarms_per_scan_predicted": profile.clutter.rate,
        "false_alarm_relative_error": (rate - profile.clutter.rate) / profile.clutter.rate if profile.clutter.rate > 0 else float("nan"),
    }
    return Validation(summary, pairs, bins, counts)


def input_refs_for(log: SensorLog) -> list[InputRef]:
    files = log.source.get("files")
    if isinstance(files, dict):
        return [InputRef(name=str(k), sha256=str(v)) for k, v in files.items()]
    return []


def write_detection_run(cal: DetectionCalibration, out, *, overwrite: bool = False) -> list[str]:
    from calib.io.atomic import atomic_output

    with atomic_output(out, overwrite=overwrite, directory=True) as tmp:
        return fill_detection_run(cal, tmp)


def fill_detection_run(cal: DetectionCalibration, folder) -> list[str]:
    """Create ``folder`` with profile.yaml, summary.yaml, pairs.csv.gz and the figures; returns the figure names."""
    from calib.config import dump_yaml
    from calib.report import plot_clutter, plot_pd
    from profiles.store import dump_profile

    folder.mkdir()
    (folder / "profile.yaml").write_text(dump_profile(cal.profile))
    (folder / "summary.yaml").write_text(dump_yaml(cal.summary))
    cal.pairs.to_csv(folder / "pairs.csv.gz", index=False, float_format="%.9g", compression={"method": "gzip", "mtime": 0})
    plot_pd(cal, folder / "pd_vs_range.png")
    plot_clutter(cal, folder / "clutter.png")
    return ["pd_vs_range.png", "clutter.png"]
