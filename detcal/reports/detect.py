"""The run folders of ``detcal detect``: the circle detector over every scan, the plane detector over every cloud.

Circles: ``detections.csv`` (one row per detection: time [s], scan index,
frame, centre x/y [m, sensor frame], range [m], bearing [rad], radius [m], fit
error [m^2], convexity [m], points, squared Mahalanobis distance),
``config.yaml`` (the detector parameters actually used), ``summary.yaml`` and,
with ``plot_scan``, ``scan_<k>.png`` (the scan's clusters, circles and P_D field).

Planes: ``planes.csv`` (one row per plane: frame, time [s], plane index,
normal, offset [m], azimuth and elevation [rad], their standard deviations and
the offset's from the fit covariance, inliers, residual sigma [m], area [m^2]
of the convex outline, width [m] of the enclosing rectangle; sensor frame),
``outlines.csv`` (frame, plane, vertex, x, y, z: the convex outlines),
``config.yaml``, ``summary.yaml`` (planes per frame, ms per frame) and, with
``plot_frame``, ``planes_<k>.png`` (a top view of the segmented planes over the
cloud) and, when the log has poses (truth, else odometry),
``transition_<k>.png``: the planes of frame k-1 carried to frame k by the plane
transition (eq. 35) beside those segmented at k, with the paper's area,
vertex-distance and normal-angle table (``transition_<k>.csv``).
"""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import pandas as pd  # noqa: E402
from matplotlib.patches import Circle  # noqa: E402

from calib.config import dump_yaml, load_yaml_model  # noqa: E402
from calib.detect import DetectConfig, detections_table, run_detector  # noqa: E402
from calib.io.atomic import atomic_output  # noqa: E402
from calib.plane_detect import PlaneDetectConfig, frame_sensor_poses, outlines_table, planes_table, run_plane_detector  # noqa: E402
from detectors.circle import CircleDetections  # noqa: E402
from detectors.sensor_log import SensorLog  # noqa: E402
from detectors.plane import PlaneDetections, detect_planes  # noqa: E402
from detectors.raytrace import pd_grid  # noqa: E402
from profiles.errors import DataError, UsageError  # noqa: E402
from profiles.planes import PlaneDetectorParams  # noqa: E402
from profiles.schema import PD_COVARIATES, HotellingParams, PdTable  # noqa: E402
from profiles.store import resolve  # noqa: E402
from detcal.reports.figures import save_figure, wrapped_title  # noqa: E402

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
    wrapped_title(ax, f"{log.name}: scan {k}")
    ax.legend(loc="lower left", fontsize=8)
    save_figure(fig, path)
#: Thesis Table 6.1 (a real park data set), clamped as in ch. 6: above n_p = 6 use
#: the value at 6, values below 0.1 become 0. Used for plots when no profile is given.
THESIS_TABLE_6_1 = PdTable(
    covariate="n_p",
    edges=[0, 1, 2, 3, 4, 5, 6, 7],
    pd=[0.0, 0.0, 0.0, 0.3595, 0.7562, 0.8854, 0.8987],
    counts=[273025, 62025, 28582, 19423, 10374, 6909, 4185],
    clamping="thesis: n_p > 6 uses n_p = 6; P_D < 0.1 set to 0",
)

def detect_config(profile_ref: str | None, config: Path | None) -> tuple[DetectConfig, PdTable | None]:
    """The detector settings of ``detcal detect``: a profile's detector, gate and n_p table, or a config file."""

    if profile_ref is None:
        return load_yaml_model(DetectConfig, config), None
    if config is not None:
        raise UsageError("--profile and --config both set the detector; give one")

    prof = resolve(profile_ref)
    if prof.detector.kind != "circle2d":
        raise UsageError(f"profile {prof.ref} is a {prof.kind} profile, not one of the circle detector")
    hot = None if prof.hotelling is None else HotellingParams.model_validate(prof.hotelling.model_dump(include=set(HotellingParams.model_fields)))
    cfg = DetectConfig(detector=prof.detector.circle, hotelling=hot, k_sigma=prof.detector.k_sigma)
    return cfg, prof.pd if PD_COVARIATES.get(prof.pd.covariate).ray_traced else None


def write_detect_run(
    log: SensorLog, cfg: DetectConfig, out: Path, *, plot_scan: int | None = None, pd_table: PdTable | None = None, overwrite: bool = False
) -> dict:
    if plot_scan is not None and log.scans is not None and not 0 <= plot_scan < len(log.scans):
        raise UsageError(f"--plot: scan {plot_scan} is outside the log (0..{len(log.scans) - 1})")
    det = run_detector(log, cfg)
    table = detections_table(log, det)
    summary = {
        "log": log.name,
        "scans": len(log.scans),
        "detections": len(det),
        "per_scan_mean": float(len(det) / max(1, len(log.scans))),
        "gated": cfg.hotelling is not None,
    }
    with atomic_output(out, overwrite=overwrite, directory=True) as tmp:
        tmp.mkdir()
        table.to_csv(tmp / "detections.csv", index=False, float_format="%.9g")
        (tmp / "config.yaml").write_text(dump_yaml(cfg.model_dump(mode="json")))
        (tmp / "summary.yaml").write_text(dump_yaml(summary))
        if plot_scan is not None:
            plot_scan_detections(log, det, plot_scan, pd_table or THESIS_TABLE_6_1, cfg.k_sigma, tmp / f"scan_{plot_scan:05d}.png")
    return summary
def plane_detect_config(profile_ref: str | None, config: Path | None) -> PlaneDetectConfig:
    """The detector settings of ``detcal detect`` on clouds: a lidar3d-planes profile's detector, or a config file."""

    if profile_ref is None:
        return load_yaml_model(PlaneDetectConfig, config)
    if config is not None:
        raise UsageError("--profile and --config both set the detector; give one")

    prof = resolve(profile_ref)
    if prof.detector.kind != "plane3d":
        raise UsageError(f"profile {prof.ref} is a {prof.kind} profile; point clouds need a lidar3d-planes one")
    return PlaneDetectConfig(detector=prof.detector.plane)


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
    wrapped_title(axes[0], f"{log.name}, frame {k}: {len(det)} planes from {cloud.shape[0]:,} returns ({(lab >= 0).mean() * 100:.0f} % on a plane)", fontsize=9)
    wrapped_title(axes[1], "the same, within 20 m", fontsize=9)
    save_figure(fig, path)


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
    wrapped_title(axes[0], f"top view, frame {k}: {len(pairs)} pairs, median normal angle {med:.2f} deg, median vertex distance {vd:.2f} m ({source} poses)", fontsize=9)
    wrapped_title(axes[1], "side view (x-z)", fontsize=9)
    save_figure(fig, path)
    return pairs
