"""The batch oracle: its Jacobians against finite differences, the truth recovered without noise, and its
posterior consistent with the simulators' truth over seeded worlds (what lets it judge a filter)."""

import numpy as np
import pytest

from calib.sim import glmb_paper, rfs
from calib.sim.glmb_paper import GlmbPaperConfig, simulate_glmb_paper
from calib.sim.rfs import RfsSimConfig, simulate_rfs
from profiles.errors import DataError, UsageError
from slam_runtime.oracle import (
    _Mixture,
    _problem,
    batch_oracle,
    clutter_information_ratio,
    clutter_oracle,
    mahalanobis2,
    map_distance,
    posterior_samples,
    rb_map_samples,
)
from slam_runtime.oracle_factors import Blocks, ackermann_factors, increment_factors, range_bearing_factors


def _rfs_oracle(cfg: RfsSimConfig, seed: int, odometry_sigma: float | None = None):
    log = simulate_rfs(cfg, seed)
    noise = rfs.oracle_noise(cfg)
    if odometry_sigma is not None:
        noise["odometry_sigma"] = (odometry_sigma,) * 3
    return log, batch_oracle(log, **noise)


def _coverage(runs) -> tuple[list[float], list[float]]:
    """For (log, oracle) pairs: the true last position's d2 against the oracle, and the detected landmarks'
    squared Mahalanobis error over its degrees of freedom."""
    d2, ratio = [], []
    for log, res in runs:
        d2.append(mahalanobis2(res, log.reference["ground_truth"].poses[-1]))
        e = (res.landmarks[res.detected] - log.landmarks.xy[res.detected]).ravel()
        ratio.append(e @ np.linalg.solve(res.landmark_cov, e) / e.size)
    return d2, ratio


def _numeric_jacobian(fun, v, h=1e-7):
    r0 = fun(v)
    out = np.zeros((r0.size, v.size))
    for i in range(v.size):
        d = np.zeros_like(v)
        d[i] = h
        out[:, i] = (fun(v + d) - fun(v - d)) / (2 * h)
    return out


def test_the_factors_jacobians_match_finite_differences():
    rng = np.random.default_rng(0)
    n, nl = 6, 3
    x = np.column_stack([rng.uniform(-2, 2, n), rng.uniform(-2, 2, n), rng.uniform(-3, 3, n)])
    ctrl = np.column_stack([rng.uniform(0.5, 1.5, n - 1), rng.uniform(-0.4, 0.4, n - 1)])
    lm = rng.uniform(-5, 5, (nl, 2)) + 6.0
    odo = rng.normal(0, 0.1, (n, 3))
    k_of, lj = np.array([0, 1, 3, 5, 5]), np.array([0, 2, 1, 0, 2])
    zr, zb = rng.uniform(1, 5, 5), rng.uniform(-1, 1, 5)
    dts = np.full(n - 1, 0.1)
    nx, nc = 3 * n, 2 * (n - 1)
    v0 = np.concatenate([x.ravel(), ctrl.ravel(), lm.ravel()])

    def residuals(v, with_jac=False):
        xx, cc, ll = v[:nx].reshape(n, 3), v[nx : nx + nc].reshape(-1, 2), v[nx + nc :].reshape(nl, 2)
        b = Blocks()
        increment_factors(b, xx, odo, np.array([0.1, 0.2, 0.05]))
        ackermann_factors(b, xx, cc, odo[:-1, :2], dts, 2.5, np.array([0.1, 0.03]), nx)
        range_bearing_factors(b, xx, ll, k_of, lj, zr, zb, 0.2, 0.02, nx + nc)
        jac, res = b.build(v.size)
        return (jac.toarray(), res) if with_jac else res

    jac, _ = residuals(v0, True)
    num = _numeric_jacobian(residuals, v0)
    scale = np.maximum(np.abs(num), 1.0)
    np.testing.assert_array_less(np.abs(jac - num) / scale, 1e-4)


