"""``detcal validate PROFILE LOG``: how well a profile predicts a held-out log with truth.

* reliability of the P_D model: every (scan, landmark) pair the sensor could
  have hit (n_expected > 0) gets the profile's predicted P_D; pairs are binned
  by prediction (10 equal bins) and the expected calibration error is
  ECE = sum_b (n_b / N) |observed rate_b - mean prediction_b|; the same over all
  pairs in range is reported beside it (it is smaller, flattered by the many
  out-of-view pairs predicted and observed at 0);
* false alarms per scan: observed (gated detections not of a landmark) against
  the profile's lambda;
* Hotelling coverage: the share of true detections inside the ellipsoid.
"""

from __future__ import annotations

import dataclasses

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from calib.calibrate import log_landmarks, scan_sensor_poses
from calib.config import dump_yaml
from calib.io.atomic import atomic_output
from calib.label import label_log
from detectors.circle import descriptor_matrix, hotelling_maha2
from detectors.logs import SensorLog
from profiles.errors import DataError, UsageError
from profiles.profile import DetectorProfile

N_BINS = 10


@dataclass
class Validation:
    summary: dict
    pairs: pd.DataFrame
    bins: pd.DataFrame
    counts: np.ndarray


def reliability(pred: np.ndarray, obs: np.ndarray, n_bins: int = N_BINS) -> tuple[float, pd.DataFrame]:
    """(ECE, per-bin table) of predictions in [0, 1] against 0/1 outcomes."""
    pred = np.asarray(pred, dtype=np.float64)
    obs = np.asarray(obs, dtype=np.float64)
    b = np.clip((pred * n_bins).astype(np.int64), 0, n_bins - 1)
    n = np.bincount(b, minlength=n_bins)
    sp = np.bincount(b, weights=pred, minlength=n_bins)
    so = np.bincount(b, weights=obs, minlength=n_bins)
    with np.errstate(invalid="ignore", divide="ignore"):
        table = pd.DataFrame({"low": np.arange(n_bins) / n_bins, "high": np.arange(1, n_bins + 1) / n_bins, "pairs": n, "predicted": sp / n, "observed": so / n})
    ece = float(np.nansum(n / max(1, n.sum()) * np.abs(table["observed"] - table["predicted"])))
    return ece, table


def validate(profile: DetectorProfile, log: SensorLog, *, landmarks_csv: Path | None = None, poses: str = "auto") -> Validation:
    if profile.detector.kind != "circle2d":
        raise UsageError(f"profile {profile.ref} is for an external detector, not the circle detector of laser logs")
    if log.scans is None or log.sensor is None:
        raise DataError(f"log {log.name!r} has no laser scans")
    s, ps = log.sensor, profile.sensor
    if s.layouts() != ps.layouts():
        raise UsageError(f"log {log.name!r} has another beam geometry than profile {profile.ref}")
    if s.range_sigma is None:  # a real log rarely states its noise: the profile's is the one it was calibrated with
        log = dataclasses.replace(log, sensor=type(s).model_validate({**s.model_dump(), "range_sigma": ps.range_sigma}))
    sp, src = scan_sensor_poses(log, poses)
    ids, xy, r = log_landmarks(log, landmarks_csv, sp, profile.detector.circle)
    lab = label_log(log, sp, ids, xy, r, profile.detector.circle, gate=profile.detector.association_gate, k_sigma=profile.detector.k_sigma)
    dets, pairs = lab.detections, lab.pairs
    h = profile.hotelling
    if h is None:
        gated = np.ones(len(dets), dtype=bool)
    else:
        desc = descriptor_matrix(dets["fit_error"], dets["radius"], dets["convexity"], dets["points"], h.names)
        gated = hotelling_maha2(desc, h) <= h.gamma
    true = dets["landmark"].to_numpy() >= 0
    det_idx = pairs["det"].to_numpy()
    observed = (det_idx >= 0) & gated[np.maximum(det_idx, 0)]
    predicted = profile.pd.lookup(pairs["n_p"].to_numpy())
    pairs = pairs.assign(predicted=predicted, observed=observed)
    could = pairs["n_expected"].to_numpy() > 0
    ece, bins = reliability(predicted[could], observed[could])
    ece_all, _ = reliability(predicted, observed)
    fa = dets.loc[gated & ~true, "scan"].to_numpy(np.int64)
    counts = np.bincount(fa, minlength=len(log.scans))
    obs_rate = float(counts.mean())
    pred_rate = profile.clutter.rate
    summary = {
        "profile": profile.ref,
        "log": log.name,
        "pose_source": src,
        "scans": len(log.scans),
        "pairs_could_hit": int(could.sum()),
        "ece": ece,
        "ece_all_pairs_in_range": ece_all,
        "detections_observed": int(observed.sum()),
        "detections_predicted": float(predicted.sum()),
        "false_alarms_per_scan_observed": obs_rate,
        "false_alarms_per_scan_predicted": pred_rate,
        "false_alarm_relative_error": (obs_rate - pred_rate) / pred_rate if pred_rate > 0 else float("nan"),
        "true_detections": int(true.sum()),
        "hotelling_coverage": float(gated[true].mean()) if true.any() else float("nan"),
        "hotelling_confidence": None if h is None else h.confidence,
    }
    return Validation(summary, pairs, bins, counts)


def plot_reliability(v: Validation, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    b = v.bins
    fig, (ax, ax2) = plt.subplots(1, 2, figsize=(12, 5.2), dpi=100)
    ok = b["pairs"] > 0
    ax.plot([0, 1], [0, 1], "k:", lw=0.8, label="perfect calibration")
    ax.plot(b.loc[ok, "predicted"], b.loc[ok, "observed"], "o-", color="tab:blue", label=f"observed (ECE {v.summary['ece']:.4f})")
    for _, row in b[ok].iterrows():
        ax.annotate(f"{int(row['pairs']):,}", (row["predicted"], row["observed"]), textcoords="offset points", xytext=(4, -10), fontsize=7)
    ax.set_xlabel("predicted P_D")
    ax.set_ylabel("observed detection rate")
    ax.set_title("reliability of the P_D model (pairs the sensor could hit)")
    ax.legend(loc="upper left")
    ax.grid(alpha=0.3)
    kmax = int(v.counts.max()) if v.counts.size else 0
    ks = np.arange(kmax + 1)
    from scipy.stats import poisson

    ax2.bar(ks, np.bincount(v.counts, minlength=kmax + 1), color="tab:gray", label="observed scans")
    lam = v.summary["false_alarms_per_scan_predicted"]
    ax2.plot(ks, v.counts.size * poisson.pmf(ks, lam), "o-", color="tab:red", label=f"predicted Poisson, lambda = {lam:.3f}")
    ax2.set_title(f"false alarms per scan: observed mean {v.summary['false_alarms_per_scan_observed']:.3f}")
    ax2.set_xlabel("false alarms in a scan")
    ax2.legend()
    fig.tight_layout()
    fig.savefig(path, metadata={"Software": None})
    plt.close(fig)


def write_validation_run(v: Validation, out: Path, *, overwrite: bool = False) -> None:
    with atomic_output(out, overwrite=overwrite, directory=True) as tmp:
        tmp.mkdir()
        (tmp / "summary.yaml").write_text(dump_yaml(v.summary))
        v.bins.to_csv(tmp / "reliability.csv", index=False, float_format="%.9g")
        v.pairs.to_csv(tmp / "pairs.csv.gz", index=False, float_format="%.9g", compression={"method": "gzip", "mtime": 0})
        plot_reliability(v, tmp / "reliability.png")
