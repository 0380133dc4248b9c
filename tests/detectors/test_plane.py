"""The plane detector against the street simulator's truth, synthetic planes, real KITTI frames and bad clouds."""

from __future__ import annotations

import numpy as np
import pytest

from detectors.geometry import compose
from detectors.geometry3d import chart_from_normal, normal_angle, wrap
from detectors.plane import check_cloud, detect_planes
from profiles.errors import DataError
from tests.conftest import shared


def frame_truth(sim, k):
    """Sensor-frame true planes (n, d) of frame k, the returns' primitive ids, and the cloud."""
    log = sim.log
    li = sim.config.lidar
    sp = compose(sim.frame_poses[k], np.array([li.mount.x, li.mount.y, li.mount.theta]))
    c, s = np.cos(sp[2]), np.sin(sp[2])
    n = log.planes.normal
    ns = np.column_stack([c * n[:, 0] + s * n[:, 1], -s * n[:, 0] + c * n[:, 1], n[:, 2]])
    ds = log.planes.offset - n @ np.array([sp[0], sp[1], li.height])
    flip = np.where(ds < 0, -1.0, 1.0)
    a, b = log.clouds.offsets[k], log.clouds.offsets[k + 1]
    return ns * flip[:, None], ds * flip, sim.labels[a:b], log.clouds.frame(k)


def test_detector_recovers_the_street_truth(small_street):
    """Done-when target on the simulator: >= 95 % of the true planes with >= 200 returns found, normal error median
    <= 1 deg, offset error median <= 3 cm. A plane counts as found when a detection takes at least half of its returns
    and is that plane (normal within 2 deg, offset within 10 cm): facades in one line are one infinite plane, and one
    detection finds them all."""
    found, total, ang, off = 0, 0, [], []
    for k in (0, 15, 30):
        ns, ds, ids, cloud = frame_truth(small_street, k)
        det, lab = detect_planes(cloud, return_labels=True)
        counts = np.bincount(ids[ids < len(ds)], minlength=len(ds))
        for p in np.flatnonzero(counts >= 200):
            total += 1
            got = lab[ids == p]
            got = got[got >= 0]
            if got.size < counts[p] / 2:
                continue
            m = np.bincount(got).argmax()
            a, o = np.degrees(normal_angle(det.normal[m], ns[p])), abs(det.offset[m] - ds[p])
            if a > 2.0 or o > 0.1:
                continue
            found += 1
            ang.append(a)
            off.append(o)
    assert total >= 30
    assert found / total >= 0.95, (found, total)
    assert np.median(ang) <= 1.0 and np.median(off) <= 0.03


def synthetic_wall(rng, n=3000, sigma=0.02, dist=8.0, tilt=0.3):
    """Points on a 6 m x 3 m wall at ``dist`` m whose normal is (cos tilt, sin tilt, 0), noise along the normal."""
    nrm = np.array([np.cos(tilt), np.sin(tilt), 0.0])
    u = np.array([-np.sin(tilt), np.cos(tilt), 0.0])
    a, b = rng.uniform(-3, 3, n), rng.uniform(-1.5, 1.5, n)
    pts = dist * nrm + a[:, None] * u + b[:, None] * np.array([0, 0, 1.0]) + rng.normal(0, sigma, n)[:, None] * nrm
    return pts, nrm, dist


def test_covariance_is_consistent_with_the_errors():
    """The reported chart covariance predicts the errors: over independent noise draws the mean squared
    Mahalanobis error (NEES) of (azimuth, elevation, offset) is chi-square with 3 dof, mean 3; with 60 draws the
    mean's standard deviation is sqrt(6 / 60) = 0.32, so [2.0, 4.0] is a +-3 sigma band."""
    rng = np.random.default_rng(5)
    nees = []
    for _ in range(60):
        pts, nrm, dist = synthetic_wall(rng)
        det = detect_planes(pts)
        assert len(det) == 1
        truth = chart_from_normal(nrm, dist)
        e = det.chart[0] - truth
        e[0] = wrap(e[0])
        nees.append(float(e @ np.linalg.solve(det.cov[0], e)))
    assert 2.0 <= np.mean(nees) <= 4.0, np.mean(nees)


def test_msse_rejects_outliers_next_to_the_plane():
    """900 points (30 %) scattered 0.15-0.6 m in front of one third of the wall, like a bush: their cells are not
    planar, lend their returns to the wall's region at its border, and MSSE keeps the wall's returns only."""
    rng = np.random.default_rng(6)
    pts, nrm, dist = synthetic_wall(rng, n=3000)
    u = np.array([-np.sin(0.3), np.cos(0.3), 0.0])
    part = pts[(pts - dist * nrm) @ u < -1.0]
    out = part[rng.integers(0, len(part), 900)] - rng.uniform(0.15, 0.6, 900)[:, None] * nrm
    det = detect_planes(np.vstack([pts, out]))
    big = int(np.argmax(det.inliers))
    assert np.degrees(normal_angle(det.normal[big], nrm)) < 0.3
    assert abs(det.offset[big] - dist) < 0.01
    assert 2800 <= det.inliers[big] <= 3000  # MSSE at T = 2.5 keeps about 98 % of Gaussian inliers, no outlier


def test_outline_area_and_rectangle():
    rng = np.random.default_rng(7)
    pts, nrm, dist = synthetic_wall(rng, n=6000, sigma=0.005)
    det = detect_planes(pts)
    assert det.area[0] == pytest.approx(18.0, rel=0.03)  # the convex hull of points filling a 6 x 3 m rectangle
    sides = sorted(np.linalg.norm(np.roll(det.rect[0], -1, 0) - det.rect[0], axis=1))
    assert np.allclose(sides, [3, 3, 6, 6], atol=0.1)
    assert np.abs(det.polygon(0) @ det.normal[0] - det.offset[0]).max() < 1e-9  # the outline lies in the plane


def test_bad_clouds_are_refused():
    good = np.random.default_rng(0).normal(size=(100, 4))
    bad = good.copy()
    bad[3, 1] = np.nan
    with pytest.raises(DataError, match=r"frame 7: point 3 has a NaN or infinite coordinate"):
        check_cloud(bad, "frame 7")
    with pytest.raises(DataError, match=r"cloud: empty frame \(no points\)"):
        detect_planes(np.zeros((0, 4)))
    with pytest.raises(DataError, match=r"expected an \(N, 3\) or \(N, 4\) array .*got shape \(100, 5\)"):
        detect_planes(np.zeros((100, 5)))


def test_kitti_frames():
    """Real HDL-64E frames: tens of planes each, and the ground under the sensor (KITTI's Velodyne is 1.73 m up)."""
    folder = shared("kitti_object/velodyne")
    for f in sorted(folder.glob("*.bin")):
        det = detect_planes(np.fromfile(f, dtype="<f4").reshape(-1, 4))
        assert len(det) >= 15
        big = np.argmax(np.where(np.abs(det.normal[:, 2]) > 0.99, det.inliers, 0))
        assert 1.4 <= det.offset[big] <= 1.9 and det.inliers[big] > 5000
