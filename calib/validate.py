"""``detcal validate PROFILE LOG...``: how well a profile predicts held-out logs with truth.

A profile is only worth exporting if it predicts data it was not fitted to.
The report (:mod:`calib.scoring` for the formulas):

* **P_D** -- every (frame, landmark) pair the sensor could have seen gets the
  profile's prediction (laser: pairs with n_expected > 0, through n_p;
  detection-level: pairs inside the profile's field of view, through range and
  bearing). Pairs predicted exactly 0 are a row of their own (with how many of
  them were detected); the expected calibration error runs over the informative
  pairs, shown with the bin counts and with the ECE binomial noise alone would
  give; the Brier score and the mean log-likelihood per pair;
* **false alarms per frame** -- observed with a 95 % batch-means interval
  against the profile's rate; Pearson's chi-square of the held-out counts
  against the profile's count model (Poisson or negative binomial) and the
  held-out dispersion; the held-out false alarms' mean log density under the
  profile's clutter density beside the uniform one;
* **Hotelling coverage** (laser) -- the share of true detections inside the
  ellipsoid with its interval, against the nominal confidence;
* the frames' own period (the held-out logs', not the training one).

One row per held-out log and one for all of them together.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd

from calib.calibrate import log_landmarks, scan_sensor_poses
from calib.clutter import density_loglik
from calib.config import dump_yaml
from calib.io.atomic import atomic_output
from calib.label import label_log
from calib.scoring import score_counts, score_coverage, score_pd
from detectors.circle import descriptor_matrix, hotelling_maha2
from detectors.sensor_log import SensorLog
from profiles.errors import DataError, UsageError
from profiles.profile import DetectorProfile

GZ = {"method": "gzip", "mtime": 0}
BLOCK_S = 10.0  # pairs of one landmark within this many seconds count as one cluster of correlated outcomes


@dataclass
class Held:
    """What one held-out log gives the scores (any sensor kind)."""

    name: str
    pairs: pd.DataFrame  # at least: predicted, observed, log, landmark, block (10 s of the frame's time)
    counts: np.ndarray  # false alarms per frame (F,)
    fa_range: np.ndarray  # false alarms' range [m] and bearing [rad], sensor frame
    fa_bearing: np.ndarray
    frame_period: float  # [s]
    inside: np.ndarray | None = None  # true detections inside the Hotelling ellipsoid (laser)
    extra: dict = field(default_factory=dict)


@dataclass
class Validation:
    summary: dict
    pairs: pd.DataFrame
    bins: pd.DataFrame
    counts: np.ndarray
    per_log: pd.DataFrame
    profile: DetectorProfile


def _scores(profile: DetectorProfile, hs: list[Held]) -> tuple[dict, pd.DataFrame, pd.DataFrame, np.ndarray]:
    """(summary, reliability table, pairs, counts) of held-out logs taken together."""
    pairs = pd.concat([x.pairs for x in hs], ignore_index=True)
    counts = np.concatenate([x.counts for x in hs])
    cl = pairs.groupby(["log", "landmark", "block"], sort=False).ngroup().to_numpy() if "block" in pairs else None
    s, bins = score_pd(pairs["predicted"].to_numpy(), pairs["observed"].to_numpy(), cl)
    s.update(score_counts(counts, profile.clutter))
    d = profile.clutter.density
    if d is not None:
        r = np.concatenate([x.fa_range for x in hs])
        b = np.concatenate([x.fa_bearing for x in hs])
        dl, n_in = density_loglik(d, r, b)
        s["clutter_density_loglik"] = dl
        s["clutter_density_loglik_uniform"] = float(-np.log((d.range_edges[-1] - d.range_edges[0]) * (d.bearing_edges[-1] - d.bearing_edges[0])))
        s["false_alarms_outside_density_grid"] = int(r.size - n_in)
    ins = [x.inside for x in hs if x.inside is not None]
    if ins:
        s.update(score_coverage(np.concatenate(ins), None if profile.hotelling is None else profile.hotelling.confidence))
    s["frame_period_s"] = float(np.median([x.frame_period for x in hs]))
    for x in hs:  # per-log extras: numbers add up over logs, anything else is listed
        for k, v in x.extra.items():
            if len(hs) == 1:
                s[k] = v
            elif isinstance(v, int | float) and not isinstance(v, bool):
                s[k] = s.get(k, 0) + v
            else:
                s.setdefault(k, []).append(v)
    return s, bins, pairs, counts


def _row(name: str, s: dict) -> dict:
    """One row of the per-log table: scalars as they are, intervals as _low and _high."""
    row = {"log": name}
    for k, v in s.items():
        if isinstance(v, list):
            if len(v) == 2 and all(isinstance(x, float) for x in v):
                row[k + "_low"], row[k + "_high"] = v
        else:
            row[k] = v
    return row


def score(profile: DetectorProfile, held: list[Held], extra: dict | None = None) -> Validation:
    """The validation report of ``profile`` over held-out logs (one row each and all together)."""
    per = [_scores(profile, [h]) for h in held]
    summary, bins, pairs, counts = _scores(profile, held) if len(held) > 1 else per[0]
    per_log = pd.DataFrame([_row(h.name, p[0]) for h, p in zip(held, per, strict=True)] + [_row("all", summary)])
    trained = profile.provenance.parameters.get("frame_period")
    head = {"profile": profile.ref, "logs": [h.name for h in held], "frame_period_training_s": trained}
    return Validation({**head, **summary, **(extra or {})}, pairs, bins, counts, per_log, profile)


# ------------------------------------------------------------------------------------------ laser logs


def held_out_laser(profile: DetectorProfile, log: SensorLog, *, landmarks_csv: Path | None = None, poses: str = "auto") -> Held:
    """Label a laser log with the profile's detector and score what the profile predicts for it."""
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
    observed = det_idx >= 0
    observed[observed] = gated[det_idx[observed]]
    could = pairs["n_expected"].to_numpy() > 0
    t = (log.scans.stamp - log.scans.stamp[0]) / 1e9
    pairs = pairs.assign(
        predicted=profile.pd.lookup(pairs["n_p"].to_numpy()), observed=observed, log=log.name, block=(t[pairs["scan"].to_numpy()] // BLOCK_S).astype(np.int64)
    )[could].reset_index(drop=True)
    fa = dets[gated & ~true]
    counts = np.bincount(fa["scan"].to_numpy(np.int64), minlength=len(log.scans))
    period = float(np.median(np.diff(log.scans.stamp))) / 1e9 if len(log.scans) > 1 else float("nan")
    return Held(
        log.name, pairs, counts, fa["range"].to_numpy(np.float64), fa["bearing"].to_numpy(np.float64), period,
        inside=gated[true], extra={"pose_source": src},
    )


def validate(profile: DetectorProfile, logs: SensorLog | list[SensorLog], *, landmarks_csv: Path | None = None, poses: str = "auto") -> Validation:
    """Score a laser profile on held-out laser logs with truth."""
    if profile.detector.kind != "circle2d":
        raise UsageError(f"profile {profile.ref} is for an external detector, not the circle detector of laser logs")
    logs = [logs] if isinstance(logs, SensorLog) else list(logs)
    return score(profile, [held_out_laser(profile, lg, landmarks_csv=landmarks_csv, poses=poses) for lg in logs])


# ------------------------------------------------------------------------------------------ report


def plot_reliability(v: Validation, path: Path, title: str | None = None) -> None:
    """Reliability diagram (informative pairs, with counts) beside the false alarms per frame against the count model."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    s = v.summary
    b = v.bins
    inf = b.iloc[1:]
    ok = inf["pairs"] > 0
    fig, (ax, ax2) = plt.subplots(1, 2, figsize=(13, 5.4), dpi=100)
    ax.plot([0, 1], [0, 1], "k:", lw=0.8, label="perfect calibration")
    x, y = inf.loc[ok, "predicted"], inf.loc[ok, "observed"]
    err = [np.maximum(y - inf.loc[ok, "observed_low"], 0), np.maximum(inf.loc[ok, "observed_high"] - y, 0)]
    ax.errorbar(x, y, yerr=err, fmt="o-", color="tab:blue", capsize=3, label=f"observed, 95 % Wilson interval (ECE {s['ece']:.4f})")
    for _, row in inf[ok].iterrows():
        ax.annotate(f"{int(row['pairs']):,}", (row["predicted"], row["observed"]), textcoords="offset points", xytext=(5, -11), fontsize=7)
    z = b.iloc[0]
    ax.text(
        0.98, 0.03,
        f"predicted 0: {int(z['pairs']):,} pairs, {int(z['detected']):,} detected\n"
        f"ECE a calibrated model would show: {s['ece_if_calibrated']:.4f}\n"
        f"(independent pairs), {s['ece_if_calibrated_blocks']:.4f} (10 s blocks)\n"
        f"Brier {s['brier']:.4f} (constant rate {s['brier_constant_rate']:.4f})\n"
        f"log-likelihood {s['loglik_per_pair']:.4f} per pair",
        transform=ax.transAxes, ha="right", va="bottom", fontsize=8, bbox={"fc": "white", "ec": "0.7"},
    )
    ax.set_xlim(0, 1)
    ax.set_ylim(0, 1)
    ax.set_xlabel("predicted P_D (bins of 0.1; numbers: pairs)")
    ax.set_ylabel("observed detection rate")
    ax.set_title(f"P_D reliability: {s['pairs_informative']:,} informative pairs of {s['pairs']:,}")
    ax.legend(loc="upper left", fontsize=8)
    ax.grid(alpha=0.3)
    c = v.counts
    kmax = int(c.max()) if c.size else 0
    ks = np.arange(kmax + 1)
    clut = v.profile.clutter
    ax2.bar(ks, np.bincount(c, minlength=kmax + 1), color="tab:gray", label="held-out frames")
    ax2.plot(ks, c.size * clut.count_pmf(ks), "o-", color="tab:red", ms=3, label=f"profile: {clut.count_model.replace('_', ' ')}, mean {clut.rate:.3f}")
    lo, hi = s["false_alarms_per_frame_ci95"]
    ax2.set_title(
        f"false alarms per frame: {s['false_alarms_per_frame_observed']:.3f} [{lo:.3f}, {hi:.3f}] observed, "
        f"error {100 * s['false_alarm_relative_error']:+.1f} %\n"
        f"chi2 {s['clutter_chi2']:.1f} on {s['clutter_chi2_dof']} dof (p = {s['clutter_chi2_p_value']:.2g}), "
        f"dispersion {s['clutter_dispersion']:.2f} (profile {s['clutter_dispersion_profile']:.2f})",
        fontsize=9,
    )
    ax2.set_yscale("log")
    ax2.set_ylim(bottom=0.5)
    ax2.set_xlabel("false alarms in a frame")
    ax2.set_ylabel("frames (log scale)")
    ax2.legend(fontsize=8)
    if title:
        fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    fig.savefig(path, metadata={"Software": None})
    plt.close(fig)


def write_validation_run(v: Validation, out: Path, *, overwrite: bool = False) -> None:
    with atomic_output(out, overwrite=overwrite, directory=True) as tmp:
        tmp.mkdir()
        (tmp / "summary.yaml").write_text(dump_yaml(_plain(v.summary)))
        v.bins.to_csv(tmp / "reliability.csv", index=False, float_format="%.9g")
        v.per_log.to_csv(tmp / "logs.csv", index=False, float_format="%.9g")
        v.pairs.to_csv(tmp / "pairs.csv.gz", index=False, float_format="%.9g", compression=GZ)
        plot_reliability(v, tmp / "reliability.png", title=f"{v.profile.ref} on {', '.join(v.summary['logs'])}")


def _plain(x):
    """Numpy scalars and NaN made YAML-friendly (NaN stays .nan)."""
    if isinstance(x, dict):
        return {k: _plain(v) for k, v in x.items()}
    if isinstance(x, list | tuple):
        return [_plain(v) for v in x]
    if isinstance(x, np.generic):
        return x.item()
    return x
