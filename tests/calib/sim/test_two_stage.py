"""The two-stage scenario (Li & Yang 2022): its B-spline against its control polygon, the obstacle avoidance, the
features' motion and the detection statistics against the settings."""

import numpy as np
import pytest
from pydantic import ValidationError
from scipy.spatial import ConvexHull

from calib.sim.two_stage import DEGREE, TwoStageConfig, avoid, bspline, initial_path, simulate_two_stage, summary, truth_profile


def _cox_de_boor(knots: np.ndarray, i: int, k: int, u: float) -> float:
    """N_i,k(u) by the recursion of Li & Yang sec. 3.4 (degree k here; 0/0 = 0; the last span closed at u = 1)."""
    if k == 0:
        last = knots[i + 1] == knots[-1] and knots[i] < knots[i + 1]
        return 1.0 if knots[i] <= u < knots[i + 1] or (last and u == knots[-1]) else 0.0
    out = 0.0
    if knots[i + k] > knots[i]:
        out += (u - knots[i]) / (knots[i + k] - knots[i]) * _cox_de_boor(knots, i, k - 1, u)
    if knots[i + k + 1] > knots[i + 1]:
        out += (knots[i + k + 1] - u) / (knots[i + k + 1] - knots[i + 1]) * _cox_de_boor(knots, i + 1, k - 1, u)
    return out


def _hull_distance(pts: np.ndarray, o: np.ndarray) -> float:
    """Distance from o to the convex hull of pts (0 inside; a degenerate hull: to its segments)."""
    try:
        hull = ConvexHull(pts)
        if np.all(hull.equations[:, :2] @ o + hull.equations[:, 2] <= 0):
            return 0.0
        edges = [(pts[a], pts[b]) for a, b in hull.simplices]
    except Exception:  # collinear points: the polyline's segments
        edges = list(zip(pts[:-1], pts[1:], strict=True))
    best = np.inf
    for a, b in edges:
        t = np.clip(np.dot(o - a, b - a) / max(np.dot(b - a, b - a), 1e-12), 0.0, 1.0)
        best = min(best, float(np.hypot(*(a + t * (b - a) - o))))
    return best


def test_bspline_is_the_papers_sum_over_its_control_polygon():
    """C(u) = sum_i N_i,k(u) X(i) evaluated by the recursion equals the spline; it starts and ends at the polygon's
    ends; every point lies in the convex hull of the k + 1 control points of its span; a straight polygon gives a
    straight curve."""
    rng = np.random.default_rng(4)
    x = np.cumsum(rng.normal(0, 10, (12, 2)), axis=0)
    spl = bspline(x)
    for u in np.linspace(0.0, 1.0, 57):
        ref = sum(_cox_de_boor(spl.t, i, DEGREE, u) * x[i] for i in range(len(x)))
        np.testing.assert_allclose(spl(u), ref, atol=1e-9)
    np.testing.assert_allclose(spl(0.0), x[0], atol=1e-12)
    np.testing.assert_allclose(spl(1.0), x[-1], atol=1e-12)
    for u in np.linspace(0.0, 1.0, 301):
        span = min(int(np.searchsorted(spl.t, u, side="right")) - 1, len(x) - 1)
        hull = ConvexHull(x[span - DEGREE : span + 1])
        assert np.all(hull.equations[:, :2] @ spl(u) + hull.equations[:, 2] <= 1e-9)
    line = np.column_stack([np.linspace(0, 100, 9), np.linspace(5, 25, 9)])
    c = bspline(line)(np.linspace(0, 1, 50))
    np.testing.assert_allclose(c[:, 1], 5 + 0.2 * c[:, 0], atol=1e-9)


