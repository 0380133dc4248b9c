"""The run folder of ``detcal slam run``: tables, metrics, the config used, and figures (matplotlib, Agg).

Layout::

    config.yaml       filter settings, profile reference, seed, the input files and their sha256
    metrics.yaml      trajectory RMSE (filter, weighted mean, dead reckoning), map OSPA/GOSPA, timings
    trajectory.csv    stamp_ns, best particle x/y/theta, weighted mean x/y/theta, dead reckoning x/y/theta
    map.csv           x, y, weight of the map estimate (components of weight >= map_threshold)
    steps.csv         stamp_ns, ms, measurements, ess, resampled, components, and what the hooks recorded (map_ospa;
                      for the labelled filters hypotheses and map_labels)
    labels.csv        labelled filters: one row per span of a label in the best particle's map estimate (its birth
                      step and measurement, first and last step, whether it ended: track births and deaths)
    trajectory_map.png, ospa.png, timing.png, hypotheses.png (labelled filters: hypotheses per particle, labels,
                      births and deaths per step)

Everything is written into a temporary folder that is renamed into place, so a
failed run leaves nothing behind. Tables use fixed formats: the same inputs
and seed give the same bytes (the timings and the ``ms`` column aside).
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np

from calib.config import dump_yaml_ordered
from detectors.geometry import compose, interpolate_poses, rigid_transform
from detectors.sensor_log import SensorLog
from profiles.atomic import atomic_output
from slam_runtime.run import SlamResult
from detcal.reports.figures import wrapped_title


def _table(path: Path, header: list[str], cols: list[np.ndarray], fmts: list[str]) -> None:
    rows = [",".join(header)]
    for vals in zip(*cols, strict=True):
        rows.append(",".join(f % v for f, v in zip(fmts, vals, strict=True)))
    path.write_text("\n".join(rows) + "\n")


def write_slam_run(log: SensorLog, res: SlamResult, out: Path, config: dict, *, overwrite: bool = False, labels=None) -> list[str]:
    """Write the run folder; returns the figure names. ``labels``: the run's
    :class:`slam_runtime.labels.LabelHistory` (labelled filters), written as ``labels.csv``."""
    with atomic_output(out, overwrite=overwrite, directory=True) as tmp:
        tmp.mkdir()
        (tmp / "config.yaml").write_text(dump_yaml_ordered(config))
        (tmp / "metrics.yaml").write_text(dump_yaml_ordered({k: (float(v) if isinstance(v, np.floating) else v) for k, v in res.metrics.items()}))
        odo = res.odometry if res.odometry is not None else np.full_like(res.trajectory, np.nan)
        _table(
            tmp / "trajectory.csv",
            ["stamp_ns", "x", "y", "theta", "mean_x", "mean_y", "mean_theta", "odometry_x", "odometry_y", "odometry_theta"],
            [res.stamps, *res.trajectory.T, *res.mean_trajectory.T, *odo.T],
            ["%d"] + ["%.6f"] * 9,
        )
        cols = ["x", "y"] if res.map_xy.shape[1] == 2 else ["L_nx", "L_ny", "L_nz", "d"]  # planes: the metric's embedding
        _table(tmp / "map.csv", [*cols, "weight"], [*res.map_xy.reshape(-1, len(cols)).T, res.map_w], ["%.6f"] * (len(cols) + 1))
        hooks = sorted(res.per_step)
        _table(
            tmp / "steps.csv",
            ["stamp_ns", "ms", "measurements", "ess", "resampled", "components", *hooks],
            [res.stamps, res.step_ms, res.n_measurements, res.ess, res.resampled.astype(int), res.components, *(res.per_step[h] for h in hooks)],
            ["%d", "%.3f", "%d", "%.4f", "%d", "%.2f"] + ["%.6f"] * len(hooks),
        )
        figures = _figures(log, res, odo, tmp)
        if labels is not None and "hypotheses" in res.per_step and np.isfinite(res.per_step["hypotheses"]).any():
            header, cols, fmts = labels.table(res.stamps)
            _table(tmp / "labels.csv", header, cols, fmts)
            figures.append(_hypotheses_figure(res, labels, tmp))
    return figures


def _hypotheses_figure(res: SlamResult, labels, folder: Path) -> str:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    t = (res.stamps - res.stamps[0]) / 1e9
    fig, ax = plt.subplots(2, 1, figsize=(7, 5), sharex=True)
    ax[0].plot(t, res.per_step["hypotheses"], "k-", lw=0.8, label="hypotheses per particle (mean)")
    ax[0].plot(t, res.components, "b-", lw=0.8, label="tracks per particle (mean)")
    ax[0].set_yscale("symlog", linthresh=10)
    ax[0].legend(fontsize=7)
    ax[0].grid(alpha=0.3)
    n = res.per_step.get("map_labels")
    if n is not None:
        ax[1].plot(t, n, "k-", lw=0.8, label="labels in the map estimate")
    b, d = labels.births(), labels.deaths()
    if b.size:
        ax[1].plot(t[b], np.zeros(b.size), "g|", ms=10, label=f"births ({b.size})")
    d = d[d < t.size]
    if d.size:
        ax[1].plot(t[d], np.zeros(d.size), "r|", ms=14, label=f"deaths ({d.size})")
    ax[1].set_xlabel("time [s]")
    ax[1].set_ylabel("labels")
    ax[1].legend(fontsize=7)
    ax[1].grid(alpha=0.3)
    wrapped_title(ax[0], f"{res.filter}: hypotheses and the best particle's labelled map", fontsize=9)
    fig.tight_layout()
    fig.savefig(folder / "hypotheses.png", dpi=110)
    plt.close(fig)
    return "hypotheses.png"


def _figures(log: SensorLog, res: SlamResult, odo: np.ndarray, folder: Path) -> list[str]:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    names = []
    fig, ax = plt.subplots(figsize=(8, 7))
    gt = log.reference.get("ground_truth")
    gps = log.reference.get("gps")
    if gt is not None:
        t = interpolate_poses(gt.stamp, gt.poses, res.stamps[(res.stamps >= gt.stamp[0]) & (res.stamps <= gt.stamp[-1])])
        ax.plot(t[:, 0], t[:, 1], "k-", lw=1.2, label="ground truth")
    elif gps is not None and "trajectory_rmse_vs_gps_m" in res.metrics:
        # the estimates are drawn in the GPS frame, moved by the rigid fit the metric used, and the paths at the
        # point of the vehicle the GPS locates (as the metric compares them)
        sel = (gps.stamp >= res.stamps[0]) & (gps.stamp <= res.stamps[-1])
        tf = rigid_transform(gps.at_point(interpolate_poses(res.stamps, res.trajectory, gps.stamp[sel])), gps.poses[sel])
        res = replace(
            res,
            trajectory=compose(tf, gps.at_point(res.trajectory)),
            mean_trajectory=compose(tf, gps.at_point(res.mean_trajectory)),
            map_xy=compose(tf, np.column_stack([res.map_xy, np.zeros(len(res.map_xy))]))[:, :2] if res.map_xy.size else res.map_xy,
        )
        odo = compose(tf, gps.at_point(odo)) if np.isfinite(odo).all() else odo
        ax.plot(gps.poses[sel, 0], gps.poses[sel, 1], "k.", ms=2, label="GPS (estimates rigidly aligned to it)")
    if np.isfinite(odo).all():
        ax.plot(odo[:, 0], odo[:, 1], "r--", lw=0.8, label="dead reckoning")
    ax.plot(res.mean_trajectory[:, 0], res.mean_trajectory[:, 1], "c-", lw=0.6, alpha=0.7, label="weighted mean")
    ax.plot(res.trajectory[:, 0], res.trajectory[:, 1], "b-", lw=1.0, label="best particle")
    if log.landmarks is not None:
        ax.plot(log.landmarks.xy[:, 0], log.landmarks.xy[:, 1], "k*", ms=6, label="true landmarks")
    if res.map_xy.ndim == 2 and res.map_xy.shape[1] == 4:
        draw_planes(ax, log, res.map_xy, res.trajectory)
    elif res.map_xy.size:
        ax.scatter(res.map_xy[:, 0], res.map_xy[:, 1], s=18, facecolors="none", edgecolors="g", label="map (weight >= threshold)")
    ax.set_aspect("equal")
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    title = f"{log.name}: {res.filter}-SLAM"
    m = res.metrics
    for key in ("ground_truth", "gps"):
        if f"trajectory_rmse_vs_{key}_m" in m:
            title += f"\nRMSE vs {key}: {m[f'trajectory_rmse_vs_{key}_m']:.2f} m (dead reckoning {m[f'odometry_rmse_vs_{key}_m']:.2f} m)"
    wrapped_title(ax, title, fontsize=9)
    ax.legend(fontsize=7, loc="best")
    fig.tight_layout()
    fig.savefig(folder / "trajectory_map.png", dpi=110)
    plt.close(fig)
    names.append("trajectory_map.png")

    t = (res.stamps - res.stamps[0]) / 1e9
    osp = res.per_step.get("map_ospa")
    if osp is not None and np.isfinite(osp).any():
        fig, ax = plt.subplots(figsize=(7, 3.5))
        ok = np.isfinite(osp)
        ax.plot(t[ok], osp[ok], "b-")
        ax.set_xlabel("time [s]")
        ax.set_ylabel(f"map OSPA (c = {m.get('ospa_c_m', 1.0)} m, p = {m.get('ospa_p', 1.0)})")
        ax.set_ylim(0, m.get("ospa_c_m", 1.0) * 1.05)
        ax.grid(alpha=0.3)
        fig.tight_layout()
        fig.savefig(folder / "ospa.png", dpi=110)
        plt.close(fig)
        names.append("ospa.png")

    fig, ax = plt.subplots(figsize=(7, 3.5))
    # log axis: the step that first uses a compiled kernel includes its compilation (seconds), which on a linear axis
    # would flatten every other step (milliseconds)
    ms = np.maximum(res.step_ms, 1e-3)
    ax.semilogy(t, ms, "k-", lw=0.5)
    if ms.size:
        k = int(np.argmax(ms))
        ax.semilogy(t[k:k + 1], ms[k:k + 1], "ro", ms=4, label=f"slowest step: {ms[k]:.0f} ms (compiles kernels on first use)")
        ax.legend(fontsize=7, loc="upper right")
    ax.set_xlabel("time [s]")
    ax.set_ylabel("filter ms per step (log axis)")
    split = ", ".join(f"{k} {v / max(res.stamps.size, 1):.2f}" for k, v in res.stage_ms.items())
    wrapped_title(ax, f"median {np.median(res.step_ms):.1f} ms per step, mean {res.step_ms.mean():.1f} ms (with the compilation)\n"
                  f"per stage [ms/step]: {split}", fontsize=8)  # fmt: skip
    ax.grid(alpha=0.3, which="both")
    fig.tight_layout()
    fig.savefig(folder / "timing.png", dpi=110)
    plt.close(fig)
    names.append("timing.png")
    return names
def draw_planes(ax, log: SensorLog, est: np.ndarray, trajectory: np.ndarray, reach: float = 30.0) -> None:
    """Top view: the true landmark planes' outlines and each mapped plane's trace near the trajectory."""
    pl = log.planes
    if pl is not None:
        steep = np.abs(pl.normal[:, 2]) <= np.sin(np.radians(45.0))
        for i in np.flatnonzero(steep):
            v = pl.polygon(int(i))
            ax.plot(v[:, 0], v[:, 1], "-", color="0.6", lw=0.8, label="true planes" if i == np.flatnonzero(steep)[0] else None)
    est = np.asarray(est, dtype=np.float64).reshape(-1, 4)
    if not est.size:
        return
    lo, hi = trajectory[:, :2].min(0) - reach, trajectory[:, :2].max(0) + reach
    t = np.linspace(-np.hypot(*(hi - lo)), np.hypot(*(hi - lo)), 2000)
    first = True
    for e in est:
        n = e[:3] / max(np.linalg.norm(e[:3]), 1e-12)
        h = np.hypot(n[0], n[1])
        if h < 0.3:
            continue
        foot = np.array([n[0], n[1]]) / h**2 * e[3]  # where the plane crosses z = 0, nearest the origin
        pts = foot + t[:, None] * np.array([-n[1], n[0]]) / h
        near = np.min(np.hypot(*(pts[:, None, :] - trajectory[None, ::10, :2]).transpose(2, 0, 1)), axis=1) <= reach
        if near.any():
            ax.plot(pts[near, 0], pts[near, 1], "g.", ms=1.2, label="mapped planes (traces)" if first else None)
            first = False
