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
from calib.sim.park import ParkConfig, Simulation, World, sensor_poses, simulate_park
from calib.sim.street import StreetConfig, StreetSimulation, simulate_street, street_summary
from detectors.geometry import compose
from detectors.logs import SensorLog
from profiles.errors import DataError


def log_summary(sim: Simulation) -> dict:
    log = sim.log
    r = log.scans.ranges
    return {
        "seed": sim.seed,
        "scans": len(log.scans),
        "beams": log.scans.n_beams,
        "odometry_rows": len(log.odometry),
        "duration_s": float((log.scans.stamp[-1] - log.scans.stamp[0]) / 1e9),
        "path_length_m": float(np.sum(np.hypot(*np.diff(log.reference["ground_truth"].poses[:, :2], axis=0).T))),
        "returning_beam_share": float(np.isfinite(r).mean()),
        "trees": int(sim.world.tree_r.size),
        "posts": int(sim.world.post_r.size),
        "bushes": int(sim.world.bush_offsets.size - 1),
        "wall_segments": int(sim.world.wall_p0.shape[0]),
    }


def write_simulation(sim: Simulation, out: Path, *, overwrite: bool = False, figure: bool = True) -> dict:
    summary = log_summary(sim)
    with atomic_output(out, overwrite=overwrite, directory=True) as tmp:
        tmp.mkdir()
        write_native(sim.log, tmp / "log.dlog")
        (tmp / "world.yaml").write_text(dump_yaml(sim.world.to_dict()))
        (tmp / "config.yaml").write_text(dump_yaml({"seed": sim.seed, "park": sim.config.model_dump(mode="json")}))
        (tmp / "summary.yaml").write_text(dump_yaml(summary))
        if figure:
            plot_overview(sim, tmp / "overview.png")
    return summary


def load_world(path: Path) -> World:
    try:
        return World.from_dict(yaml.safe_load(path.read_text()), str(path))
    except (OSError, yaml.YAMLError) as exc:
        raise DataError(f"{path}: cannot read the world ({exc})") from None


def plot_overview(sim: Simulation, path: Path) -> None:
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
    ax.set_title(f"simulated park, seed {sim.seed}: {w.tree_r.size} trees, {len(log.scans)} scans")
    ax.legend(loc="upper right")
    fig.tight_layout()
    fig.savefig(path, metadata={"Software": None})
    plt.close(fig)


def simulate_to(out: Path, seed: int, cfg: ParkConfig | None = None, *, overwrite: bool = False) -> dict:
    sim = simulate_park(cfg or ParkConfig(), seed, progress=progress)
    return write_simulation(sim, out, overwrite=overwrite)


def write_rfs_simulation(cfg, seed: int, out: Path, *, overwrite: bool = False) -> dict:
    """The rfs-sim run folder: log.dlog, profile.yaml (the simulator's true statistics), config.yaml,
    summary.yaml, overview.png."""
    from calib.sim.rfs import simulate_rfs, summary, truth_profile
    from profiles.store import dump_profile

    log = simulate_rfs(cfg, seed)
    info = {"seed": seed, **summary(log, cfg)}
    with atomic_output(out, overwrite=overwrite, directory=True) as tmp:
        tmp.mkdir()
        write_native(log, tmp / "log.dlog")
        (tmp / "profile.yaml").write_text(dump_profile(truth_profile(cfg)))
        (tmp / "config.yaml").write_text(dump_yaml({"seed": seed, "rfs_sim": cfg.model_dump(mode="json")}))
        (tmp / "summary.yaml").write_text(dump_yaml(info))
        plot_rfs_overview(log, tmp / "overview.png")
    return info


def write_glmb_paper_simulation(cfg, seed: int, out: Path, *, overwrite: bool = False) -> dict:
    """The glmb-paper run folder: log.dlog, profile.yaml (the simulator's true statistics), config.yaml,
    summary.yaml, overview.png."""
    from calib.sim.glmb_paper import simulate_glmb_paper, summary, truth_profile
    from profiles.store import dump_profile

    log = simulate_glmb_paper(cfg, seed)
    info = {"seed": seed, **summary(log, cfg)}
    with atomic_output(out, overwrite=overwrite, directory=True) as tmp:
        tmp.mkdir()
        write_native(log, tmp / "log.dlog")
        (tmp / "profile.yaml").write_text(dump_profile(truth_profile(cfg)))
        (tmp / "config.yaml").write_text(dump_yaml({"seed": seed, "glmb_paper": cfg.model_dump(mode="json")}))
        (tmp / "summary.yaml").write_text(dump_yaml(info))
        plot_glmb_paper_overview(log, tmp / "overview.png")
    return info


def write_street_simulation(cfg: StreetConfig, seed: int, out, *, overwrite: bool = False) -> dict:
    """The run folder: log.dlog (clouds, odometry, true poses, plane truth, sensor model), world.yaml,
    labels.npy (the primitive id of every return), config.yaml, summary.yaml, overview.png."""
    import io

    sim = simulate_street(cfg, seed, progress=progress)
    summary = street_summary(sim)
    with atomic_output(out, overwrite=overwrite, directory=True) as tmp:
        tmp.mkdir()
        write_native(sim.log, tmp / "log.dlog")
        (tmp / "world.yaml").write_text(dump_yaml(sim.world.to_dict()))
        buf = io.BytesIO()
        np.lib.format.write_array(buf, sim.labels, allow_pickle=False)
        (tmp / "labels.npy").write_bytes(buf.getvalue())
        (tmp / "config.yaml").write_text(dump_yaml({"seed": seed, "street": cfg.model_dump(mode="json")}))
        (tmp / "summary.yaml").write_text(dump_yaml(summary))
        plot_street(sim, tmp / "overview.png")
    return summary


def plot_street(sim: StreetSimulation, path) -> None:
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
    ax.set_title(
        f"simulated street, seed {sim.seed}: {len(log.planes)} planes, {len(w.cyl)} cylinders, {len(w.sph)} spheres; "
        f"cloud of frame {k} ({cloud.shape[0]:,} returns)",
        fontsize=9,
    )
    ax.legend(loc="upper left")
    fig.tight_layout()
    fig.savefig(path, metadata={"Software": None})
    plt.close(fig)
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
    ax.set_title(f"{log.name}: {len(log.detections)} detections over {log.detections.n_frames} steps", fontsize=9)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
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
    ax.set_aspect("equal")
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.set_title(f"{log.name}: {len(d)} detections over {d.n_frames} scans", fontsize=9)
    ax.legend(fontsize=7, loc="upper right")
    fig.tight_layout()
    fig.savefig(path, dpi=110, metadata={"Software": None})
    plt.close(fig)
