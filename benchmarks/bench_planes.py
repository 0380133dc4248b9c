"""Plane detector: speed and accuracy on the three KITTI frames and on simulated street frames, beside Open3D.

Prints, per frame, ms per frame (median of ``--repeat`` runs) and the number of planes for detcal's detector
(spherical cells, region growing, MSSE) and for Open3D's RANSAC ``segment_plane`` applied repeatedly (each
plane's inliers removed, until fewer than ``--min-points`` remain or ``--max-planes`` are found) and its
``detect_planar_patches``; on simulated frames also the recall of true planes with >= 200 returns and the
median normal-angle and offset errors (the issue's targets: >= 95 %, <= 1 deg, <= 3 cm). Writes the KITTI
figures (top views of the segmentation) to ``--figures``.

Open3D is not a dependency of detcal: install it beside detcal to get the baseline (``pip install open3d-cpu``;
its Linux wheel needs the system's libusb-1.0). Without it the baseline columns are skipped and said so.

    python benchmarks/bench_planes.py [--kitti ../shared/data/kitti_object/velodyne] [--sim-frames 10] [--figures DIR]
"""

from __future__ import annotations

import argparse
import os
import time
from pathlib import Path

import numpy as np

from calib.io.kitti import read_kitti
from detcal.reports.detect import plot_planes_top
from calib.sim.street import StreetConfig, simulate_street
from detectors.geometry import compose
from detectors.geometry3d import normal_angle
from detectors.plane import detect_planes
from profiles.planes import PlaneDetectorParams


def open3d():
    try:
        import open3d as o3d  # noqa: F401

        return o3d
    except Exception as exc:  # noqa: BLE001 - any import failure means no baseline
        print(f"Open3D baseline unavailable: {type(exc).__name__}: {exc}")
        return None


def o3d_ransac(o3d, pts: np.ndarray, min_points: int, max_planes: int, dist: float = 0.05, iters: int = 1000):
    """Planes (normal, d, inlier indices) by repeated RANSAC segment_plane, removing each plane's inliers."""
    idx = np.arange(pts.shape[0])
    out = []
    o3d.utility.random.seed(0)
    while idx.size >= min_points and len(out) < max_planes:
        pc = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(pts[idx]))
        model, inl = pc.segment_plane(distance_threshold=dist, ransac_n=3, num_iterations=iters)
        inl = np.asarray(inl)
        if inl.size < min_points:
            break
        a, b, c, d = model
        nrm = np.array([a, b, c])
        out.append((nrm / np.linalg.norm(nrm), -d / np.linalg.norm(nrm), idx[inl]))
        idx = np.delete(idx, inl)
    return out


def o3d_patches(o3d, pts: np.ndarray):
    """Planes of Open3D's detect_planar_patches (needs normals): (normal, d, inlier indices) per patch."""
    pc = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(pts))
    pc.estimate_normals(o3d.geometry.KDTreeSearchParamKNN(knn=20))
    boxes = pc.detect_planar_patches(normal_variance_threshold_deg=60, coplanarity_deg=75, outlier_ratio=0.75, min_plane_edge_length=0, min_num_points=0)
    out = []
    for b in boxes:
        inl = np.asarray(b.get_point_indices_within_bounding_box(pc.points))
        nrm = np.asarray(b.R)[:, 2]
        out.append((nrm, float(nrm @ np.asarray(b.center)), inl))
    return out


def timed(f, repeat: int):
    ms = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        res = f()
        ms.append((time.perf_counter() - t0) * 1e3)
    return res, float(np.median(ms))


def score(planes, ns, ds, ids):
    """Recall of true planes with >= 200 returns, median normal error [deg] and offset error [m] of those found.
    planes: list of (normal, d, inlier indices); found = a plane that takes >= half the true plane's returns and
    is that plane (normal within 2 deg, offset within 10 cm): facades in one line are one plane, and one detection
    finds them all."""
    counts = np.bincount(ids[ids < len(ds)], minlength=len(ds))
    lab = np.full(ids.size, -1)
    for m, (_, _, inl) in enumerate(planes):
        lab[inl] = m
    found, total, ang, off = 0, 0, [], []
    for p in np.flatnonzero(counts >= 200):
        total += 1
        got = lab[ids == p]
        got = got[got >= 0]
        if got.size < counts[p] / 2:
            continue
        m = np.bincount(got).argmax()
        n, d, _ = planes[m]
        sgn = 1.0 if n @ ns[p] >= 0 else -1.0
        if np.degrees(normal_angle(n, ns[p])) > 2.0 or abs(sgn * d - ds[p]) > 0.1:
            continue
        found += 1
        ang.append(np.degrees(normal_angle(n, ns[p])))
        off.append(abs(sgn * d - ds[p]))
    return found, total, (np.median(ang) if ang else np.nan), (np.median(off) if off else np.nan)


