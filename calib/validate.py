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
import textwrap
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd

from calib.calibrate import log_landmarks, scan_sensor_poses
from calib.clutter import density_loglik
from calib.drift import PARTS, DriftConfig, DriftReport, RowDrift, decide, row_drift
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
    # one row per true detection for the drift tests (calib.drift.row_drift): cluster (log/landmark) and
    # log_mse, inside (laser) or range_residual, bearing_residual (detection-level)
    truth: pd.DataFrame | None = None


@dataclass
class Validation:
    summary: dict
    pairs: pd.DataFrame
    bins: pd.DataFrame
    counts: np.ndarray
    per_log: pd.DataFrame
    profile: DetectorProfile
    drift: DriftReport | None = None


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


def drift_rows(profile: DetectorProfile, held: list[Held], cfg: DriftConfig, per_log: list[RowDrift] | None = None) -> list[RowDrift]:
    """The drift tests' rows: one per held-out log (key = its place + 1; ``per_log`` when they were computed
    already, where the logs were labelled) and, for several, all together (key 0)."""
    rows = per_log if per_log is not None else [drift_row(profile, [h], h.name, k + 1, cfg) for k, h in enumerate(held)]
    return ([drift_row(profile, held, "all", 0, cfg)] if len(held) > 1 else []) + rows


def drift_row(profile: DetectorProfile, hs: list[Held], name: str, key: int, cfg: DriftConfig) -> RowDrift:
    """The raw drift tests of ``profile`` on held-out logs taken together (:func:`calib.drift.row_drift`)."""
    truths = [h.truth for h in hs if h.truth is not None]
    return row_drift(
        profile, pd.concat([h.pairs for h in hs], ignore_index=True), np.concatenate([h.counts for h in hs]),
        pd.concat(truths, ignore_index=True) if truths else None, name, key, cfg,
    )


def score(
    profile: DetectorProfile, held: list[Held], extra: dict | None = None, drift: DriftConfig | None = None, rows: list[RowDrift] | None = None
) -> Validation:
    """The validation report of ``profile`` over held-out logs (one row each and all together), with the
    drift verdicts (:mod:`calib.drift`; ``drift`` its settings, defaults when None; ``rows`` the per-log
    rows when computed already)."""
    per = [_scores(profile, [h]) for h in held]
    summary, bins, pairs, counts = _scores(profile, held) if len(held) > 1 else per[0]
    report = decide(drift_rows(profile, held, drift or DriftConfig(), rows), drift or DriftConfig())
    verdicts = report.table().set_index("log")
    rows = [_row(h.name, p[0]) for h, p in zip(held, per, strict=True)] + [_row("all", summary)]
    for r in rows:
        name = r["log"] if r["log"] in verdicts.index else (held[0].name if len(held) == 1 else None)
        if name is not None:
            r.update(verdicts.loc[name].to_dict())
    per_log = pd.DataFrame(rows)
    trained = profile.provenance.parameters.get("frame_period")
    head = {"profile": profile.ref, "logs": [h.name for h in held], "frame_period_training_s": trained}
    first = report.rows[0]  # all logs together, or the one log
    flat = {"verdict": report.verdict, "drift": first.headline}
    for k in PARTS:
        part = first.parts.get(k)
        flat[f"{k}_verdict"] = part.verdict if part else "not tested"
        flat[f"{k}_p_value"] = part.p_value if part else float("nan")
        flat[f"{k}_p_adjusted"] = part.p_adjusted if part else float("nan")
    return Validation({**head, **flat, **summary, **(extra or {})}, pairs, bins, counts, per_log, profile, report)


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
    t_dets = dets[true]
    truth = pd.DataFrame(
        {
            "cluster": log.name + "/" + t_dets["landmark"].astype(str).to_numpy(),
            "log_mse": descriptor_matrix(t_dets["fit_error"], t_dets["radius"], t_dets["convexity"], t_dets["points"], ("log_mse",))[:, 0],
            "inside": gated[true],
        }
    )
    return Held(
        log.name, pairs, counts, fa["range"].to_numpy(np.float64), fa["bearing"].to_numpy(np.float64), period,
        inside=gated[true], extra={"pose_source": src}, truth=truth,
    )


