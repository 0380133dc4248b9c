"""The run folder of a laser calibration (``detcal calibrate``) and the report's figures, a person would rather
look at than read; the figure functions serve the detection-level and plane calibrations' folders too."""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from matplotlib.patches import Circle  # noqa: E402
import pandas as pd  # noqa: E402
from scipy.stats import nbinom, poisson  # noqa: E402

from calib.calibrate import Calibration  # noqa: E402
from calib.config import dump_yaml  # noqa: E402
from detcal.reports.detect import plot_scan_detections  # noqa: E402
from detectors.circle import descriptor_matrix  # noqa: E402
from profiles.store import dump_profile  # noqa: E402

GZ = {"method": "gzip", "mtime": 0}  # fixed header time: same tables, same bytes
SAVE = {"metadata": {"Software": None}}


def _save(fig, path: Path) -> None:
    fig.tight_layout()
    fig.savefig(path, **SAVE)
    plt.close(fig)


def plot_pd(cal: Calibration, path: Path) -> None:
    """P_D against n_p: raw estimate with 95 % Wilson intervals, the clamped table, counts."""
    t = cal.profile.pd
    e = np.asarray(t.edges)
    x = e[:-1]
    n = np.asarray(t.counts)
    k = np.asarray(t.detections)
    raw = np.where(n > 0, k / np.maximum(n, 1), np.nan)
    lo, hi = np.asarray(t.wilson_low), np.asarray(t.wilson_high)
    fig, ax = plt.subplots(figsize=(9, 5.5), dpi=100)
    ax.errorbar(x, raw, yerr=[np.maximum(raw - lo, 0), np.maximum(hi - raw, 0)], fmt="o", color="tab:blue", capsize=3, label="estimate, 95 % Wilson interval")
    ax.step(np.append(x, x[-1] + 1), np.append(t.pd, t.pd[-1]), where="post", color="tab:red", label="profile table (clamped)")
    for xi, ni in zip(x, n, strict=True):
        ax.annotate(f"{ni:,}", (xi, 1.02), ha="center", fontsize=7, rotation=90, va="bottom", annotation_clip=False)
    ax.set_ylim(0, 1.15)
    ax.set_xlabel(f"{t.covariate} (last bin: {t.covariate} >= {x[-1]:g})")
    ax.set_ylabel("P_D")
    ax.set_title(f"P_D against {t.covariate} (numbers: pairs per bin)", pad=28)
    ax.legend(loc="lower right")
    ax.grid(alpha=0.3)
    _save(fig, path)


def plot_roc(cal: Calibration, path: Path) -> None:
    fig, ax = plt.subplots(figsize=(6.5, 6), dpi=100)
    for key, color, label in (("hotelling", "tab:red", "Hotelling ellipsoid"), ("fisher", "tab:blue", "Fisher's linear discriminant")):
        fpr, tpr = cal.roc[key]
        ax.plot(fpr, tpr, color=color, label=f"{label} (AUC {cal.roc['auc_' + key]:.4f})")
    ax.plot([0, 1], [0, 1], "k:", lw=0.8)
    ax.set_xlabel("false-alarm rate (share of false detections kept)")
    ax.set_ylabel("detection rate (share of true detections kept)")
    ax.set_title("ROC of the false-alarm reduction (in-sample)")
    ax.legend(loc="lower right")
    ax.grid(alpha=0.3)
    _save(fig, path)


