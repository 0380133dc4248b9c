"""Figures (matplotlib, Agg backend): what a person would rather look at than read."""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from matplotlib.patches import Circle  # noqa: E402

from detectors.circle import CircleDetections  # noqa: E402
from detectors.logs import SensorLog  # noqa: E402
from detectors.raytrace import pd_grid  # noqa: E402
from profiles.schema import PdTable  # noqa: E402

FIELD_RADIUS = 0.1  # hypothetical landmark radius of the P_D field, as in thesis fig. 6.1
PLOT_REACH = 40.0  # metres shown around the sensor
MAX_DRAWN_RADIUS = 3.0  # circles fitted to walls are huge: list them, do not draw them


def plot_scan_detections(log: SensorLog, det: CircleDetections, k: int, table: PdTable, k_sigma: float, path: Path) -> None:
    """One scan in the sensor frame: returns coloured by cluster, fitted circles, and the P_D field."""
    s = log.sensor
    ang = log.scan_angles(k)
    r = log.scans.ranges[k].astype(np.float64)
    x, y = r * np.cos(ang), r * np.sin(ang)
    ok = np.isfinite(x)
    reach = float(np.nanmax(r)) if ok.any() else float(s.range_max or 10.0)
    reach = min(reach, float(s.range_max or reach), PLOT_REACH)
    xs = np.linspace(-reach, reach, 241)
    ys = np.linspace(-reach, reach, 241)
    sigma = s.range_sigma if s.range_sigma is not None else 0.02
    pdf, _ = pd_grid(np.zeros(3), ang, r, xs, ys, FIELD_RADIUS, table.lookup, range_sigma=sigma, k_sigma=k_sigma, range_max=s.range_max)
    fig, ax = plt.subplots(figsize=(9, 8), dpi=100)
    im = ax.imshow(pdf, origin="lower", extent=(xs[0], xs[-1], ys[0], ys[-1]), cmap="viridis", vmin=0, vmax=1, alpha=0.85)
    fig.colorbar(im, ax=ax, shrink=0.8, label=f"P_D of a {FIELD_RADIUS} m landmark ({table.covariate} table)")
    ax.plot(x[ok], y[ok], ".", color="tab:red", ms=2.5, label="returns")
    mine = det.scan == k
    huge = mine & (det.radius > MAX_DRAWN_RADIUS)
    mine &= ~huge
    for cx, cy, cr, a, b in zip(det.x[mine], det.y[mine], det.radius[mine], det.first[mine], det.last[mine], strict=True):
        ax.plot(x[a : b + 1], y[a : b + 1], "-", color="white", lw=2.0)
        ax.add_patch(Circle((cx, cy), cr, fill=False, color="orange", lw=1.5))
    ax.plot([], [], "-", color="white", lw=2, label="clusters")
    ax.plot([], [], "o", mfc="none", color="orange", label=f"fitted circles ({int(mine.sum())}; {int(huge.sum())} over {MAX_DRAWN_RADIUS:g} m not drawn)")
    ax.plot(0, 0, "k^", ms=8, label="sensor")
    ax.set_aspect("equal")
    ax.set_xlim(xs[0], xs[-1])
    ax.set_ylim(ys[0], ys[-1])
    ax.set_xlabel("x [m], sensor frame")
    ax.set_ylabel("y [m]")
    ax.set_title(f"{log.name}: scan {k}")
    ax.legend(loc="lower left", fontsize=8)
    fig.tight_layout()
    fig.savefig(path, metadata={"Software": None})
    plt.close(fig)
