"""``detcal icp``: the ground truth of a log, its quality report, its registered cloud, and its scores.

The run folder holds:

- ``poses.csv`` (time, x, y, theta per scan), ``poses_tum.txt`` and
  ``poses_kitti.txt`` (:mod:`calib.trajectory`; ``evo_ape``/``evo_rpe`` read them);
- ``quality.yaml``: the verdict, its figures and the failing stretches
  (:mod:`calib.gtquality`), the relation scores when relations were given;
  ``keyframes.csv`` (fitness per keyframe) and ``loops.csv`` (every loop
  candidate, why it was refused or what the robust graph made of it);
- ``summary.yaml``, ``cloud.npz`` (registered points) and ``map.png`` (the
  cloud, the trajectory, the loops kept and turned off, the failing stretches).
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np
import pandas as pd

from calib.config import dump_yaml
from calib.gtquality import QualityReport, QualityThresholds, assess
from calib.icp import IcpResult, icp_ground_truth, read_relations, rigid_align
from calib.io.atomic import atomic_output
from calib.progress import progress
from calib.trajectory import kitti_text, relation_scores, tum_text
from detectors.geometry import interpolate_poses
from detectors.sensor_log import SensorLog


def score_against_truth(log: SensorLog, res: IcpResult) -> dict:
    """Position RMSE against the log's ground truth: anchored at the first pose, and after a best rigid fit (ATE)."""
    ref = log.reference["ground_truth"]
    truth = interpolate_poses(ref.stamp, ref.poses, log.scans.stamp)
    from detectors.geometry import compose

    anchored = compose(truth[0], res.poses)
    fitted = rigid_align(res.poses, truth)
    odo = rigid_align(res.odometry, truth)

    def rmse(p):
        return float(np.sqrt(np.mean(np.sum((p[:, :2] - truth[:, :2]) ** 2, axis=1))))

    return {"rmse_anchored_first_pose_m": rmse(anchored), "ate_rmse_rigid_fit_m": rmse(fitted), "odometry_ate_rmse_rigid_fit_m": rmse(odo)}


def write_icp_run(
    log: SensorLog, out: Path, *, relations: Path | None = None, overwrite: bool = False, thresholds: QualityThresholds | None = None
) -> dict:
    """Build the ground truth of ``log``, assess it and write the run folder (module docstring); returns the summary."""
    rel = read_relations(relations) if relations is not None else None  # a bad file is refused before the ICP's work
    t0, c0 = time.perf_counter(), time.process_time()
    res = icp_ground_truth(log, progress=progress)
    dt, cpu = time.perf_counter() - t0, time.process_time() - c0
    quality = assess(log, res.poses, res.details, rel, thresholds)
    summary: dict = {
        "log": log.name,
        "scans": len(log.scans),
        "keyframes": int(res.keyframes.size),
        "loop_closures": len(res.loops),
        "ground_truth": "passes" if quality.verdict.passed else "fails",
        **({"failed": [c.describe() for c in quality.verdict.failures]} if not quality.verdict.passed else {}),
        "seconds": dt,
        "cpu_seconds": cpu,
        "cpu_seconds_by_stage": dict(res.details.cpu_seconds) if res.details is not None else {},
        "scans_per_cpu_second": len(log.scans) / cpu if cpu > 0 else float("nan"),
    }
    if "ground_truth" in log.reference:
        summary.update(score_against_truth(log, res))
    if rel is not None:
        for name, poses in (("icp", res.poses), ("odometry", res.odometry)):
            sc = relation_scores(log.scans.stamp, poses, rel)
            summary[f"{name}_relations"] = sc["relations"]
            for k in ("trans_mean_m", "trans_std_m", "trans_max_m", "rot_mean_deg", "rot_std_deg", "rot_max_deg"):
                summary[f"{name}_{k.replace('trans', 'trans_error').replace('rot', 'rot_error')}"] = sc[k]
    with atomic_output(out, overwrite=overwrite, directory=True) as tmp:
        tmp.mkdir()
        write_trajectories(tmp, log.scans.stamp, res.poses)
        write_quality(tmp, quality)
        (tmp / "summary.yaml").write_text(dump_yaml(summary))
        cloud = registered_cloud(log, res.poses)
        np.savez_compressed(tmp / "cloud.npz", xy=cloud.astype(np.float32))
        plot_icp(log, res, cloud, tmp / "map.png", quality)
    return summary


