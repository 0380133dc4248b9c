"""``detcal detect`` on point clouds: the plane detector over every cloud of a log.

The run folder holds ``planes.csv`` (one row per plane: frame, time [s], plane
index, normal, offset [m], azimuth and elevation [rad], their standard
deviations and the offset's from the fit covariance, inliers, residual sigma
[m], area [m^2] of the convex outline, width [m] of the enclosing rectangle;
sensor frame), ``outlines.csv`` (frame, plane, vertex, x, y, z: the convex
outlines), ``config.yaml``, ``summary.yaml`` (planes per frame, ms per frame)
and, with ``plot_frame``, ``planes_<k>.png`` (a top view of the segmented
planes over the cloud) and, when the log has poses (truth, else odometry),
``transition_<k>.png``: the planes of frame k-1 carried to frame k by the
plane transition (eq. 35) beside those segmented at k, with the paper's area,
vertex-distance and normal-angle table (``transition_<k>.csv``).
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np
import pandas as pd
from pydantic import BaseModel, ConfigDict

from calib.config import dump_yaml
from calib.io.atomic import atomic_output
from calib.progress import progress
from detectors.logs import SensorLog
from detectors.plane import PlaneDetections, detect_planes
from profiles.errors import DataError, UsageError
from profiles.planes import PlaneDetectorParams


class PlaneDetectConfig(BaseModel):
    """What ``detcal detect --config`` reads for point clouds."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)
    detector: PlaneDetectorParams = PlaneDetectorParams()


def plane_detect_config(profile_ref: str | None, config: Path | None) -> PlaneDetectConfig:
    """The detector settings of ``detcal detect`` on clouds: a lidar3d-planes profile's detector, or a config file."""
    from calib.config import load_yaml_model
    from profiles.errors import UsageError

    if profile_ref is None:
        return load_yaml_model(PlaneDetectConfig, config)
    if config is not None:
        raise UsageError("--profile and --config both set the detector; give one")
    from profiles.store import resolve

    prof = resolve(profile_ref)
    if prof.detector.kind != "plane3d":
        raise UsageError(f"profile {prof.ref} is a {prof.kind} profile; point clouds need a lidar3d-planes one")
    return PlaneDetectConfig(detector=prof.detector.plane)


def run_plane_detector(log: SensorLog, params: PlaneDetectorParams, *, show_progress: bool = True) -> tuple[PlaneDetections, np.ndarray]:
    """Planes of every cloud of ``log`` and the ms each frame took (F,)."""
    if log.clouds is None:
        raise DataError(f"log {log.name!r} has no point clouds to detect planes in")
    n = len(log.clouds)
    it = progress(range(n), n, "detecting planes") if show_progress else range(n)
    parts, ms = [], np.zeros(n)
    for k in it:  # one cloud at a time; the detector is vectorised inside
        t0 = time.perf_counter()
        d = detect_planes(log.clouds.frame(k), params, where=f"{log.name}: cloud {k}")
        ms[k] = (time.perf_counter() - t0) * 1e3
        parts.append(d.with_frame(k))
    return PlaneDetections.concat(parts), ms


def planes_table(log: SensorLog, det: PlaneDetections) -> pd.DataFrame:
    sd = np.sqrt(np.maximum(np.diagonal(det.cov, axis1=1, axis2=2), 0.0)) if len(det) else np.zeros((0, 3))
    per = np.bincount(det.frame, minlength=len(log.clouds))
    first = np.concatenate([[0], np.cumsum(per)])[det.frame]
    return pd.DataFrame(
        {
            "frame": det.frame, "time": log.clouds.stamp[det.frame] / 1e9, "plane": np.arange(len(det)) - first, "sensor_frame": "sensor",
            "nx": det.normal[:, 0], "ny": det.normal[:, 1], "nz": det.normal[:, 2], "offset": det.offset,
            "azimuth": det.chart[:, 0], "elevation": det.chart[:, 1],
            "sd_azimuth": sd[:, 0], "sd_elevation": sd[:, 1], "sd_offset": sd[:, 2],
            "inliers": det.inliers, "sigma": det.sigma, "area": det.area, "width": det.width,
        }
    )


def outlines_table(det: PlaneDetections, table: pd.DataFrame) -> pd.DataFrame:
    counts = np.diff(det.outline_offsets)
    return pd.DataFrame(
        {
            "frame": np.repeat(det.frame, counts), "plane": np.repeat(table["plane"].to_numpy(), counts),
            "vertex": np.arange(det.outline.shape[0]) - np.repeat(det.outline_offsets[:-1], counts),
            "x": det.outline[:, 0], "y": det.outline[:, 1], "z": det.outline[:, 2],
        }
    )


