"""The paper's evaluation of the plane transition model (Gostar et al., Sensors 2019, Tables 1-6) on simulated
consecutive frames, and Algorithm 1's throughput.

1. Throughput: Algorithm 1 (``slam_runtime.plane_transition.algorithm1``) on L planes x N particles
   (x P vehicle hypotheses), plane-particles per second (the issue's target: >= 10^6).
2. Tables: the KITTI drive the paper used (0005, frames 11/12 and 124/125) is not available here, so the same
   frame numbers of a simulated street (HDL-64E-like, 10 Hz) stand in. At frame k the plane detector segments
   the cloud; each plane becomes N particles drawn from its fit covariance, in the vehicle frame; Algorithm 1
   moves them to k+1 with the vehicle state at k (true pose, velocity from the odometry reading) and one ECT
   noise sample per Monte Carlo run; the EAP plane and its outline (eq. 31) are compared with the planes
   segmented at k+1 (area, the four vertex distances, the normal angle; averaged over the runs, as the paper's
   100), and both with the simulator's true planes at k+1.

    python benchmarks/bench_plane_transition.py [--seed 1] [--runs 100] [--particles 100]
"""

from __future__ import annotations

import argparse
import os
import time

import numpy as np

from calib.plane_eval import compare
from calib.sim.street import StreetConfig, simulate_street
from detectors.geometry3d import beta_from_hesse, hesse_from_beta, normal_angle, normal_from_chart, orient_away, pose_matrix, transform_points
from detectors.plane import detect_planes
from slam_runtime.ect import ECT, POSE
from slam_runtime.plane_transition import algorithm1


def throughput(rng) -> None:
    ect = ECT()
    print("Algorithm 1 throughput (eq. 35 with the ECT model, EAP per plane):")
    print(f"{'vehicle P':>9} {'planes L':>8} {'particles N':>11} {'ms/step':>8} {'plane-particles/s':>18}")
    for p, l_, n in ((1, 10, 1000), (1, 100, 1000), (1, 100, 10000), (10, 50, 2000)):
        x = ECT().initial(np.array([0.0, 0.0, 0.1]), p)
        x[:, 1] = 7.0
        b = beta_from_hesse(*_unit(rng, (l_, n)))
        w = np.ones((l_, n))
        algorithm1(ect, x, b, w, 0.1, rng)
        reps = 5
        t0 = time.perf_counter()
        for _ in range(reps):
            algorithm1(ect, x, b, w, 0.1, rng)
        dt = (time.perf_counter() - t0) / reps
        print(f"{p:>9} {l_:>8} {n:>11} {dt * 1e3:>8.1f} {p * l_ * n / dt:>18,.0f}")


def _unit(rng, shape):
    n = rng.normal(size=shape + (3,))
    return n / np.linalg.norm(n, axis=-1, keepdims=True), rng.uniform(1, 30, shape)


def mount_matrix(li) -> np.ndarray:
    return pose_matrix(np.array([li.mount.x, li.mount.y, li.mount.theta]), li.height)


