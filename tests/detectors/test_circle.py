import numpy as np
import pytest
from scipy.optimize import least_squares

from calib.sim.park import ParkConfig, World, cast_world, sensor_model, sensor_poses, simulate_park
from detectors.circle import detect_circles, fit_circles, segment
from detectors.raytrace import count_unoccluded
from profiles.schema import CircleDetectorParams, HotellingParams
from tests.conftest import small_park_config

ANG = np.linspace(-np.pi / 2, np.pi / 2, 361)


def trunk_scan(cx, cy, r, ang=ANG):
    d = np.column_stack([np.cos(ang), np.sin(ang)])
    proj = d @ np.array([cx, cy])
    disc = proj**2 - (cx * cx + cy * cy - r * r)
    return np.where(disc >= 0, proj - np.sqrt(np.maximum(disc, 0)), np.nan)


def test_noise_free_trunk_is_recovered_exactly():
    det = detect_circles(trunk_scan(6.0, -2.0, 0.35), ANG, CircleDetectorParams())
    assert len(det) == 1
    assert det.x[0] == pytest.approx(6.0, abs=1e-9) and det.y[0] == pytest.approx(-2.0, abs=1e-9)
    assert det.radius[0] == pytest.approx(0.35, abs=1e-9) and det.fit_error[0] < 1e-18
    assert det.range[0] == pytest.approx(np.hypot(6, -2)) and det.bearing[0] == pytest.approx(np.arctan2(-2, 6))
    assert det.convexity[0] > 0


def test_segmentation_breaks_on_jumps_and_missing_returns():
    r = np.full(20, np.nan)
    r[2:8] = 5.0
    r[8:12] = 9.0  # a jump of 4 m
    r[14:16] = 5.0  # too short
    r[17:20] = 5.0
    r[18] = np.nan  # a missing return splits 17..19 into pieces of one
    ang = np.linspace(-0.2, 0.2, 20)
    scan, beam, label, _, _ = segment(r[None], ang, jump=0.5, min_points=3)
    assert np.bincount(label).tolist() == [6, 4]
    assert beam[label == 1].tolist() == [8, 9, 10, 11]


def test_batched_lm_matches_scipy_least_squares_per_cluster():
    rng = np.random.default_rng(4)
    xs, ys, labels, firsts, lasts, truth = [], [], [], [], [], []
    for k in range(40):
        c = rng.uniform([3, -5], [20, 5])
        r = rng.uniform(0.08, 0.6)
        phi = np.arctan2(-c[1], -c[0]) + rng.uniform(-1.2, 1.2, rng.integers(4, 30))
        phi.sort()
        pts = c + r * np.column_stack([np.cos(phi), np.sin(phi)]) + rng.normal(0, 0.02, (phi.size, 2))
        xs.append(pts[:, 0]), ys.append(pts[:, 1]), labels.append(np.full(phi.size, k))
        firsts.append(pts[0]), lasts.append(pts[-1]), truth.append(pts)
    p, fe, _ = fit_circles(np.concatenate(labels), np.concatenate(xs), np.concatenate(ys), 40, np.array(firsts), np.array(lasts), 100)
    for k, pts in enumerate(truth):
        ref = least_squares(lambda q, pts=pts: np.hypot(*(pts - q[:2]).T) - q[2], p[k] + [0.01, -0.01, 0.005], method="lm", xtol=1e-14, ftol=1e-14)
        assert fe[k] <= 2 * ref.cost * (1 + 1e-6) + 1e-15  # scipy's cost is half the sum of squares
        np.testing.assert_allclose(p[k], [*ref.x[:2], abs(ref.x[2])], atol=1e-6)


@pytest.fixture(scope="module")
def sim_1cm():
    cfg = small_park_config()
    cfg.laser.range_sigma = 0.01
    return simulate_park(cfg, seed=21)


def test_fully_visible_trees_found_within_2cm(sim_1cm):
    sim, log = sim_1cm, sim_1cm.log
    gt = log.reference["ground_truth"]
    sp = sensor_poses(gt.poses[np.searchsorted(gt.stamp, log.scans.stamp)], log.sensor.mount)
    n_p, n_exp = count_unoccluded(sp, log.sensor.angles(), log.scans.ranges, sim.world.tree_xy, sim.world.tree_r, range_sigma=0.01, range_max=80)
    det = detect_circles(log.scans.ranges, log.sensor.angles(), CircleDetectorParams(), range_sigma=0.01)
    # true tree centres in each scan's sensor frame
    rel = sim.world.tree_xy[None, :, :] - sp[:, None, :2]
    c, s = np.cos(sp[:, 2])[:, None], np.sin(sp[:, 2])[:, None]
    tx, ty = c * rel[..., 0] + s * rel[..., 1], -s * rel[..., 0] + c * rel[..., 1]
    visible = (n_p == n_exp) & (n_p >= 5)
    scans, trees = np.nonzero(visible)
    centre_err, radius_err, found = [], [], 0
    for si, ti in zip(scans, trees, strict=True):
        mine = np.flatnonzero(det.scan == si)
        d = np.hypot(det.x[mine] - tx[si, ti], det.y[mine] - ty[si, ti])
        if d.size and d.min() < 0.5:
            j = mine[np.argmin(d)]
            found += 1
            centre_err.append(d.min())
            radius_err.append(abs(det.radius[j] - sim.world.tree_r[ti]))
    assert scans.size > 200
    assert found / scans.size > 0.97  # missing returns (1 %) can split a cluster; a few are lost
    # sigma_r = 1 cm per return; with >= 5 returns on a short arc the fit error of the centre is
    # of the order of sigma_r (the arc's short baseline amplifies it), so 2 cm is 2 sigma_r
    assert np.median(centre_err) <= 0.02 and np.median(radius_err) <= 0.02