def held_and_row(log: SensorLog, profile: DetectorProfile, key: int, drift: DriftConfig, landmarks_csv: Path | None, poses: str) -> tuple[Held, RowDrift]:
    """One laser log's share of a validation, where the log is: its labelled pairs and counts, and its own drift
    tests (row ``key``); the task :func:`validate` hands to ``per_log``."""
    h = held_out_laser(profile, log, landmarks_csv=landmarks_csv, poses=poses)
    return h, drift_row(profile, [h], h.name, key, drift)


def validate(
    profile: DetectorProfile,
    logs: SensorLog | list[SensorLog],
    *,
    landmarks_csv: Path | None = None,
    poses: str = "auto",
    drift: DriftConfig | None = None,
    per_log=None,
) -> Validation:
    """Score a laser profile on held-out laser logs with truth, with the drift verdicts.

    per_log: how the per-log work (labelling, each log's drift tests) runs,
    ``per_log(fn, [(log, *args), ...]) -> [fn(log, *args), ...]`` (as for
    :func:`calib.calibrate.calibrate`; :mod:`calib.engine` runs them on Dask
    workers); the pooled row and the verdicts are computed here, so the result
    does not depend on where the logs were done.
    """
    if profile.detector.kind != "circle2d":
        raise UsageError(f"profile {profile.ref} is for an external detector, not the circle detector of laser logs")
    logs = [logs] if isinstance(logs, SensorLog) else list(logs)
    cfg = drift or DriftConfig()
    each = per_log or (lambda fn, args: [fn(*a) for a in args])
    done = each(held_and_row, [(lg, profile, k + 1, cfg, landmarks_csv, poses) for k, lg in enumerate(logs)])
    return score(profile, [h for h, _ in done], drift=cfg, rows=[r for _, r in done])


# ------------------------------------------------------------------------------------------ report


def _band_panel(ax, b: pd.DataFrame, x: np.ndarray, xlabel: str, title: str, ticks: list[str] | None = None) -> None:
    """Observed detection rate per bin (points, pairs as numbers) against the profile's (line) with the bootstrap
    bands: each bin alone (shaded) and, for tested bins, all of them at once (dashed: the max-T test's)."""
    ok = (b["pairs"] > 0).to_numpy()
    b, x = b[ok], x[ok]
    step = "mid" if ticks else None
    ax.fill_between(x, b["band_low"], b["band_high"], color="tab:orange", alpha=0.25, step=step, label="95 % of a right profile, each bin (bootstrap)")
    ax.plot(x, b["expected"], "-", color="tab:orange", lw=1.2, drawstyle="steps-mid" if ticks else "default", label="profile")
    tested = b["band_all_low"].notna().to_numpy()
    if tested.any():
        for col in ("band_all_low", "band_all_high"):
            ax.plot(x[tested], b[col][tested], "--", color="tab:brown", lw=1.0, drawstyle="steps-mid" if ticks else "default",
                    label="95 % of a right profile, all tested bins at once" if col == "band_all_low" else None)
    lo = np.where(tested, b["band_all_low"], b["band_low"])
    hi = np.where(tested, b["band_all_high"], b["band_high"])
    out = ((b["observed"] < lo) | (b["observed"] > hi)).to_numpy()
    ax.plot(x[~out], b["observed"][~out], "o", color="tab:blue", ms=5, label="observed")
    ax.plot(x[out], b["observed"][out], "o", color="tab:red", ms=6, label="observed, outside the band" + (" (all at once)" if tested.any() else ""))
    for xi, row in zip(x, b.itertuples(), strict=True):
        ax.annotate(f"{int(row.pairs):,}", (xi, row.observed), textcoords="offset points", xytext=(4, -10), fontsize=6, color="0.3")
    if ticks is not None:
        ax.set_xticks(x, [t for t, k in zip(ticks, ok, strict=True) if k], rotation=40, ha="right", fontsize=7)
    ys = np.concatenate([b["observed"], b["band_low"], b["band_high"], b["band_all_low"], b["band_all_high"]]).astype(float)
    ys = ys[np.isfinite(ys)]
    if ys.size:
        pad = 0.08 * max(float(ys.max() - ys.min()), 0.02)
        ax.set_ylim(max(float(ys.min()) - pad, -0.02), min(float(ys.max()) + pad, 1.02))
    ax.set_xlabel(xlabel)
    ax.set_ylabel("detection rate")
    ax.set_title(textwrap.fill(title, 80), fontsize=8)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7, loc="best")