def frame_sensor_poses(log: SensorLog) -> tuple[np.ndarray | None, str]:
    """(F, 3) sensor poses at the clouds (ground truth, else dead-reckoned speed and yaw-rate odometry), and their source."""
    from detectors.geometry import compose, interpolate_poses

    m = log.sensor.mount if log.sensor is not None else None
    mount = np.zeros(3) if m is None else np.array([m.x, m.y, m.theta])
    ref = log.reference.get("ground_truth")
    st = log.clouds.stamp
    if ref is not None and ref.stamp[0] <= st[0] and st[-1] <= ref.stamp[-1]:
        return compose(interpolate_poses(ref.stamp, ref.poses, st), mount), "ground truth"
    o = log.odometry
    if o is not None and o.kind == "velocity" and o.stamp[0] <= st[0]:
        t = o.stamp / 1e9
        pose = np.zeros((o.stamp.size, 3))
        for i in range(1, o.stamp.size):  # dead reckoning, sequential by nature
            v, w = o.values[i - 1]
            dt = t[i] - t[i - 1]
            th = pose[i - 1, 2]
            pose[i] = pose[i - 1] + np.array([v * dt * np.cos(th + w * dt / 2), v * dt * np.sin(th + w * dt / 2), w * dt])
        return compose(interpolate_poses(o.stamp, pose, st), mount), "odometry"
    return None, "none"


def write_plane_detect_run(
    log: SensorLog, cfg: PlaneDetectConfig, out: Path, *, plot_frame: int | None = None, overwrite: bool = False
) -> dict:
    if log.clouds is None:
        raise DataError(f"log {log.name!r} has no point clouds to detect planes in")
    if plot_frame is not None and not 0 <= plot_frame < len(log.clouds):
        raise UsageError(f"--plot: frame {plot_frame} is outside the log (0..{len(log.clouds) - 1})")
    det, ms = run_plane_detector(log, cfg.detector)
    table = planes_table(log, det)
    per = np.bincount(det.frame, minlength=len(log.clouds))
    pts = np.diff(log.clouds.offsets)
    summary = {
        "log": log.name,
        "frames": len(log.clouds),
        "points_per_frame_mean": float(pts.mean()),
        "planes": len(det),
        "planes_per_frame": [int(x) for x in per] if per.size <= 20 else f"min {per.min()}, median {np.median(per):g}, max {per.max()}",
        "planes_per_frame_mean": float(per.mean()),
        "ms_per_frame_mean": float(ms.mean()),
        "ms_per_frame_median": float(np.median(ms)),
        "labelled_share_of_points": float(det.inliers.sum() / max(1, pts.sum())),
    }
    with atomic_output(out, overwrite=overwrite, directory=True) as tmp:
        tmp.mkdir()
        table.to_csv(tmp / "planes.csv", index=False, float_format="%.9g")
        outlines_table(det, table).to_csv(tmp / "outlines.csv", index=False, float_format="%.6f")
        (tmp / "config.yaml").write_text(dump_yaml(cfg.model_dump(mode="json")))
        if plot_frame is not None:
            plot_planes_top(log, plot_frame, cfg.detector, tmp / f"planes_{plot_frame:05d}.png")
            poses, src = frame_sensor_poses(log) if log.sensor is not None and log.sensor.lidar is not None else (None, "none")
            if poses is not None and plot_frame > 0:
                pairs = plot_transition(log, det, poses, plot_frame, src, tmp / f"transition_{plot_frame:05d}.png")
                pairs.to_csv(tmp / f"transition_{plot_frame:05d}.csv", index=False, float_format="%.6f")
                summary["transition_pairs"] = len(pairs)
                if len(pairs):
                    summary["transition_normal_angle_median_deg"] = float(pairs["normal_angle_deg"].median())
                    summary["transition_vertex_distance_median_m"] = float(np.median(pairs.filter(like="vertex_").to_numpy()))
        (tmp / "summary.yaml").write_text(dump_yaml(summary))
    return summary


def _top_view(ax, det: PlaneDetections, colours, lw=1.5, ls="-", label=None):
    for i in range(len(det)):
        v = det.polygon(i)
        v = np.vstack([v, v[:1]])
        ax.plot(v[:, 0], v[:, 1], ls, color=colours(i % 20), lw=lw, label=label if i == 0 else None)