def test_avoidance_goes_round_each_obstacle():
    """Straight path through an obstacle and past another 20 m off: the detours start where the path first comes
    within sigma_min (eqs. 28-29), follow the circle of radius sigma_min, and rejoin the path where it leaves it."""
    path = np.column_stack([np.arange(0.0, 1001.0), np.zeros(1001)])
    obs = np.array([[300.0, 0.0], [700.0, -20.0], [500.0, 400.0]])
    out, arc, avoided = avoid(path, np.zeros(len(path), bool), obs, 50.0)
    assert avoided.tolist() == [True, True, False]
    d = np.hypot(*(out[:, None, :] - obs[None, :2]).transpose(2, 0, 1))
    assert np.all(d[:, :2] >= 50.0 - 1e-9)
    on_circle = np.abs(d[:, :2] - 50.0) < 1e-6
    assert on_circle[:, 0].sum() > 100 and on_circle[:, 1].sum() > 50  # pi * 50 m and the chord's arc, sampled every ~1 m
    # the first detour leaves the path at its last point outside the disc, x = 250 (the trigger), and rejoins at 350
    first = np.flatnonzero(on_circle[:, 0] & (np.abs(out[:, 1]) > 1e-9))
    np.testing.assert_allclose([out[first[0] - 1], out[first[-1] + 1]], [[250.0, 0.0], [350.0, 0.0]], atol=1e-9)
    # the obstacle 20 m below the path is passed above it (the side the path passes)
    assert np.all(out[on_circle[:, 1], 1] >= -20.0 - 1e-9)
    # the detours are arcs (the paper's CT motion), the straight path is not
    assert arc[np.abs(out[:, 1]) > 1e-9].all() and not arc[np.abs(out[:, 1]) < 1e-9].any()


@pytest.mark.parametrize("path", ["serpentine", "spiral"])
def test_run_follows_its_plan(path):
    """The initial path starts at the start (the serpentine ends at the far corner); the smoothed path keeps from
    every avoided obstacle at least the distance of the nearest convex hull of four consecutive control points (the
    convex-hull property) and, the corners it cuts being small, 85 % of sigma_min; the sensor's poses lie on the
    smoothed path, heading along it."""
    cfg = TwoStageConfig(path=path)
    run = simulate_two_stage(cfg, 3)
    init, _ = initial_path(cfg)
    np.testing.assert_allclose(init[0], cfg.start)
    if path == "serpentine":
        np.testing.assert_allclose(init[-1], cfg.end)
    assert run.obstacles[: cfg.on_path].all()  # features placed on the path are obstacles
    for o in run.features[0, run.obstacles, :2]:
        near = np.hypot(*(run.path - o).T).min()
        assert near >= 0.85 * cfg.safety_distance
        # (a span's hull lies within its extent of its control points: spans far from the obstacle cannot be nearest)
        dc = np.hypot(*(run.control - o).T)
        spans = [i for i in range(len(run.control) - DEGREE) if dc[i : i + DEGREE + 1].min() < near + 4 * cfg.spline_spacing]
        assert near >= min(_hull_distance(run.control[i : i + DEGREE + 1], o) for i in spans) - 1e-6
    poses = run.log.reference["ground_truth"].poses
    assert poses.shape == (cfg.steps, 3)
    assert np.hypot(*(run.path[None] - poses[:, None, :2]).transpose(2, 0, 1)).min(axis=1).max() < 1.0
    step = np.diff(poses[:, :2], axis=0)
    straight = np.hypot(*step.T) > 50  # (on arcs the heading turns within a step)
    ang = np.arctan2(step[:, 1], step[:, 0])
    dif = np.angle(np.exp(1j * (ang - poses[:-1, 2])))
    assert np.median(np.abs(dif[straight])) < 0.05


def test_speed_halves_on_arcs_and_a_given_speed_is_kept():
    """speed: null covers the whole path in the steps; a given speed drives the straight parts at it (Table 1: 2 m/s)
    and the arcs at half of it."""
    run = simulate_two_stage(TwoStageConfig(), 0)
    poses = run.log.reference["ground_truth"].poses
    np.testing.assert_allclose(poses[-1, :2], run.path[-1], atol=1e-6)
    slow = simulate_two_stage(TwoStageConfig(speed=2.0, steps=60), 0).log.reference["ground_truth"].poses
    v = np.hypot(*np.diff(slow[:, :2], axis=0).T)
    assert np.max(v) == pytest.approx(2.0, abs=1e-6)
    assert np.min(v) >= 1.0 - 0.05  # down to half speed where the path turns