def test_without_noise_the_oracle_is_the_truth():
    cfg = RfsSimConfig(steps=200, var_odometry=0.0, var_range=1e-14, var_bearing=1e-14)
    log, res = _rfs_oracle(cfg, 3, odometry_sigma=1e-9)  # the simulator adds none; the solver needs a scale
    assert res.converged
    truth = log.reference["ground_truth"].poses
    np.testing.assert_allclose(res.poses, truth, atol=1e-6)
    np.testing.assert_allclose(res.landmarks[res.detected], log.landmarks.xy[res.detected], atol=1e-6)


@pytest.mark.slow  # a batch solve over a whole rfs-sim run, several seeds
def test_the_oracles_posterior_covers_the_truth_as_it_states_rfs_sim():
    """20 seeded rfs-sim worlds of 300 steps: the true final position's squared Mahalanobis distance from the
    MAP under the stated covariance is chi-square(2) if the posterior is right (mean 2; the mean of 20 has a
    standard deviation of 0.45: [0.9, 3.1] is 2.5 of them either way), and the detected landmarks' is
    chi-square with 2 per landmark (the ratio to its degrees of freedom: mean 1, within 12 %)."""
    cfg = RfsSimConfig(steps=300)
    d2, ratio = _coverage(_rfs_oracle(cfg, 100 + seed) for seed in range(20))
    assert 0.9 <= np.mean(d2) <= 3.1
    assert 0.88 <= np.mean(ratio) <= 1.12


@pytest.mark.slow  # end to end: whole simulated runs, tens of CPU seconds; make test-slow (CI) runs it
def test_the_oracles_posterior_covers_the_truth_as_it_states_glmb_paper():
    """Ackermann controls (glmb-paper, 10 worlds): the same chi-square(2) check of the last position (the
    mean of 10 has a standard deviation of 0.63: [0.45, 3.55] is 2.5 of them either way) and the landmarks'
    ratio within 15 %."""
    cfg = GlmbPaperConfig(clutter=1.0)

    def solved(seed):
        log = simulate_glmb_paper(cfg, 200 + seed)
        return log, batch_oracle(log, **glmb_paper.oracle_noise(cfg))

    d2, ratio = _coverage(solved(seed) for seed in range(10))
    assert 0.45 <= np.mean(d2) <= 3.55
    assert 0.85 <= np.mean(ratio) <= 1.15


def test_a_log_without_labelled_detections_is_refused():
    log = simulate_rfs(RfsSimConfig(steps=100), 1)
    log.detections.descriptors.pop("landmark")
    with pytest.raises(DataError, match="rfs_sim_1: the detections carry no 'landmark' label"):
        batch_oracle(log, odometry_sigma=(0.01, 0.01, 0.01), range_sigma=0.02, bearing_sigma=0.007)


def test_the_marginals_are_the_blocks_of_the_inverse_information():
    """The last pose's and the landmarks' covariances are read from the right rows: against a dense inverse of
    the information matrix on a short run."""
    _, res = _rfs_oracle(RfsSimConfig(steps=80, landmarks=4), 7)
    full = np.linalg.inv(res.information.toarray())
    n = res.poses.shape[0]
    np.testing.assert_allclose(res.final_cov, full[3 * n - 3 : 3 * n, 3 * n - 3 : 3 * n], rtol=1e-6, atol=1e-15)
    np.testing.assert_allclose(res.landmark_cov, full[3 * n :, 3 * n :], rtol=1e-6, atol=1e-15)
    lm = res.information.toarray()[3 * n :, 3 * n :]
    np.testing.assert_allclose(res.landmark_cov_given_path[:2, :2], np.linalg.inv(lm[:2, :2]), rtol=1e-9)