def plot_clutter(cal, path: Path) -> None:
    """False alarms per frame: histogram, the Poisson fit and (when chosen) the negative binomial, with the tests."""
    c = cal.clutter
    counts = c.counts
    kmax = int(counts.max()) if counts.size else 0
    ks = np.arange(kmax + 1)
    fig, ax = plt.subplots(figsize=(8, 5), dpi=100)
    ax.bar(ks, np.bincount(counts, minlength=kmax + 1), color="tab:gray", label="frames")
    ax.plot(ks, counts.size * poisson.pmf(ks, c.rate), "o-", color="tab:red", ms=4, label=f"Poisson, lambda = {c.rate:.3f}")
    if c.size is not None:
        r = c.size
        ax.plot(ks, counts.size * nbinom.pmf(ks, r, r / (r + c.rate)), "s-", color="tab:blue", ms=4, label=f"negative binomial, r = {r:.3g}")
    verdict = "rejected" if np.isfinite(c.p_value) and c.p_value < 0.05 else "not rejected"
    disp = c.dispersion_test
    line2 = (
        f"dispersion {c.dispersion:.2f}; negative binomial vs Poisson: LR = {disp.statistic:.1f}, p = {disp.p_value:.3g} -> {c.count_model.replace('_', ' ')}"
        if disp is not None
        else f"dispersion {c.dispersion:.2f}"
    )
    ax.set_title(f"false alarms per frame: Poisson chi2 = {c.chi2:.1f} on {c.dof} dof, p = {c.p_value:.3g} ({verdict} at 0.05)\n{line2}", fontsize=9)
    ax.set_xlabel("false alarms in a frame")
    ax.set_ylabel("frames")
    ax.legend()
    _save(fig, path)


def plot_pd_grid(table, pairs, path: Path) -> None:
    """A range x bearing P_D table: the grid, and observed rates against range and bearing beside the model's."""
    from calib.pdmodels import predict

    e, be = np.asarray(table.edges), np.asarray(table.bearing_edges)
    pdv = np.asarray(table.pd)
    fig, axes = plt.subplots(1, 3, figsize=(16, 4.8), dpi=100)
    ax = axes[0]
    shown_e = np.append(e[:-1], e[-2] + 2 * (e[-1] - e[-2]))  # the last row is open-ended: drawn twice as deep
    m = ax.pcolormesh(np.degrees(be), shown_e, pdv, cmap="viridis", vmin=0, vmax=max(0.05, float(pdv.max())), shading="flat")
    fig.colorbar(m, ax=ax, label="P_D")
    ax.set_xlabel("bearing [deg] (sensor frame, left positive)")
    ax.set_ylabel("range [m]")
    sel = table.selection
    ax.set_title(f"P_D model: {table.model}" + (f" (held-out choice over {sel.folds})" if sel else ""), fontsize=9)
    pred = predict(table, pairs)
    y = pairs["detected"].to_numpy(float)
    for ax, col, edges, unit, scale in ((axes[1], "range", e, "range [m]", 1.0), (axes[2], "bearing", be, "bearing [deg]", np.degrees(1.0))):
        v = pairs[col].to_numpy()
        i = np.clip(np.searchsorted(edges, v, side="right") - 1, 0, edges.size - 2)
        n = np.bincount(i, minlength=edges.size - 1)
        k = np.bincount(i, weights=y, minlength=edges.size - 1)
        p = np.bincount(i, weights=pred, minlength=edges.size - 1)
        mid = (edges[:-1] + edges[1:]) / 2 * scale
        ok = n > 0
        with np.errstate(invalid="ignore", divide="ignore"):
            ax.plot(mid[ok], (k / n)[ok], "o", color="tab:blue", label="observed")
            ax.plot(mid[ok], (p / n)[ok], "-", color="tab:red", label="model (mean over the same pairs)")
        ax.set_xlabel(unit)
        ax.set_ylabel("detection rate")
        ax.set_ylim(0, 1)
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
    if sel:
        txt = ", ".join(f"{c} {ll:.4f}" for c, ll in zip(sel.candidates, sel.loglik, strict=True))
        fig.suptitle(f"held-out log-likelihood per pair: {txt} -> {sel.chosen}", fontsize=9)
    _save(fig, path)


