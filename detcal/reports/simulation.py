"""The run folders of ``detcal simulate``: run a simulator and write its log, truth, summary and overview figure.

Every folder is written to a temporary name and renamed, so never half-written.
The park's (:func:`simulate_to`): ``log.dlog`` (scans, odometry, true poses,
trees as landmarks, sensor model), ``world.yaml`` (all geometry: trees, posts,
bushes, walls), ``config.yaml`` (the config actually used, with the seed),
``summary.yaml`` and ``overview.png`` (the park, the path and one scan). The
rfs-sim and glmb-paper scenarios add ``profile.yaml``, the profile of the
simulator's true statistics; the street adds ``world.yaml`` and ``labels.npy``.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import yaml

from calib.config import dump_yaml
from calib.io.atomic import atomic_output
from calib.io.native import write_native
from calib.progress import progress
from calib.sim import SIMULATORS
from calib.sim.park import Simulation, World, sensor_poses
from calib.sim.street import StreetSimulation
from calib.sim.two_stage import TwoStageRun
from detectors.geometry import compose
from detectors.sensor_log import SensorLog
from profiles import strict_yaml
from profiles.errors import DataError
from detcal.reports.figures import save_figure, wrapped_title


def write_simulation_run(name: str, cfg, seed: int, out: Path, *, overwrite: bool = False, figure: bool = True) -> dict:
    """Run the simulator ``name`` (:data:`calib.sim.SIMULATORS`) with its config and seed and write its run folder:
    log.dlog, the simulator's own files, config.yaml (the seed and the config actually used), summary.yaml and,
    when the simulator has one, overview.png. Returns the summary."""
    sim = SIMULATORS.get(name)
    run = sim.run(cfg, seed, progress=progress)
    with atomic_output(out, overwrite=overwrite, directory=True) as tmp:
        tmp.mkdir()
        write_native(run.log, tmp / "log.dlog")
        for rel, data in run.files.items():
            if isinstance(data, bytes):
                (tmp / rel).write_bytes(data)
            else:
                (tmp / rel).write_text(data)
        (tmp / "config.yaml").write_text(dump_yaml({"seed": seed, sim.key: cfg.model_dump(mode="json")}))
        (tmp / "summary.yaml").write_text(dump_yaml(run.summary))
        draw = FIGURES.get(name)
        if figure and draw is not None:
            draw(run.result, tmp / "overview.png")
    return run.summary


def load_world(path: Path) -> World:
    try:
        return World.from_dict(strict_yaml.load(path.read_text()), str(path))
    except (OSError, yaml.YAMLError) as exc:
        raise DataError(f"{path}: cannot read the world ({exc})") from None


def plot_park_overview(sim: Simulation, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.collections import LineCollection, PatchCollection
    from matplotlib.patches import Circle, Polygon

    w, log = sim.world, sim.log
    fig, ax = plt.subplots(figsize=(10, 7.5), dpi=100)
    ax.add_collection(PatchCollection([Circle(c, r) for c, r in zip(w.tree_xy, w.tree_r, strict=True)], color="tab:green", label="trees"))
    ax.add_collection(PatchCollection([Circle(c, max(r, 0.15)) for c, r in zip(w.post_xy, w.post_r, strict=True)], color="k"))
    polys = [Polygon(w.bush_vertices[a:b]) for a, b in zip(w.bush_offsets[:-1], w.bush_offsets[1:], strict=True)]
    ax.add_collection(PatchCollection(polys, color="olive", alpha=0.6))
    ax.add_collection(LineCollection(np.stack([w.wall_p0, w.wall_p1], axis=1), colors="tab:brown", linewidths=2))
    truth = log.reference["ground_truth"].poses
    ax.plot(truth[:, 0], truth[:, 1], "b-", lw=0.8, label="true path")
    k = len(log.scans) // 3
    scan_t = log.scans.stamp[k]
    pose = truth[np.searchsorted(log.reference["ground_truth"].stamp, scan_t)]
    sp = sensor_poses(pose[None], log.sensor.mount)[0]
    a = sp[2] + log.sensor.angles()
    r = log.scans.ranges[k].astype(np.float64)
    ok = np.isfinite(r)
    ax.plot(sp[0] + r[ok] * np.cos(a[ok]), sp[1] + r[ok] * np.sin(a[ok]), "r.", ms=2, label=f"scan {k}")
    ax.set_aspect("equal")
    ax.set_xlim(-5, sim.config.width + 5)
    ax.set_ylim(-5, sim.config.height + 5)
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    wrapped_title(ax, f"simulated park, seed {sim.seed}: {w.tree_r.size} trees, {len(log.scans)} scans")
    ax.legend(loc="upper right")
    save_figure(fig, path)


def plot_street_overview(sim: StreetSimulation, path) -> None:
    """Top view of the world, the path, and one frame's cloud coloured by height."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.patches import Circle

    w, log = sim.world, sim.log
    fig, ax = plt.subplots(figsize=(10, 9), dpi=100)
    colours = {"facade": "k", "wall": "tab:brown", "board": "tab:red", "car": "tab:blue"}
    for p, k in zip(w.polygons, w.poly_kind, strict=True):
        if k in colours:
            ax.plot(p[:, 0], p[:, 1], "-", color=colours[k], lw=1.0)
    for c, k in zip(w.cyl, w.cyl_kind, strict=True):
        ax.add_patch(Circle(c[:2], max(c[2], 0.3), color="saddlebrown" if k == "trunk" else "0.3"))
    for s, k in zip(w.sph, w.sph_kind, strict=True):
        ax.add_patch(Circle(s[:2], s[3], color="tab:green", alpha=0.25 if k == "crown" else 0.5, lw=0))
    k = len(log.clouds) // 2
    cloud = log.clouds.frame(k).astype(np.float64)
    li = sim.config.lidar
    sp = compose(sim.frame_poses[k], np.array([li.mount.x, li.mount.y, li.mount.theta]))
    c, s = np.cos(sp[2]), np.sin(sp[2])
    sel = cloud[::3]
    ax.scatter(sp[0] + c * sel[:, 0] - s * sel[:, 1], sp[1] + s * sel[:, 0] + c * sel[:, 1], s=0.2, c=sel[:, 2], cmap="viridis", alpha=0.6)
    gt = log.reference["ground_truth"].poses
    ax.plot(gt[:, 0], gt[:, 1], "m-", lw=1.5, label="true path")
    ax.set_aspect("equal")
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    wrapped_title(
        ax,
        f"simulated street, seed {sim.seed}: {len(log.planes)} planes, {len(w.cyl)} cylinders, {len(w.sph)} spheres; "
        f"cloud of frame {k} ({cloud.shape[0]:,} returns)",
        fontsize=9,
    )
    ax.legend(loc="upper left")
    save_figure(fig, path)