def test_features_static_or_constant_velocity():
    """Static features keep their place; moving ones obey m_k+1 = F m_k + B v_k with the drawn accelerations of
    sigma 0.5 m/s^2 (the empirical sigma of v_k within 10 % over 10 features x 99 steps x 2 axes)."""
    cfg = TwoStageConfig()
    st = simulate_two_stage(cfg, 1).features
    assert np.all(st == st[:1]) and not st[:, :, 2:].any()
    mv = simulate_two_stage(TwoStageConfig(moving=True), 1).features
    acc = np.diff(mv[:, :, 2:], axis=0)  # dt = 1: v_k
    np.testing.assert_allclose(np.diff(mv[:, :, :2], axis=0), mv[:-1, :, 2:] + 0.5 * acc, atol=1e-9)
    assert np.std(acc) == pytest.approx(0.5, rel=0.1)
    np.testing.assert_allclose(np.hypot(*mv[0, :, 2:].T), 1.0)


def test_detections_follow_pd_and_clutter():
    """Over 20 seeded runs: the share of in-radius features detected is P_D = 0.98 within 4 binomial standard
    errors, the false alarms per scan those of 20 uniform over S inside the disc (area ratio) within 4 Poisson
    standard errors; with clutter_area disc, 20 per scan."""
    hits = chances = fa = 0
    fa_disc = 0
    for seed in range(20):
        cfg = TwoStageConfig()
        run = simulate_two_stage(cfg, seed)
        poses = run.log.reference["ground_truth"].poses
        r = np.hypot(*(run.features[:, :, :2] - poses[:, None, :2]).transpose(2, 0, 1))
        lab = np.asarray(run.log.detections.descriptors["landmark"])
        chances += int((r <= cfg.detection_radius).sum())
        hits += int((lab > 0).sum())
        fa += int((lab == 0).sum())
        fa_disc += summary(simulate_two_stage(TwoStageConfig(clutter_area="disc", steps=20), seed), TwoStageConfig(steps=20))["false_alarms"]
    p = hits / chances
    assert abs(p - 0.98) < 4 * np.sqrt(0.98 * 0.02 / chances)
    # inside the disc of a sensor well inside S the expected count is 20 x area share (the path keeps within S)
    lam = 20 * np.pi * 150.0**2 / 2000.0**2 * 20 * 100
    assert abs(fa - lam) < 4 * np.sqrt(lam)
    assert abs(fa_disc - 20 * 20 * 20) < 4 * np.sqrt(20 * 20 * 20)


def test_same_seed_same_log_and_profile():
    a, b = simulate_two_stage(TwoStageConfig(moving=True), 9), simulate_two_stage(TwoStageConfig(moving=True), 9)
    np.testing.assert_array_equal(a.features, b.features)
    np.testing.assert_array_equal(a.log.detections.range, b.log.detections.range)
    np.testing.assert_array_equal(a.log.odometry.values, b.log.odometry.values)
    prof = truth_profile(TwoStageConfig())
    assert prof.pd.pd == [0.98, 0.0] and prof.clutter.space == "xy"
    assert prof.clutter.kappa == pytest.approx(20 / 2000.0**2)


@pytest.mark.parametrize(
    ("settings", "match"),
    [
        ({"on_path": 11}, "on_path .* must not exceed features"),
        ({"safety_distance": 150.0}, "safety_distance .* below half the lane spacing"),
        ({"end": (-900.0, 800.0)}, "must lie above and to the right of start"),
        ({"pd": 1.5}, "less than or equal to 1"),
    ],
)
def test_bad_settings_are_refused(settings, match):
    with pytest.raises(ValidationError, match=match):
        TwoStageConfig(**settings)
