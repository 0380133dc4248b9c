"""``detcal icp``: ICP ground truth of a log, its registered cloud, and scores against truth or relations."""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np
import pandas as pd

from calib.config import dump_yaml
from calib.icp import IcpResult, icp_ground_truth, read_relations, relation_errors, rigid_align
from calib.io.atomic import atomic_output
from calib.progress import progress
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


def write_icp_run(log: SensorLog, out: Path, *, relations: Path | None = None, overwrite: bool = False) -> dict:
    rel = read_relations(relations) if relations is not None else None  # a bad file is refused before the ICP's work
    t0 = time.perf_counter()
    res = icp_ground_truth(log, progress=progress)
    dt = time.perf_counter() - t0
    summary: dict = {
        "log": log.name,
        "scans": len(log.scans),
        "keyframes": int(res.keyframes.size),
        "loop_closures": len(res.loops),
        "seconds": dt,
        "scans_per_second": len(log.scans) / dt,
    }
    if "ground_truth" in log.reference:
        summary.update(score_against_truth(log, res))
    if rel is not None:
        for name, poses in (("icp", res.poses), ("odometry", res.odometry)):
            et, er = relation_errors(log.scans.stamp, poses, rel)
            summary[f"{name}_relations"] = int(et.size)
            summary[f"{name}_trans_error_mean_m"] = float(et.mean())
            summary[f"{name}_trans_error_std_m"] = float(et.std())
            summary[f"{name}_rot_error_mean_deg"] = float(np.degrees(er).mean())
            summary[f"{name}_rot_error_std_deg"] = float(np.degrees(er).std())
    with atomic_output(out, overwrite=overwrite, directory=True) as tmp:
        tmp.mkdir()
        pd.DataFrame(
            {"time": log.scans.stamp / 1e9, "x": res.poses[:, 0], "y": res.poses[:, 1], "theta": res.poses[:, 2]}
        ).to_csv(tmp / "poses.csv", index=False, float_format="%.9g")
        (tmp / "summary.yaml").write_text(dump_yaml(summary))
        cloud = registered_cloud(log, res.poses)
        np.savez_compressed(tmp / "cloud.npz", xy=cloud.astype(np.float32))
        plot_icp(log, res, cloud, tmp / "map.png")
    return summary


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


def plot_icp(log: SensorLog, res: IcpResult, cloud: np.ndarray, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(10, 8), dpi=100)
    step = max(1, cloud.shape[0] // 300_000)
    ax.plot(cloud[::step, 0], cloud[::step, 1], ",", color="k", alpha=0.3)
    ax.plot(res.poses[:, 0], res.poses[:, 1], "r-", lw=0.8, label="ICP + pose graph")
    ax.plot(res.odometry[:, 0], res.odometry[:, 1], "b:", lw=0.6, label="odometry")
    for a, b in res.loops:
        pa, pb = res.poses[res.keyframes[a]], res.poses[res.keyframes[b]]
        ax.plot([pa[0], pb[0]], [pa[1], pb[1]], "g-", lw=1)
    ax.plot([], [], "g-", label=f"loop closures ({len(res.loops)})")
    ax.set_aspect("equal")
    ax.legend(loc="upper right")
    ax.set_title(f"{log.name}: registered scans")
    fig.tight_layout()
    fig.savefig(path, metadata={"Software": None})
    plt.close(fig)