def test_the_samples_have_the_stated_moments():
    """posterior_samples and rb_map_samples draw with the stated means and covariances (20,000 draws: the
    sample mean within 4 standard errors, the sample covariance within 5 %)."""
    _, res = _rfs_oracle(RfsSimConfig(steps=300), 11)
    rng = np.random.default_rng(0)
    fin, lms = posterior_samples(res, rng, 20000)
    sd = np.sqrt(np.diag(res.final_cov[:2, :2]))
    assert np.all(np.abs(fin.mean(axis=0) - res.poses[-1, :2]) < 4 * sd / np.sqrt(20000))
    np.testing.assert_allclose(np.cov(fin.T), res.final_cov[:2, :2], rtol=0.05, atol=0.05 * sd.max() ** 2)
    flat = lms.reshape(20000, -1)
    np.testing.assert_allclose(np.diag(np.cov(flat.T)), np.diag(res.landmark_cov), rtol=0.05)
    rb = rb_map_samples(res, rng, 20000).reshape(20000, -1)
    np.testing.assert_allclose(np.diag(np.cov(rb.T)), np.diag(res.landmark_cov - res.landmark_cov_given_path), rtol=0.05)


def test_map_distance_of_posterior_and_rb_draws():
    """A map drawn from the posterior sits 1 from the mode on average (the mean of 200 draws within 5 %); an ideal
    RB particle's map nearer (below 0.8 here); a map 0.6 m off every landmark pairs none."""
    _, res = _rfs_oracle(RfsSimConfig(steps=300), 12)
    rng = np.random.default_rng(1)
    _, lms = posterior_samples(res, rng, 200)
    post = np.mean([map_distance(res, m)[0] for m in lms])
    rb = np.mean([map_distance(res, m)[0] for m in rb_map_samples(res, rng, 200)])
    assert 0.95 <= post <= 1.05
    assert rb < 0.8
    assert map_distance(res, res.landmarks[res.detected] + 0.6) == (pytest.approx(float("nan"), nan_ok=True), 0)


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        (
            {"odometry_sigma": (0.01, 0.01)},
            r"odometry_sigma of increment odometry is 3 positive numbers \(dx, dy, dtheta\), not \(0.01, 0.01\)",
        ),
        ({"odometry_sigma": (0.01, 0.0, 0.01)}, "odometry_sigma of increment odometry is 3 positive numbers"),
        ({"range_sigma": 0.0}, "oracle: range_sigma must be a positive number, not 0.0"),
        ({"iterations": 0}, "oracle: iterations must be at least 1, not 0"),
    ],
)
def test_bad_settings_are_refused_naming_them(kwargs, message):
    log = simulate_rfs(RfsSimConfig(steps=100), 1)
    args = {"odometry_sigma": (0.01, 0.01, 0.01), "range_sigma": 0.02, "bearing_sigma": 0.007, **kwargs}
    with pytest.raises(UsageError, match=message):
        batch_oracle(log, **args)


def test_a_label_that_is_no_landmark_is_refused():
    log = simulate_rfs(RfsSimConfig(steps=100), 1)
    lab = np.asarray(log.detections.descriptors["landmark"])
    lab[np.flatnonzero(lab > 0)[0]] = 999
    with pytest.raises(DataError, match="rfs_sim_1: detection label 999 is no landmark of the log's truth"):
        batch_oracle(log, odometry_sigma=(0.01, 0.01, 0.01), range_sigma=0.02, bearing_sigma=0.007)


def _ratio_by_finite_differences(pd: float, density: float, rng: np.random.Generator, n: int, window: float = 10.0) -> float:
    """An independent reference: scan by scan, the score of the scan's log-likelihood by central differences."""
    h = 1e-4
    total = 0.0
    for _ in range(n):
        z = rng.uniform(-window, window, size=(rng.poisson(density * (2 * window) ** 2), 2))
        if rng.random() < pd:
            z = np.vstack([z, rng.standard_normal(2)])

        ll = [np.log((1 - pd) + pd / density * np.sum(np.exp(-0.5 * ((z - [x, 0.0]) ** 2).sum(axis=1)) / (2 * np.pi))) for x in (h, -h)]
        total += ((ll[0] - ll[1]) / (2 * h)) ** 2
    return total / n / pd