def plot_clutter_density(clutter, path: Path) -> None:
    """Where false alarms fall: the profile's clutter density over range x bearing (with the calibration counts)."""
    d = clutter.density
    re_, be = np.asarray(d.range_edges), np.asarray(d.bearing_edges)
    dens = np.asarray(d.density) * clutter.rate  # intensity kappa(z)
    fig, ax = plt.subplots(figsize=(8, 5.5), dpi=100)
    m = ax.pcolormesh(np.degrees(be), re_, dens, cmap="magma", shading="flat")
    fig.colorbar(m, ax=ax, label="kappa(z) [false alarms / (m rad frame)]")
    if d.counts is not None and np.asarray(d.counts).size <= 400:
        c = np.asarray(d.counts)
        for i in range(c.shape[0]):
            for j in range(c.shape[1]):
                ax.text(np.degrees((be[j] + be[j + 1]) / 2), (re_[i] + re_[i + 1]) / 2, str(c[i, j]), ha="center", va="center", fontsize=6, color="cyan")
    sel = d.selection
    title = "clutter intensity over the measurement space"
    if sel:
        parts = [f"{c} {v:.3f}" for c, v in zip(sel.candidates, sel.loglik, strict=True)]
        lines = [", ".join(parts[i : i + 3]) for i in range(0, len(parts), 3)]
        title += f"\nheld-out mean log density per false alarm ({sel.folds}):\n" + "\n".join(lines) + f"\n-> {sel.chosen}"
    ax.set_title(title, fontsize=9)
    ax.set_xlabel("bearing [deg] (sensor frame)")
    ax.set_ylabel("range [m]")
    _save(fig, path)


def plot_sensors(cal, path: Path) -> None:
    """Per sensor: observed P_D against range beside the pooled model's prediction for the same pairs; clutter rates."""
    from calib.clutter import batch_means_ci
    from calib.pdmodels import predict

    pairs = cal.pairs
    table = cal.profile.pd
    pred = predict(table, pairs)
    edges = np.asarray(table.edges)
    fig, (ax, ax2) = plt.subplots(1, 2, figsize=(14, 5), dpi=100)
    colors = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    for s, name in enumerate(cal.names):
        w = pairs["log"].to_numpy() == s
        v = pairs.loc[w, "range"].to_numpy()
        i = np.clip(np.searchsorted(edges, v, side="right") - 1, 0, edges.size - 2)
        n = np.bincount(i, minlength=edges.size - 1)
        k = np.bincount(i, weights=pairs.loc[w, "detected"].to_numpy(float), minlength=edges.size - 1)
        p = np.bincount(i, weights=pred[w], minlength=edges.size - 1)
        ok = n >= 20
        mid = (edges[:-1] + edges[1:]) / 2
        col = colors[s % len(colors)]
        ax.plot(mid[ok], k[ok] / n[ok], "o-", color=col, ms=3, label=f"{name} observed")
        ax.plot(mid[ok], p[ok] / n[ok], ":", color=col)
    ax.set_xlabel("range [m]")
    ax.set_ylabel("detection rate (dotted: pooled model on the same pairs)")
    sp = cal.profile.sensors
    ax.set_title(
        f"P_D per sensor; between-sensor sd {sp.pd_between_sd:.3f} (logit offsets sd {sp.pd_logit_sd:.2f}"
        + (f", cells m = {sp.pd_concentration:.3g})" if sp.pd_concentration else ")"),
        fontsize=9,
    )
    ax.set_ylim(0, 1)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7, ncol=2)
    mids, los, his = [], [], []
    for lab in cal.labelled:
        m, lo, hi = batch_means_ci(lab.counts)
        mids.append(m), los.append(m - lo), his.append(hi - m)
    x = np.arange(len(cal.names))
    ax2.bar(x, mids, yerr=[los, his], color="tab:gray", capsize=4, label="per sensor, 95 % batch-means interval")
    ax2.axhline(cal.profile.clutter.rate, color="tab:red", label=f"pooled {cal.profile.clutter.rate:.3f}")
    ax2.set_xticks(x, cal.names)
    ax2.set_ylabel("false alarms per frame")
    ax2.set_title(f"clutter per sensor; between-sensor sd {sp.clutter_between_sd:.3f}", fontsize=9)
    ax2.legend(fontsize=8)
    _save(fig, path)