def write_trajectories(folder: Path, stamps_ns: np.ndarray, poses: np.ndarray) -> None:
    """poses.csv, poses_tum.txt and poses_kitti.txt of vehicle poses (S, 3) at scan stamps (S,) [ns]."""
    pd.DataFrame({"time": stamps_ns / 1e9, "x": poses[:, 0], "y": poses[:, 1], "theta": poses[:, 2]}).to_csv(
        folder / "poses.csv", index=False, float_format="%.9g"
    )
    (folder / "poses_tum.txt").write_text(tum_text(stamps_ns, poses))
    (folder / "poses_kitti.txt").write_text(kitti_text(poses))


def write_quality(folder: Path, quality: QualityReport) -> None:
    """quality.yaml, and keyframes.csv / loops.csv when the poses came from a registration."""
    (folder / "quality.yaml").write_text(dump_yaml(quality.as_dict()))
    write_quality_tables(folder, quality)


def write_quality_tables(folder: Path, quality: QualityReport) -> None:
    """keyframes.csv (fitness per keyframe) and loops.csv (every loop candidate) of a registration's report."""
    if quality.keyframes is not None:
        quality.keyframes.to_csv(folder / "keyframes.csv", index=False, float_format="%.6g")
    if quality.loops is not None:
        quality.loops.to_csv(folder / "loops.csv", index=False, float_format="%.6g")


def registered_cloud(log: SensorLog, poses: np.ndarray, every: int = 1) -> np.ndarray:
    """(P, 2) world-frame points of every ``every``-th scan, vehicle poses (S, 3)."""
    from detectors.geometry import compose

    m = log.sensor.mount
    sp = compose(poses[::every], np.array([m.x, m.y, m.theta]))
    r = log.scans.ranges[::every].astype(np.float64)
    ang = log.scan_angles(slice(None, None, every))
    a = sp[:, 2:3] + (ang if ang.ndim == 2 else ang[None, :])
    x, y = sp[:, 0:1] + r * np.cos(a), sp[:, 1:2] + r * np.sin(a)
    ok = np.isfinite(x)
    return np.column_stack([x[ok], y[ok]])


def plot_icp(log: SensorLog, res: IcpResult, cloud: np.ndarray, path: Path, quality: QualityReport | None = None) -> None:
    """The registered cloud and trajectory; loops kept (green) and turned off (orange); failing stretches (magenta)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(10, 8), dpi=100)
    step = max(1, cloud.shape[0] // 300_000)
    ax.plot(cloud[::step, 0], cloud[::step, 1], ",", color="k", alpha=0.3)
    ax.plot(res.odometry[:, 0], res.odometry[:, 1], "b:", lw=0.6, label="odometry")
    ax.plot(res.poses[:, 0], res.poses[:, 1], "r-", lw=0.8, label="ground truth (registration + pose graph)")
    reg = res.details
    if reg is not None and reg.edges.loop.any():
        kp = res.poses[res.keyframes]
        rows = np.flatnonzero(reg.edges.loop)
        off = reg.solution.weight[rows] < 0.5
        for mask, colour, label in ((~off, "g", "loops kept"), (off, "orange", "loops turned off by the robust graph")):
            i, j = reg.edges.i[rows[mask]], reg.edges.j[rows[mask]]
            if i.size:
                xs = np.column_stack([kp[i, 0], kp[j, 0], np.full(i.size, np.nan)]).ravel()
                ys = np.column_stack([kp[i, 1], kp[j, 1], np.full(i.size, np.nan)]).ravel()
                ax.plot(xs, ys, "-", color=colour, lw=0.5, alpha=0.6, label=f"{label} ({i.size})")
    if quality is not None and quality.failing.any():
        p = np.where(quality.failing[:, None], res.poses[:, :2], np.nan)
        ax.plot(p[:, 0], p[:, 1], "-", color="m", lw=3, alpha=0.8, label=f"failing stretches ({len(quality.stretches)})")
    ax.set_aspect("equal")
    ax.legend(loc="upper right", fontsize=8)
    verdict = "" if quality is None else (" - passes" if quality.verdict.passed else " - FAILS: " + quality.verdict.failures[0].name)
    ax.set_title(f"{log.name}: registered scans{verdict}")
    fig.tight_layout()
    fig.savefig(path, metadata={"Software": None})
    plt.close(fig)