def test_clutter_information_ratio_against_finite_differences():
    """No clutter: all the information (exactly 1; and 1 within Monte Carlo error for a detector that never
    misses with a vanishing clutter). Under the glmb-paper scenario's clutter (P_D 0.7; 1, 5, 15 false alarms
    per scan over 0-3 m and the full circle, whitened by 0.3 m x 2 deg) it falls with the clutter and agrees
    with a scan-by-scan reference that differentiates the likelihood numerically, to within 0.04 (three
    standard errors of the reference's 8,000 scans)."""
    assert clutter_information_ratio(0.7, 0.0, np.random.default_rng(0)) == 1.0
    assert clutter_information_ratio(1.0, 1e-6, np.random.default_rng(0)) == pytest.approx(1.0, abs=0.02)
    got = []
    for c in (1.0, 5.0, 15.0):
        dens = c / (3.0 * 2 * np.pi) * 0.3 * np.radians(2.0)
        q = clutter_information_ratio(0.7, dens, np.random.default_rng(1))
        assert q == pytest.approx(_ratio_by_finite_differences(0.7, dens, np.random.default_rng(2), 8000), abs=0.04)
        got.append(q)
    assert 1.0 > got[0] > got[1] > got[2] > 0.5
    with pytest.raises(UsageError, match="pd must be"):
        clutter_information_ratio(0.0, 0.1, np.random.default_rng(0))
    with pytest.raises(UsageError, match="density must be"):
        clutter_information_ratio(0.7, float("nan"), np.random.default_rng(0))


def _clutter_solved(cfg: GlmbPaperConfig, seed: int, **kw):
    log = simulate_glmb_paper(cfg, seed)
    kappa = cfg.clutter / ((cfg.range_max - cfg.range_min) * 2 * np.pi) if cfg.clutter else 1e-12
    args = {**glmb_paper.oracle_noise(cfg), "pd": cfg.pd, "clutter_density": kappa, "range_max": cfg.range_max, **kw}
    return log, clutter_oracle(log, **args)


def test_the_clutter_oracle_without_false_alarms_is_the_labelled_oracle():
    """No false alarms and a vanishing clutter intensity: every gated measurement is its landmark's for certain
    (responsibility 1), so the mode is the labelled oracle's and the association doubt removes no information.
    The view reaches as far as a report can (the labelled oracle uses a landmark's detections past the 3 m
    detection range too), and the gate is 5 sigma: with no clutter to explain it, a measurement 5.3-5.7 sigma
    from another landmark that missed its scan would be that landmark's too (each landmark's term is its own:
    two close landmarks of this world, at two scans; with the scenario's clutter such a pair weighs 1e-6)."""
    cfg = GlmbPaperConfig(clutter=0.0)
    log, res = _clutter_solved(cfg, 3, range_max=glmb_paper.reach(cfg), gate=25.0)
    ref = batch_oracle(log, **glmb_paper.oracle_noise(cfg))
    assert res.converged
    np.testing.assert_allclose(res.poses, ref.poses, atol=1e-7)
    np.testing.assert_allclose(res.landmarks, ref.landmarks, atol=1e-7)
    np.testing.assert_allclose(res.landmark_cov, ref.landmark_cov, rtol=1e-5, atol=1e-9)
    assert res.own_weight == pytest.approx(1.0, abs=1e-6)
    assert res.false_weight == 0.0 and res.stray_weight == pytest.approx(0.0, abs=1e-9)
    assert res.information_loss == pytest.approx(0.0, abs=1e-6)