def test_reruns_and_batching_give_identical_detections(sim_1cm):
    log = sim_1cm.log
    a = detect_circles(log.scans.ranges, log.sensor.angles(), CircleDetectorParams(), range_sigma=0.01)
    b = detect_circles(log.scans.ranges, log.sensor.angles(), CircleDetectorParams(), range_sigma=0.01)
    for f in a.__dataclass_fields__:
        np.testing.assert_array_equal(getattr(a, f), getattr(b, f))
    one = detect_circles(log.scans.ranges[7], log.sensor.angles(), CircleDetectorParams(), range_sigma=0.01)
    mine = a.scan == 7
    np.testing.assert_allclose(one.x, a.x[mine], atol=1e-12)
    np.testing.assert_allclose(one.radius, a.radius[mine], atol=1e-12)


def test_convexity_separates_corners_seen_from_inside_from_trunks():
    # the sensor stands inside right-angled corners (two 3 m walls meeting 7-10 m away, their
    # bisector pointing at the sensor); trunks stand in the open
    p0, p1 = [], []
    for phi, dist in [(0.4, 8.0), (2.0, 9.0), (-1.0, 10.0), (3.5, 7.0)]:
        corner = dist * np.array([np.cos(phi), np.sin(phi)])
        for side in (-1, 1):
            a = phi + np.pi + side * np.pi / 4
            p0.append(corner)
            p1.append(corner + 3.0 * np.array([np.cos(a), np.sin(a)]))
    rng = np.random.default_rng(2)
    bearing = np.array([1.2, -2.2, 2.75, -0.3, 0.9, -1.8, 1.5, -2.5])  # clear of the corners' directions
    trees = rng.uniform(4, 11, bearing.size)[:, None] * np.column_stack([np.cos(bearing), np.sin(bearing)])
    world = World(trees, rng.uniform(0.1, 0.4, trees.shape[0]), np.zeros((0, 2)), np.zeros(0), np.zeros((0, 2)), np.array([0]), np.array(p0), np.array(p1))
    sm = sensor_model(ParkConfig.model_validate({"laser": {"n_beams": 721, "fov_deg": 360.0, "range_sigma": 0.0}}))
    r, ids = cast_world(world, np.zeros(3), sm)
    r = np.where(np.isfinite(r), r, np.nan)
    det = detect_circles(r, sm.angles(), CircleDetectorParams(jump=0.3))
    hit_of = ids[det.first]
    wall = hit_of >= trees.shape[0]
    assert wall.sum() >= 4 and (~wall).sum() >= 6
    assert np.all(det.convexity[~wall] > 0)
    # a corner cluster holds returns of both of its walls; a single straight wall seen alone
    # fits a huge circle on either side and is no test of convexity
    both = np.array([np.unique(ids[a : b + 1]).size >= 2 for a, b in zip(det.first, det.last, strict=True)])
    corners = wall & both
    assert corners.sum() >= 3
    assert np.all(det.convexity[corners] < 0)


def test_hotelling_gate_keeps_exactly_the_inside():
    r = trunk_scan(6.0, -2.0, 0.35)
    r2 = trunk_scan(4.0, 3.0, 0.15)
    scan = np.where(np.isfinite(r), r, r2)
    full = detect_circles(scan, ANG, CircleDetectorParams())
    assert len(full) == 2
    h = HotellingParams(names=["radius"], mean=[0.35], covariance=[[0.01]], gamma=1.0)
    gated = detect_circles(scan, ANG, CircleDetectorParams(), hotelling=h)
    assert len(gated) == 1 and gated.radius[0] == pytest.approx(0.35)
    assert gated.maha2[0] == pytest.approx(0.0, abs=1e-12)
    # (0.15 - 0.35)^2 / 0.01 = 4 > gamma
    loose = HotellingParams(names=["radius"], mean=[0.35], covariance=[[0.01]], gamma=4.0 + 1e-6)
    assert len(detect_circles(scan, ANG, CircleDetectorParams(), hotelling=loose)) == 2


def test_measurement_covariance_matches_the_scatter_of_estimates():
    rng = np.random.default_rng(9)
    clean = trunk_scan(8.0, 1.0, 0.3)
    est = []
    covs = []
    for _ in range(300):
        noisy = clean + rng.normal(0, 0.01, clean.size)
        d = detect_circles(noisy, ANG, CircleDetectorParams(), range_sigma=0.01)
        est.append([d.range[0], d.bearing[0]])
        covs.append(d.cov[0])
    emp = np.cov(np.array(est).T)
    mean_cov = np.mean(covs, axis=0)
    # the linearised covariance predicts the Monte Carlo scatter within 30 % (300 samples: +-8 % s.e.)
    np.testing.assert_allclose(np.sqrt(np.diag(mean_cov)), np.sqrt(np.diag(emp)), rtol=0.3)