def _part_title(row: RowDrift | None, part: str) -> str:
    p = row.parts.get(part) if row is not None else None
    if p is None:
        why = row.missing.get(part, "no drift tests") if row is not None else "no drift tests"
        return f"not tested ({why})"
    return f"{p.verdict} (p = {p.p_value:.3g}, adjusted {p.p_adjusted:.3g}): {p.text}"


def plot_reliability(v: Validation, path: Path, title: str | None = None, row: int = 0) -> None:
    """The validation report's figure: where the log departs from what a right profile would give.

    Four panels, each with the bootstrap band of :mod:`calib.drift` (95 % of what
    this log's own opportunities would show if the profile were right, its own
    sampling error included): P_D per cell of the profile (the tested bins; a
    reliability diagram for a range x bearing grid), P_D over range and over
    bearing (for the eye: an n_p profile's misfit along range is in the band's
    centre too), and the false alarms per frame against the count model.
    ``row``: which drift row (0: all logs together when there are several).
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    s = v.summary
    r = v.drift.rows[row] if v.drift is not None else None
    fig, axes = plt.subplots(2, 2, figsize=(13, 9.5), dpi=100)
    ax, ax_r, ax_b, ax2 = axes.ravel()
    bins = r.pd_bins if r is not None else None
    if bins is not None:
        cells = bins[bins["family"] == "cell"]
        if len(cells) <= 24:
            _band_panel(ax, cells.reset_index(drop=True), np.arange(len(cells), dtype=float), "cell of the profile's P_D table",
                        "P_D per cell (tested): " + _part_title(r, "pd"), ticks=cells["label"].tolist())
        else:
            rel = bins[bins["family"] == "predicted"].reset_index(drop=True)
            ax.plot([0, 1], [0, 1], "k:", lw=0.8)
            _band_panel(ax, rel, rel["predicted"].to_numpy(float), "predicted P_D (bins of 0.1)", f"P_D ({len(cells)} cells, shown by prediction): " + _part_title(r, "pd"))
            ax.set_xlim(0, 1)
        for fam, axx, unit in (("range", ax_r, "m"), ("bearing", ax_b, "deg")):
            f = bins[bins["family"] == fam].reset_index(drop=True)
            centre = (f["low"].to_numpy(float) + f["high"].to_numpy(float)) / 2
            if fam == "bearing":
                centre = np.degrees(centre)
            tested = bool(f["tested"].any())
            _band_panel(axx, f, centre, f"{fam} [{unit}] (bins: {'equal pair counts' if fam == 'range' else 'equal widths'})",
                        f"P_D over {fam} ({'tested with the cells' if tested else 'shown, not tested: an n_p table'})")
        z = v.bins.iloc[0]
        ax.set_title(
            ax.get_title() + f"\npredicted 0: {int(z['pairs']):,} pairs, {int(z['detected']):,} detected; ECE {s['ece']:.4f} "
            f"(a calibrated model: {s['ece_if_calibrated_blocks']:.4f})", fontsize=8,
        )
    else:
        for axx in (ax, ax_r, ax_b):
            axx.text(0.5, 0.5, "P_D: " + _part_title(r, "pd"), ha="center", va="center", transform=axx.transAxes, fontsize=8)
    h = r.clutter_hist if r is not None else None
    if h is not None:
        ks = h["count"].to_numpy()
        ax2.bar(ks, h["frames"], color="tab:gray", label="frames of this log")
        ax2.plot(ks, h["expected"], "o", color="tab:red", ms=3, label=f"profile: {v.profile.clutter.count_model.replace('_', ' ')}, mean {v.profile.clutter.rate:.3g}")
        ax2.vlines(ks, np.maximum(h["band_low"], 0.5), np.maximum(h["band_high"], 0.5), color="tab:red", alpha=0.45, lw=4,
                   label="95 % of a right profile (bootstrap: this log's frames and autocorrelation)")
        ax2.set_yscale("log")
        ax2.set_ylim(bottom=0.5)
        ax2.set_xlabel(f"false alarms in a frame (the last bar: {int(ks[-1])} or more)")
        ax2.set_ylabel("frames (log scale)")
        ax2.legend(fontsize=7)
    ax2.set_title(textwrap.fill("false alarms per frame: " + _part_title(r, "clutter"), 80), fontsize=8)
    lines = [title or f"{v.profile.ref} on {', '.join(s['logs'])}"]
    if r is not None:
        lines.append(textwrap.fill(f"{r.name}: {r.headline}", 160))
        lines += [f"{k}: {_part_title(r, k)}" for k in ("noise", "coverage")]
    fig.suptitle("\n".join(lines), fontsize=9)
    fig.tight_layout()
    fig.savefig(path, metadata={"Software": None})
    plt.close(fig)


def write_validation_run(v: Validation, out: Path, *, overwrite: bool = False) -> list[str]:
    """The validation run folder: summary.yaml (with every drift test), logs.csv (one row per log and one for
    all, with the verdicts), parts.csv (each part's score beside its sampling floor, p-values and verdict, per row), reliability.csv, pairs.csv.gz, drift_bins.csv and clutter_counts.csv (the bootstrap
    bands), reliability.png (all logs together, or the one log) and with several logs one figure per log;
    returns the figure names."""
    with atomic_output(out, overwrite=overwrite, directory=True) as tmp:
        tmp.mkdir()
        return fill_validation_run(v, tmp)


def fill_validation_run(v: Validation, tmp: Path) -> list[str]:
    """Write the files of :func:`write_validation_run` into the existing folder ``tmp``."""
    (tmp / "summary.yaml").write_text(dump_yaml(_plain({**v.summary, **({"drift_tests": v.drift.summary()} if v.drift else {})})))
    v.bins.to_csv(tmp / "reliability.csv", index=False, float_format="%.9g")
    v.per_log.to_csv(tmp / "logs.csv", index=False, float_format="%.9g")
    v.pairs.to_csv(tmp / "pairs.csv.gz", index=False, float_format="%.9g", compression=GZ)
    figures = ["reliability.png"]
    plot_reliability(v, tmp / "reliability.png", title=f"{v.profile.ref} on {', '.join(v.summary['logs'])}")
    if v.drift is not None:
        rows = v.drift.rows
        bins = [r.pd_bins.assign(row=r.name) for r in rows if r.pd_bins is not None]
        hists = [r.clutter_hist.assign(row=r.name) for r in rows if r.clutter_hist is not None]
        if bins:
            pd.concat(bins, ignore_index=True).to_csv(tmp / "drift_bins.csv", index=False, float_format="%.9g")
        if hists:
            pd.concat(hists, ignore_index=True).to_csv(tmp / "clutter_counts.csv", index=False, float_format="%.9g")
        v.drift.parts().to_csv(tmp / "parts.csv", index=False, float_format="%.9g")
        if len(rows) > 1:
            for k, r in enumerate(rows[1:], start=1):
                name = f"reliability_{_safe(r.name)}.png"
                plot_reliability(v, tmp / name, title=f"{v.profile.ref} on {r.name}", row=k)
                figures.append(name)
    return figures


def _safe(name: str) -> str:
    """A log name made safe for a file name."""
    return "".join(c if c.isalnum() or c in "._-" else "_" for c in name)


def _plain(x):
    """Numpy scalars and NaN made YAML-friendly (NaN stays .nan)."""
    if isinstance(x, dict):
        return {k: _plain(v) for k, v in x.items()}
    if isinstance(x, list | tuple):
        return [_plain(v) for v in x]
    if isinstance(x, np.generic):
        return x.item()
    return x
