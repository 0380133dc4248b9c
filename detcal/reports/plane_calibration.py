"""The run folder of a plane calibration (``detcal calibrate`` on 3D lidar logs with plane truth) and its figures."""

from __future__ import annotations

import numpy as np

from calib.config import dump_yaml
from calib.planes import PlaneCalibration
from detcal.reports.calibration import plot_clutter
from profiles.store import dump_profile
from detcal.reports.figures import save_figure, wrapped_title


def fill_plane_run(cal: PlaneCalibration, folder) -> list[str]:
    """Create ``folder`` with profile.yaml, config.yaml, summary.yaml, pairs.csv.gz, detections.csv.gz and the
    figures (P_D against visible points, clutter); returns the figure names."""

    folder.mkdir()
    (folder / "profile.yaml").write_text(dump_profile(cal.profile))
    (folder / "config.yaml").write_text(dump_yaml(cal.config.model_dump(mode="json")))
    (folder / "summary.yaml").write_text(dump_yaml(cal.summary))
    gz = {"method": "gzip", "mtime": 0}
    cal.labels.pairs.to_csv(folder / "pairs.csv.gz", index=False, float_format="%.9g", compression=gz)
    cal.labels.detections.to_csv(folder / "detections.csv.gz", index=False, float_format="%.9g", compression=gz)
    plot_pd_points(cal, folder / "pd_vs_points.png")
    plot_clutter(cal, folder / "clutter.png")
    return ["pd_vs_points.png", "clutter.png"]


def plot_pd_points(cal: PlaneCalibration, path) -> None:
    """P_D against expected visible points (log axis) with Wilson intervals, and per incidence band from the grid's raw cells."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    t = cal.profile.pd
    e = np.asarray(t.edges, dtype=np.float64)
    x = np.sqrt(np.maximum(e[:-1], 0.5) * np.maximum(e[1:], 1.0))
    n, k = np.asarray(t.counts), np.asarray(t.detections)
    raw = np.where(n > 0, k / np.maximum(n, 1), np.nan)
    lo, hi = np.asarray(t.wilson_low), np.asarray(t.wilson_high)
    fig, ax = plt.subplots(figsize=(9, 5.5), dpi=100)
    ax.errorbar(x, raw, yerr=[np.maximum(raw - lo, 0), np.maximum(hi - raw, 0)], fmt="o", color="k", capsize=3, label="all incidences, 95 % Wilson")
    g = cal.profile.planes.pd_grid
    if g is not None:
        gn, gk = np.asarray(g.counts), np.asarray(g.detections)
        ae = g.angle_edges_deg
        for j in range(gn.shape[1]):
            ok = gn[:, j] >= 20
            if ok.any():
                ax.plot(x[ok], gk[ok, j] / gn[ok, j], ".-", lw=0.8, label=f"incidence {ae[j]:g}-{ae[j + 1]:g} deg")
    ax.step(np.append(e[:-1], e[-1] * 2), np.append(t.pd, t.pd[-1]), where="post", color="tab:red", lw=1, label="profile table (clamped)")
    ax.set_xscale("symlog", linthresh=1)
    ax.set_ylim(0, 1.05)
    ax.set_xlabel("expected returns on the visible part of the plane (ray-traced n_p)")
    ax.set_ylabel("P_D")
    wrapped_title(ax, f"plane P_D against visible points ({int(n.sum()):,} plane-frame pairs)")
    ax.legend(fontsize=7, loc="lower right")
    ax.grid(alpha=0.3)
    save_figure(fig, path)