def evaluate_pair(sim, k: int, runs: int, particles: int, rng, top: int = 3):
    """Tables for frames k -> k+1 (vehicle frame), averaged over ``runs`` Monte Carlo runs of Algorithm 1."""
    log, li = sim.log, sim.config.lidar
    tm = mount_matrix(li)  # sensor -> vehicle
    a = detect_planes(log.clouds.frame(k))
    b = detect_planes(log.clouds.frame(k + 1))
    # to the vehicle frame: beta_v^T = beta_s^T T^-1, points r_v = T r_s
    tinv = np.linalg.inv(tm)

    def to_vehicle(det):
        n, d = orient_away(*hesse_from_beta(beta_from_hesse(det.normal, det.offset) @ tinv))
        return n, d, transform_points(det.rect.reshape(-1, 3), tm).reshape(det.rect.shape)

    na, da, ra = to_vehicle(a)
    nb, db, rb = to_vehicle(b)
    # the largest landmark planes at k (steep: the ground and roofs say nothing of a planar motion; the paper's
    # pairs are facades)
    steep = np.flatnonzero(np.abs(na[:, 2]) <= np.sin(np.radians(45.0)))
    keep = steep[np.argsort(-a.area[steep], kind="stable")][: max(top * 4, 12)]
    # particles of each plane from its fit covariance (sensor-frame chart), then to the vehicle frame
    z = a.chart[keep][:, None, :] + np.einsum("lij,lnj->lni", np.linalg.cholesky(a.cov[keep] + 1e-15 * np.eye(3)), rng.standard_normal((keep.size, particles, 3)))
    ns, ds = normal_from_chart(z)
    beta = beta_from_hesse(ns, ds) @ tinv
    w = np.ones((keep.size, particles))
    gt = log.reference["ground_truth"]
    t_k = log.clouds.stamp[k]
    i = int(np.searchsorted(gt.stamp, t_k))
    ect = ECT()
    x = ect.initial(gt.poses[i], 1)
    reading = log.odometry.values[int(np.searchsorted(log.odometry.stamp, t_k, side="right")) - 1]
    dt = (log.clouds.stamp[k + 1] - t_k) / 1e9
    tables, ms = [], []
    for _ in range(runs):
        t0 = time.perf_counter()
        x1, b1, _, eap = algorithm1(ect, x, beta, w, dt, rng, reading=reading)
        ms.append((time.perf_counter() - t0) * 1e3)
        pn, pd_ = orient_away(*hesse_from_beta(eap[0]))
        m = np.linalg.inv(pose_matrix(x1[0, list(POSE)])) @ pose_matrix(ect.with_velocity(x, reading, None)[0, list(POSE)])
        rect1 = transform_points(ra[keep].reshape(-1, 3), m).reshape(-1, 4, 3)
        tables.append(compare(pn, pd_, rect1, a.area[keep], nb, db, rb, b.area))
    # pairs that were made in every run, the largest first
    common = set(tables[0]["predicted"])
    for t in tables[1:]:
        common &= set(t["predicted"])
    allpairs = tables[0]
    med = (float(allpairs["normal_angle_deg"].median()), float(np.median(allpairs.filter(like="vertex_").to_numpy()))) if len(allpairs) else (np.nan, np.nan)
    rows = []
    for p in sorted(common, key=lambda q: -a.area[keep][q])[:top]:
        r = [t[t["predicted"] == p].iloc[0] for t in tables]
        mean = {c: float(np.mean([x_[c] for x_ in r])) for c in r[0].index if c not in ("predicted", "segmented")}
        rows.append((p, int(r[0]["segmented"]), mean))
    # against the truth at k+1 (vehicle frame): the true planes' normals and offsets
    pose1 = gt.poses[int(np.searchsorted(gt.stamp, log.clouds.stamp[k + 1]))]
    n_t, d_t = orient_away(*hesse_from_beta(beta_from_hesse(log.planes.normal, log.planes.offset) @ pose_matrix(pose1)))
    truth_rows = []
    x1, b1, _, eap = algorithm1(ect, x, beta, w, dt, rng, reading=reading)
    pn, pd_ = orient_away(*hesse_from_beta(eap[0]))
    for p, s_, _ in rows:
        cand = np.argmin(np.degrees(normal_angle(nb[s_], n_t)) + 10 * np.abs(db[s_] - d_t))
        truth_rows.append(
            (np.degrees(normal_angle(pn[p], n_t[cand])), abs(pd_[p] - d_t[cand]), np.degrees(normal_angle(nb[s_], n_t[cand])), abs(db[s_] - d_t[cand]))
        )
    return rows, truth_rows, float(np.median(ms)), keep.size, med


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--runs", type=int, default=100)
    ap.add_argument("--particles", type=int, default=100)
    args = ap.parse_args()
    print(f"load average: {os.getloadavg()[0]:.2f} on {os.cpu_count()} cores\n")
    rng = np.random.default_rng(0)
    throughput(rng)
    sim = simulate_street(StreetConfig(frames=127), args.seed)
    for k in (11, 124):
        rows, truth, ms, n_planes, med = evaluate_pair(sim, k, args.runs, args.particles, rng)
        print(f"\nframes {k} -> {k + 1} (street seed {args.seed}; {args.runs} Monte Carlo runs; Algorithm 1 on {n_planes} planes x "
              f"{args.particles} particles: {ms:.2f} ms per step, median)")
        head = "".join(f"{'pair ' + str(i + 1):>12}" for i in range(len(rows)))
        print(f"{'':26}{head}")
        print(f"{'area predicted [m^2]':26}" + "".join(f"{r[2]['area_predicted']:>12.3f}" for r in rows))
        print(f"{'area segmented [m^2]':26}" + "".join(f"{r[2]['area_segmented']:>12.3f}" for r in rows))
        for q in range(4):
            print(f"{'vertex pair ' + str(q + 1) + ' [m]':26}" + "".join(f"{r[2][f'vertex_{q + 1}_m']:>12.4f}" for r in rows))
        print(f"{'normal angle [deg]':26}" + "".join(f"{r[2]['normal_angle_deg']:>12.4f}" for r in rows))
        print(f"{'predicted vs truth [deg]':26}" + "".join(f"{t[0]:>12.4f}" for t in truth))
        print(f"{'predicted vs truth [m]':26}" + "".join(f"{t[1]:>12.4f}" for t in truth))
        print(f"{'segmented vs truth [deg]':26}" + "".join(f"{t[2]:>12.4f}" for t in truth))
        print(f"{'segmented vs truth [m]':26}" + "".join(f"{t[3]:>12.4f}" for t in truth))
        print(f"all {n_planes} landmark planes at k, one run: median normal angle {med[0]:.4f} deg, median vertex distance {med[1]:.3f} m")


if __name__ == "__main__":
    main()