def _ellipse(mean2, cov2, gamma, n=200):
    w, v = np.linalg.eigh(cov2)
    t = np.linspace(0, 2 * np.pi, n)
    circ = np.stack([np.cos(t), np.sin(t)])
    return (v @ (np.sqrt(np.maximum(w, 0) * gamma)[:, None] * circ)).T + mean2


def plot_descriptors(cal: Calibration, path: Path, max_points: int = 4000) -> None:
    """Every pair of descriptors: true vs false detections and the ellipsoid's projection (at gamma)."""
    d = cal.labelled.detections
    h = cal.hotelling
    names = list(h.names)
    x = descriptor_matrix(d["fit_error"], d["radius"], d["convexity"], d["points"], names)
    true = d["landmark"].to_numpy() >= 0
    fin = np.isfinite(x).all(axis=1)
    rng = np.random.default_rng(0)  # subsample for legibility, reproducibly
    pick_t = np.flatnonzero(true & fin)
    pick_f = np.flatnonzero(~true & fin)
    pick_t = rng.permutation(pick_t)[:max_points]
    pick_f = rng.permutation(pick_f)[:max_points]
    pairs = [(i, j) for i in range(len(names)) for j in range(i + 1, len(names))] or [(0, 0)]
    fig, axes = plt.subplots(1, len(pairs), figsize=(5.2 * len(pairs), 5), dpi=100, squeeze=False)
    for ax, (i, j) in zip(axes[0], pairs, strict=True):
        ax.plot(x[pick_f, i], x[pick_f, j], ".", ms=2, color="tab:gray", alpha=0.5, label="false")
        ax.plot(x[pick_t, i], x[pick_t, j], ".", ms=2, color="tab:green", alpha=0.5, label="true")
        if i != j:
            sub = np.ix_([i, j], [i, j])
            el = _ellipse(h.mean[[i, j]], h.cov[sub], h.gamma)
            ax.plot(el[:, 0], el[:, 1], "r-", lw=1.5, label=f"{h.confidence:g} ellipsoid")
            lo = np.percentile(x[pick_t][:, [i, j]], 0.5, axis=0)
            hi = np.percentile(x[pick_t][:, [i, j]], 99.5, axis=0)
            pad = (hi - lo) * 1.5
            ax.set_xlim(min(lo[0] - pad[0], el[:, 0].min()), max(hi[0] + pad[0], el[:, 0].max()))
            ax.set_ylim(min(lo[1] - pad[1], el[:, 1].min()), max(hi[1] + pad[1], el[:, 1].max()))
        ax.set_xlabel(names[i])
        ax.set_ylabel(names[j])
        ax.legend(loc="best", fontsize=8, markerscale=4)
    fig.suptitle(f"descriptors of {int(true.sum()):,} true and {int((~true).sum()):,} false detections")
    _save(fig, path)


def plot_map(cal: Calibration, path: Path, k: int = 0, every: int = 10) -> None:
    """The registered point cloud of log k with the sensor trajectory and the landmarks; an ICP ground truth's
    failing stretches (:attr:`calib.gtquality.QualityReport.failing`) in magenta and its verdict in the title."""
    lg, sp = cal.logs[k], cal.poses[k]
    rows = np.arange(0, len(lg.scans), every)
    ang = lg.scan_angles(rows)
    r = lg.scans.ranges[rows].astype(np.float64)
    a = sp[rows, 2:3] + (ang if ang.ndim == 2 else ang[None, :])
    x = sp[rows, 0:1] + r * np.cos(a)
    y = sp[rows, 1:2] + r * np.sin(a)
    ok = np.isfinite(x)
    ids, xy, rad = cal.landmarks[k]
    fig, ax = plt.subplots(figsize=(10, 8), dpi=100)
    ax.plot(x[ok], y[ok], ",", color="tab:gray", alpha=0.6)
    for c, rr in zip(xy, rad, strict=True):
        ax.add_patch(Circle(c, max(rr, 0.3), fill=False, color="tab:green", lw=0.8))
    ax.plot(sp[:, 0], sp[:, 1], "b-", lw=1, label=f"sensor trajectory ({cal.summary['pose_source'][k]})")
    quality = cal.ground_truth[k] if k < len(cal.ground_truth) else None
    verdict = ""
    if quality is not None:
        if quality.failing.any():
            p = np.where(quality.failing[:, None], sp[:, :2], np.nan)
            ax.plot(p[:, 0], p[:, 1], "-", color="m", lw=3, alpha=0.8, label=f"ground truth failing here ({len(quality.stretches)} stretches)")
        verdict = "\nground truth passes its checks" if quality.verdict.passed else "\nground truth FAILS: " + quality.verdict.failures[0].describe()
    ax.plot([], [], "o", mfc="none", color="tab:green", label="landmarks")
    ax.set_aspect("equal")
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.set_title(f"{lg.name}: registered scans (every {every}th) and landmarks{verdict}", fontsize=10)
    ax.legend(loc="upper right")
    _save(fig, path)