def test_the_clutter_oracles_information_is_the_mixtures_curvature():
    """At the mode under 15 false alarms per scan, each landmark's block of the information matrix is the
    negative Hessian of the measurements' mixture log-likelihood in that landmark (central differences; the
    motion terms do not involve the landmarks) within 5 % (the Gauss-Newton part drops the residuals' second
    derivatives: 1-2 % here). Without the missing information of the associations (Louis) the blocks are 10-50 %
    too large, so this checks that correction."""
    cfg = GlmbPaperConfig(clutter=15.0)
    log, res = _clutter_solved(cfg, 201)
    assert res.converged and 0.1 < res.information_loss < 0.4
    noise = glmb_paper.oracle_noise(cfg)
    prob = _problem(log, noise["odometry_sigma"])
    x, lm = res.poses, res.landmarks[res.detected]
    kappa = cfg.clutter / (cfg.range_max * 2 * np.pi)
    mix = _Mixture(log, prob, x, lm, cfg.pd, kappa, 0.0, cfg.range_max, noise["range_sigma"], noise["bearing_sigma"], 36.0)
    nx, nc, _ = prob.sizes
    h = 1e-4

    def ll(j, d):
        m = lm.copy()
        m[j] += d
        return mix.pairs(x, m)[-1]

    for j in range(0, lm.shape[0], 4):
        num = np.zeros((2, 2))
        for a in range(2):
            for b in range(2):
                ea, eb = np.eye(2)[a] * h, np.eye(2)[b] * h
                num[a, b] = -(ll(j, ea + eb) - ll(j, ea - eb) - ll(j, eb - ea) + ll(j, -ea - eb)) / (4 * h * h)
        i = nx + nc + 2 * j
        blk = res.information[i : i + 2, i : i + 2].toarray()
        assert np.linalg.norm(blk - num) <= 0.05 * np.linalg.norm(num), (j, blk, num)


@pytest.mark.slow  # end to end: whole simulated runs, tens of CPU seconds; make test-slow (CI) runs it
def test_the_clutter_oracles_posterior_covers_the_truth_as_it_states():
    """8 glmb-paper worlds under 15 false alarms per scan, the associations not given: the detected landmarks'
    squared Mahalanobis error over its degrees of freedom has mean 1 if the stated posterior is right (46 or so
    degrees of freedom per world: the mean of 8 has a standard deviation of about 0.06; [0.85, 1.15] is 2.5 of
    them either way). Without the associations' missing information it is 1.19 on these worlds (overconfident);
    the true last position's d2 is chi-square(2) (the mean of 8: [0.3, 3.7])."""
    cfg = GlmbPaperConfig(clutter=15.0)
    d2, ratio = _coverage(_clutter_solved(cfg, 200 + seed) for seed in range(8))
    assert 0.3 <= np.mean(d2) <= 3.7
    assert 0.85 <= np.mean(ratio) <= 1.15


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"pd": 1.0}, r"clutter oracle: pd must be in \(0, 1\), not 1.0"),
        ({"clutter_density": 0.0}, "clutter oracle: clutter_density must be a positive number, not 0.0"),
        ({"range_min": 3.0}, "clutter oracle: need 0 <= range_min < range_max, not 3.0, 3.0"),
        ({"gate": float("nan")}, "clutter oracle: gate must be a positive number, not nan"),
        ({"bearing_sigma": -1.0}, "oracle: bearing_sigma must be a positive number, not -1.0"),
    ],
)
def test_bad_clutter_oracle_settings_are_refused_naming_them(kwargs, message):
    cfg = GlmbPaperConfig(clutter=1.0)
    log = simulate_glmb_paper(cfg, 1)
    args = {**glmb_paper.oracle_noise(cfg), "pd": 0.7, "clutter_density": 0.05, "range_max": 3.0, **kwargs}
    with pytest.raises(UsageError, match=message):
        clutter_oracle(log, **args)


def _log_oracle_inputs(cfg: RfsSimConfig, seed: int):
    """An rfs-sim log, the increment model with the simulator's per-step noise (a_* = 0: the sigma per step as a
    random walk of s / sqrt(dt) per second), and the labels in log_oracle's form (-1 for a false alarm)."""
    from slam_runtime.vehicle import OdometryIncrement

    log = simulate_rfs(cfg, seed)
    noise = rfs.oracle_noise(cfg)
    s = noise["odometry_sigma"][0] / np.sqrt(cfg.dt)
    veh = OdometryIncrement(a_trans=0.0, a_rot=0.0, a_rot_trans=0.0, lateral=0.0, s_x=s, s_y=s, s_theta=s)
    lab = np.asarray(log.detections.descriptors["landmark"])
    return log, noise, veh, np.where(lab > 0, lab, -1)


