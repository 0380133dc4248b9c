"""The calibration report: figures a person would rather look at than read."""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from matplotlib.patches import Circle  # noqa: E402
from scipy.stats import poisson  # noqa: E402

from calib.calibrate import Calibration  # noqa: E402
from detectors.circle import descriptor_matrix  # noqa: E402

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


def plot_clutter(cal: Calibration, path: Path) -> None:
    c = cal.clutter
    counts = c.counts
    kmax = int(counts.max()) if counts.size else 0
    ks = np.arange(kmax + 1)
    fig, ax = plt.subplots(figsize=(8, 5), dpi=100)
    ax.bar(ks, np.bincount(counts, minlength=kmax + 1), color="tab:gray", label="scans")
    ax.plot(ks, counts.size * poisson.pmf(ks, c.rate), "o-", color="tab:red", label=f"Poisson, lambda = {c.rate:.3f}")
    verdict = "rejected" if np.isfinite(c.p_value) and c.p_value < 0.05 else "not rejected"
    ax.set_title(
        f"false alarms per scan: chi2 = {c.chi2:.1f} on {c.dof} dof, p = {c.p_value:.3g} (Poisson {verdict} at 0.05), "
        f"dispersion {c.dispersion:.2f}",
        fontsize=9,
    )
    ax.set_xlabel("false alarms in a scan (after the Hotelling gate)")
    ax.set_ylabel("scans")
    ax.legend()
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
    """The registered point cloud of log k with the sensor trajectory and the landmarks."""
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
    ax.plot([], [], "o", mfc="none", color="tab:green", label="landmarks")
    ax.set_aspect("equal")
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.set_title(f"{lg.name}: registered scans (every {every}th) and landmarks")
    ax.legend(loc="upper right")
    _save(fig, path)


def write_report(cal: Calibration, folder: Path) -> list[str]:
    from calib.plots import plot_scan_detections
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