def plot_rfs_overview(log: SensorLog, path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    poses = log.reference["ground_truth"].poses
    fig, ax = plt.subplots(figsize=(7, 6))
    ax.plot(poses[:, 0], poses[:, 1], "k-", lw=1, label="true path")
    ax.plot(log.landmarks.xy[:, 0], log.landmarks.xy[:, 1], "g*", ms=8, label="landmarks")
    ax.set_aspect("equal")
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    wrapped_title(ax, f"{log.name}: {len(log.detections)} detections over {log.detections.n_frames} steps", fontsize=9)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def _finish(fig, ax, path, title: str, legend: str) -> None:
    """A detection-level scenario's overview: equal axes in metres, its title and legend, saved without a date."""

    ax.set_aspect("equal")
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    wrapped_title(ax, title, fontsize=9)
    ax.legend(fontsize=7, loc=legend)
    save_figure(fig, path, dpi=110)


def plot_glmb_paper_overview(log: SensorLog, path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    poses = log.reference["ground_truth"].poses
    d = log.detections
    fs = log.reference["ground_truth"]
    at = np.searchsorted(fs.stamp, d.frame_stamp[d.frame])
    sp = fs.poses[at]
    a = sp[:, 2] + d.bearing
    xy = np.column_stack([sp[:, 0] + d.range * np.cos(a), sp[:, 1] + d.range * np.sin(a)])
    clutter = np.asarray(d.descriptors["landmark"]) == 0
    fig, ax = plt.subplots(figsize=(8, 6))
    ax.plot(xy[clutter, 0], xy[clutter, 1], ".", color="tab:green", ms=1.5, alpha=0.5, label="false alarms")
    ax.plot(xy[~clutter, 0], xy[~clutter, 1], ".", color="tab:purple", ms=1.5, alpha=0.5, label="landmark detections")
    ax.plot(poses[:, 0], poses[:, 1], "b--", lw=1, label="true path")
    ax.plot(log.landmarks.xy[:, 0], log.landmarks.xy[:, 1], "k+", ms=10, mew=2, label="landmarks")
    _finish(fig, ax, path, f"{log.name}: {len(d)} detections over {d.n_frames} scans", "upper right")


def plot_two_stage_overview(run: TwoStageRun, path) -> None:
    """The initial path, the control polygon, the smoothed path, the sensor at each step and the features' tracks."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    poses = run.log.reference["ground_truth"].poses
    fig, ax = plt.subplots(figsize=(7.5, 7))
    ax.plot(run.initial[:, 0], run.initial[:, 1], ":", color="0.6", lw=1, label="initial path (stage 1)")
    ax.plot(run.control[:, 0], run.control[:, 1], ".", color="tab:orange", ms=2, label="control polygon")
    ax.plot(run.path[:, 0], run.path[:, 1], "b-", lw=1, label="smoothed path (stage 2)")
    ax.plot(poses[:, 0], poses[:, 1], "b.", ms=4, label="sensor at each step")
    tr = run.features
    for j in range(tr.shape[1]):
        ax.plot(tr[:, j, 0], tr[:, j, 1], "r-", lw=1)
    ax.plot(tr[0, :, 0], tr[0, :, 1], "r+", ms=10, mew=2, label="feature points")
    ob = tr[0, run.obstacles, :2]
    ax.plot(ob[:, 0], ob[:, 1], "ko", mfc="none", ms=10, label="obstacles avoided")
    _finish(fig, ax, path, f"{run.log.name}: {len(run.log.detections)} detections over {run.log.detections.n_frames} steps", "upper left")


#: The overview figure of each simulator's run folder (a simulator without one writes none).
FIGURES = {
    "park": plot_park_overview, "rfs-sim": plot_rfs_overview, "street": plot_street_overview, "glmb-paper": plot_glmb_paper_overview,
    "two-stage": plot_two_stage_overview,
}