def test_the_log_oracle_is_the_batch_oracle_where_both_apply():
    """On a simulated log with every detection labelled, the log oracle (poses at the frames, the odometry between
    them as the filter's vehicle model predicts it, solved a window at a time) finds the batch oracle's mode: the
    same poses at the frames and the same landmarks, to 1 mm (both minimise the same least squares; the Huber loss
    set beyond every residual)."""
    from slam_runtime.oracle import log_oracle

    cfg = RfsSimConfig(steps=300)
    log, noise, veh, labels = _log_oracle_inputs(cfg, 3)
    ref = batch_oracle(log, **noise)
    res = log_oracle(log, veh, labels, range_sigma=noise["range_sigma"], bearing_sigma=noise["bearing_sigma"], huber=1e9, window=5.0)
    assert res.converged
    at = np.searchsorted(ref.stamps, res.stamps)
    np.testing.assert_array_equal(ref.stamps[at], res.stamps)
    assert np.abs(res.poses[:, :2] - ref.poses[at, :2]).max() < 1e-3
    np.testing.assert_array_equal(res.detected, ref.detected)
    assert np.abs(res.landmarks[res.detected] - ref.landmarks[ref.detected]).max() < 1e-3
    assert res.downweighted == 0.0


def test_the_log_oracle_shrugs_off_a_wrong_label():
    """A quarter of one landmark's detections relabelled as a distant one's (a misread barcode): with the Huber
    loss the map stays within 0.1 m of the clean labels' mode (the noise: 0.02 m in range); plain least squares
    moves it by more than 0.3 m."""
    from slam_runtime.oracle import log_oracle

    cfg = RfsSimConfig(steps=300)
    log, noise, veh, labels = _log_oracle_inputs(cfg, 4)
    kw = {"range_sigma": noise["range_sigma"], "bearing_sigma": noise["bearing_sigma"], "window": 5.0}
    clean = log_oracle(log, veh, labels, **kw)
    ids, counts = np.unique(labels[labels > 0], return_counts=True)
    xy = log.landmarks.xy[np.searchsorted(log.landmarks.ids, ids)]
    a = ids[counts.argmax()]
    far = np.hypot(*(xy - xy[counts.argmax()]).T) * (counts >= counts.max() / 2)
    b = ids[far.argmax()]  # a landmark seen about as often, as far from a as there is
    wrong = labels.copy()
    rows = np.flatnonzero(labels == a)
    wrong[rows[: rows.size // 4]] = b
    robust = log_oracle(log, veh, wrong, **kw)
    plain = log_oracle(log, veh, wrong, huber=1e9, **kw)
    d = lambda r: np.abs(r.landmarks[r.detected] - clean.landmarks[clean.detected]).max()  # noqa: E731
    assert d(robust) < 0.1
    assert d(plain) > 0.3
    assert robust.downweighted > 0.0


@pytest.mark.parametrize(
    ("change", "message"),
    [("shape", "one label per detection"), ("unknown", "is no landmark of the log's truth"), ("window", "window must be positive")],
)
def test_bad_log_oracle_inputs_are_refused_naming_them(change, message):
    from slam_runtime.oracle import log_oracle

    log, noise, veh, labels = _log_oracle_inputs(RfsSimConfig(steps=100), 1)
    kw = {"range_sigma": noise["range_sigma"], "bearing_sigma": noise["bearing_sigma"]}
    if change == "shape":
        labels = labels[:-1]
    elif change == "unknown":
        labels = labels.copy()
        labels[np.flatnonzero(labels > 0)[0]] = 999
    else:
        kw["window"] = 0.0
    with pytest.raises((DataError, UsageError), match=message):
        log_oracle(log, veh, labels, **kw)


def test_the_log_oracles_forward_poses_use_only_the_data_so_far():
    """Each window's last pose is the mode of the log cut there (the same data, nothing after it), to 1 mm; the
    last one is the whole run's last pose."""
    import dataclasses

    from detectors.sensor_log import Detections
    from slam_runtime.oracle import log_oracle

    cfg = RfsSimConfig(steps=300)
    log, noise, veh, labels = _log_oracle_inputs(cfg, 5)
    kw = {"range_sigma": noise["range_sigma"], "bearing_sigma": noise["bearing_sigma"], "window": 10.0}
    res = log_oracle(log, veh, labels, **kw)
    assert res.forward_stamps.size == 3
    np.testing.assert_array_equal(res.forward_poses[-1], res.poses[-1])
    d = log.detections
    for i in range(2):
        m = int(np.searchsorted(d.frame_stamp, res.forward_stamps[i], side="right"))
        sel = d.frame < m
        cut = Detections(d.frame_stamp[:m], d.frame[sel], d.range[sel], d.bearing[sel], {k: np.asarray(v)[sel] for k, v in d.descriptors.items()})
        alone = log_oracle(dataclasses.replace(log, detections=cut), veh, labels[sel], **kw)
        assert alone.stamps[-1] == res.forward_stamps[i]
        assert np.abs(alone.poses[-1, :2] - res.forward_poses[i, :2]).max() < 1e-3


def test_frame_odometry_whitens_the_unicycles_noise_over_several_rows():
    """Velocity rows at 50 Hz, turning, and camera frames 0.3-0.7 s apart (some two frames with no row between
    them): over each frame, 4,000 draws of the unicycle's own noise, their end poses minus the predicted increment
    and whitened, have unit covariance (to 0.1; sampling error ~0.02); the raw covariance is strongly coupled (so a
    transposed whitening would fail), and a frame with no row holds the pose."""
    from detectors.sensor_log import Detections, Odometry, SensorLog
    from slam_runtime.oracle import frame_odometry
    from slam_runtime.vehicle import Unicycle

    rng = np.random.default_rng(2)
    st = (np.arange(1000) * 2e7).astype(np.int64)
    u = np.column_stack([0.2 + 0.1 * np.sin(np.arange(1000) / 90), 0.5 * np.cos(np.arange(1000) / 70)])
    fs = np.cumsum(rng.uniform(0.3e9, 0.7e9, 30)).astype(np.int64)
    fs = np.sort(np.concatenate([fs, fs[[5, 12]] + 1000]))  # two frames 1 us after another: no odometry row between
    log = SensorLog("v", odometry=Odometry("velocity", st, u),
                    detections=Detections(fs, np.arange(fs.size), np.ones(fs.size), np.zeros(fs.size), {}))  # fmt: skip
    veh = Unicycle(sigma_v=0.1, sigma_omega=0.3)
    inc, whiten = frame_odometry(log, veh)
    from slam_runtime.sources import control_rows

    frames = list(log.frames())
    held = 0
    for k, fr in enumerate(frames[1:]):
        rows, dts = control_rows(log, fr.odometry)
        if rows.shape[0] == 0:
            held += 1
            np.testing.assert_array_equal(inc[k], 0.0)
            continue
        x = np.zeros((4000, 3))
        for uu, d in zip(rows, dts, strict=True):
            x = veh.step(x, uu, float(d), rng)
        r = x - inc[k]
        r[:, 2] = np.mod(r[:, 2] + np.pi, 2 * np.pi) - np.pi
        raw = np.corrcoef(r.T)
        z = r @ whiten[k].T
        if k == 10:
            assert np.abs(raw[np.triu_indices(3, 1)]).max() > 0.5
        assert np.abs(np.cov(z.T) - np.eye(3)).max() < 0.1, k
    assert held == 2