def write_report(cal: Calibration, folder: Path) -> list[str]:
    from detectors.circle import detect_circles

    plot_pd(cal, folder / "pd_vs_np.png")
    plot_roc(cal, folder / "roc.png")
    plot_clutter(cal, folder / "clutter.png")
    plot_descriptors(cal, folder / "descriptors.png")
    plot_map(cal, folder / "map.png")
    lg = cal.logs[0]
    k = len(lg.scans) // 3
    prof = cal.profile
    det = detect_circles(lg.scans.ranges[k : k + 1], lg.scan_angles(k), prof.detector.circle, prof.hotelling, lg.sensor.range_sigma)
    plot_scan_detections(lg, det.offset(k), k, prof.pd, prof.detector.k_sigma, folder / "pd_field.png")
    return ["pd_vs_np.png", "roc.png", "clutter.png", "descriptors.png", "map.png", "pd_field.png"]


def fill_calibration_run(cal: Calibration, folder: Path) -> list[str]:
    """Create ``folder`` with profile.yaml, config.yaml, summary.yaml, quality.yaml (the checks behind the gate),
    ground_truth/<log>/ (an ICP ground truth's keyframes.csv and loops.csv), detections.csv.gz, pairs.csv.gz,
    range_noise.csv (when sigma_r was estimated) and the report figures; returns the figure names."""
    folder.mkdir()
    (folder / "profile.yaml").write_text(dump_profile(cal.profile))
    (folder / "config.yaml").write_text(dump_yaml(cal.config.model_dump(mode="json")))
    (folder / "summary.yaml").write_text(dump_yaml(cal.summary))
    write_checks(cal, folder)
    cal.labelled.detections.to_csv(folder / "detections.csv.gz", index=False, float_format="%.9g", compression=GZ)
    cal.labelled.pairs.to_csv(folder / "pairs.csv.gz", index=False, float_format="%.9g", compression=GZ)
    if cal.range_noise is not None:
        pd.DataFrame(cal.range_noise.summary()["bands"]).to_csv(folder / "range_noise.csv", index=False, float_format="%.6g")
    return write_report(cal, folder)


def write_checks(cal: Calibration, folder: Path) -> None:
    """quality.yaml: the data sufficiency verdict and, per log, its pose source and an ICP ground truth's quality
    report (figures, thresholds, failing stretches); ground_truth/<log>/ holds that report's tables."""
    from calib.groundtruth import write_quality_tables

    logs = {}
    for lg, src, q in zip(cal.logs, cal.summary["pose_source"], cal.ground_truth or [None] * len(cal.logs), strict=True):
        logs[lg.name] = {"pose_source": src, **({"ground_truth": q.as_dict()} if q is not None else {})}
        if q is not None:
            sub = folder / "ground_truth" / lg.name
            sub.mkdir(parents=True)
            write_quality_tables(sub, q)
    doc = {**({"data_sufficiency": cal.data.as_dict()} if cal.data is not None else {}), "logs": logs}
    if cal.summary.get("accepted_poor"):
        doc["accepted_poor"] = cal.summary["accepted_poor"]
    (folder / "quality.yaml").write_text(dump_yaml(doc))