def plot_planes_top(log: SensorLog, k: int, params: PlaneDetectorParams, path: Path) -> None:
    """Top view (sensor frame) of frame k's cloud with its segmented planes: inliers coloured, convex outlines drawn."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    cloud = log.clouds.frame(k)
    det, lab = detect_planes(cloud, params, where=f"{log.name}: cloud {k}", return_labels=True)
    cm = plt.get_cmap("tab20")
    fig, axes = plt.subplots(1, 2, figsize=(16, 8), dpi=90)
    r = float(np.percentile(np.hypot(cloud[:, 0], cloud[:, 1]), 97))
    for ax, lim in zip(axes, (r, min(r, 20.0)), strict=True):
        m = lab < 0
        ax.scatter(cloud[m, 0], cloud[m, 1], s=0.2, c="0.75", lw=0, label="returns (no plane)")
        ax.scatter(cloud[~m, 0], cloud[~m, 1], s=0.3, c=lab[~m] % 20, cmap=cm, vmin=0, vmax=19, lw=0)
        _top_view(ax, det, cm, lw=1.0)
        ax.plot(0, 0, "k^", ms=8)
        ax.set_xlim(-lim, lim)
        ax.set_ylim(-lim, lim)
        ax.set_aspect("equal")
        ax.set_xlabel("x [m] (sensor frame)")
        ax.set_ylabel("y [m]")
    axes[0].set_title(f"{log.name}, frame {k}: {len(det)} planes from {cloud.shape[0]:,} returns ({(lab >= 0).mean() * 100:.0f} % on a plane)", fontsize=9)
    axes[1].set_title("the same, within 20 m", fontsize=9)
    fig.tight_layout()
    fig.savefig(path, metadata={"Software": None})
    plt.close(fig)


def plot_transition(log: SensorLog, det: PlaneDetections, poses: np.ndarray, k: int, source: str, path: Path) -> pd.DataFrame:
    """Frame k-1's planes carried to frame k by eq. 35 (poses from ``source``) beside frame k's segmentation."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from calib.plane_eval import compare, predict, transition

    height = log.sensor.lidar.height
    a, b = det.take(np.flatnonzero(det.frame == k - 1)), det.take(np.flatnonzero(det.frame == k))
    m = transition(poses[k - 1], poses[k], height)
    pn, pd_, prect = predict(a.normal, a.offset, a.rect, m)
    rel = np.linalg.inv(m)
    poly_pred = [(np.c_[a.polygon(i), np.ones(len(a.polygon(i)))] @ rel.T)[:, :3] for i in range(len(a))]
    pairs = compare(pn, pd_, prect, a.area, b.normal, b.offset, b.rect, b.area)
    fig, axes = plt.subplots(2, 1, figsize=(14, 11), dpi=90, gridspec_kw={"height_ratios": [3, 1]})
    for ax, (i0, i1) in zip(axes, ((0, 1), (0, 2)), strict=True):
        for i in range(len(b)):
            v = np.vstack([b.polygon(i), b.polygon(i)[:1]])
            ax.plot(v[:, i0], v[:, i1], "-", color="tab:blue", lw=1.2, label="segmented at k" if i == 0 else None)
        for i, v in enumerate(poly_pred):
            v = np.vstack([v, v[:1]])
            ax.plot(v[:, i0], v[:, i1], "--", color="tab:orange", lw=1.0, label="predicted from k-1 (eq. 35)" if i == 0 else None)
        ax.plot(0, 0, "k^", ms=8)
        if i1 == 1:
            ax.set_aspect("equal")
        ax.set_xlabel("x [m] (sensor frame at k)")
        ax.set_ylabel("y [m]" if i1 == 1 else "z [m]")
        ax.legend(loc="upper right", fontsize=8)
    med = pairs["normal_angle_deg"].median() if len(pairs) else float("nan")
    vd = np.median(pairs.filter(like="vertex_").to_numpy()) if len(pairs) else float("nan")
    axes[0].set_title(f"top view, frame {k}: {len(pairs)} pairs, median normal angle {med:.2f} deg, median vertex distance {vd:.2f} m ({source} poses)", fontsize=9)
    axes[1].set_title("side view (x-z)", fontsize=9)
    fig.tight_layout()
    fig.savefig(path, metadata={"Software": None})
    plt.close(fig)
    return pairs