def sim_truth(sim, k):
    log, li = sim.log, sim.config.lidar
    sp = compose(sim.frame_poses[k], np.array([li.mount.x, li.mount.y, li.mount.theta]))
    c, s = np.cos(sp[2]), np.sin(sp[2])
    n = log.planes.normal
    ns = np.column_stack([c * n[:, 0] + s * n[:, 1], -s * n[:, 0] + c * n[:, 1], n[:, 2]])
    ds = log.planes.offset - n @ np.array([sp[0], sp[1], li.height])
    flip = np.where(ds < 0, -1.0, 1.0)
    a, b = log.clouds.offsets[k], log.clouds.offsets[k + 1]
    return ns * flip[:, None], ds * flip, sim.labels[a:b]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--kitti", type=Path, default=Path(__file__).resolve().parents[1].parent / "shared" / "data" / "kitti_object" / "velodyne")
    ap.add_argument("--sim-frames", type=int, default=10)
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--min-points", type=int, default=200)
    ap.add_argument("--max-planes", type=int, default=30)
    ap.add_argument("--figures", type=Path, default=None)
    args = ap.parse_args()
    print(f"load average: {os.getloadavg()[0]:.2f} on {os.cpu_count()} cores")
    o3d = open3d()
    prm = PlaneDetectorParams()
    detect_planes(np.random.default_rng(0).normal(size=(1000, 3)) * [10, 10, 0.01], prm)  # compile caches, warm up
    if args.kitti.exists():
        log = read_kitti(args.kitti)
        print("\nKITTI object frames (real HDL-64E):")
        print(f"{'frame':>7} {'points':>8} | {'detcal ms':>9} {'planes':>6} | {'RANSAC ms':>9} {'planes':>6} | {'patches ms':>10} {'planes':>6}")
        for k in range(len(log.clouds)):
            pts = log.clouds.frame(k)
            det, ms = timed(lambda pts=pts: detect_planes(pts, prm), args.repeat)
            row = f"{k:>7} {pts.shape[0]:>8,} | {ms:>9.0f} {len(det):>6}"
            if o3d is not None:
                p64 = pts[:, :3].astype(np.float64)
                rp, rms = timed(lambda p64=p64: o3d_ransac(o3d, p64, args.min_points, args.max_planes), 1)
                pp, pms = timed(lambda p64=p64: o3d_patches(o3d, p64), 1)
                row += f" | {rms:>9.0f} {len(rp):>6} | {pms:>10.0f} {len(pp):>6}"
            print(row)
            if args.figures is not None:
                args.figures.mkdir(parents=True, exist_ok=True)
                plot_planes_top(log, k, prm, args.figures / f"kitti_{k:06d}_planes.png")
    else:
        print(f"KITTI frames not found at {args.kitti}: skipped")
    if args.sim_frames:
        sim = simulate_street(StreetConfig(frames=args.sim_frames * 10), 7)
        print(f"\nsimulated street (seed 7, every 10th of {args.sim_frames * 10} frames): true planes with >= 200 returns")
        print(f"{'method':>10} {'ms/frame':>9} {'planes/frame':>12} {'found':>9} {'recall':>7} {'normal deg':>10} {'offset m':>9}")
        rows = {"detcal": [], "RANSAC": [], "patches": []}
        for k in range(0, args.sim_frames * 10, 10):
            pts = sim.log.clouds.frame(k)
            ns, ds, ids = sim_truth(sim, k)
            (det, lab), ms = timed(lambda pts=pts: detect_planes(pts, prm, return_labels=True), 1)
            planes = [(det.normal[m], det.offset[m], np.flatnonzero(lab == m)) for m in range(len(det))]
            rows["detcal"].append((ms, len(det), *score(planes, ns, ds, ids)))
            if o3d is not None:
                p64 = pts[:, :3].astype(np.float64)
                rp, rms = timed(lambda p64=p64: o3d_ransac(o3d, p64, args.min_points, args.max_planes), 1)
                rows["RANSAC"].append((rms, len(rp), *score(rp, ns, ds, ids)))
                pp, pms = timed(lambda p64=p64: o3d_patches(o3d, p64), 1)
                rows["patches"].append((pms, len(pp), *score(pp, ns, ds, ids)))
        for name, r in rows.items():
            if not r:
                continue
            a = np.array(r, dtype=np.float64)
            f, t = a[:, 2].sum(), a[:, 3].sum()
            print(
                f"{name:>10} {np.median(a[:, 0]):>9.0f} {a[:, 1].mean():>12.1f} {int(f):>4}/{int(t):<4} {f / t:>7.3f} "
                f"{np.nanmedian(a[:, 4]):>10.3f} {np.nanmedian(a[:, 5]):>9.4f}"
            )


if __name__ == "__main__":
    main()
