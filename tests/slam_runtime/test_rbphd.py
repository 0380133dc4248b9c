"""The RB-PHD map filter on scenarios whose answer is known."""

import numpy as np
import pytest

from detectors.model import DetectionModel
from profiles.schema import ClutterParams, MeasurementNoise, PdTable, SensorModel
from slam_runtime.features import RangeBearing
from slam_runtime.gm import GMBatch
from slam_runtime.mapfilter import Measurements
from slam_runtime.rbphd import RBPHD, PHDMaps, RBPHDConfig
from slam_runtime.slam import RBSlam
from slam_runtime.vehicle import OdometryIncrement

SENSOR = SensorModel(kind="camera", fov=np.pi, range_max=20.0)


def model(rate=0.5, sensor=SENSOR, pd=0.9, **kw):
    rmax = sensor.range_max
    return DetectionModel(
        PdTable(covariate="range", edges=[sensor.range_min, rmax], pd=[pd]), ClutterParams(rate=rate, volume=sensor.field_of_view * rmax), sensor, **kw
    )


def phd(det, sr=0.05, sb=0.005, **cfg):
    return RBPHD(RangeBearing(np.diag([sr**2, sb**2])), det, RBPHDConfig(**cfg))


def test_static_sensor_maps_its_landmarks():
    """A sensor that does not move, P_D 0.9, Poisson clutter: the PHD finds every landmark with weight ~1."""
    rng = np.random.default_rng(5)
    lms = np.array([[5.0, 2.0], [8.0, -3.0], [12.0, 1.0]])
    det = model(buffer=False)
    mf = phd(det, weighting="empty_set")
    fm = mf.feature
    maps = mf.empty(3)
    poses = np.zeros((3, 3))
    for _ in range(40):
        z, _ = fm.predict(np.zeros(3), lms)
        z = z[rng.uniform(size=3) < 0.9]  # each landmark detected with P_D = 0.9
        z = z + rng.normal(0, 1, z.shape) * [0.05, 0.005]
        nc = rng.poisson(0.5)
        clutter = np.column_stack([rng.uniform(0, 20, nc), rng.uniform(-np.pi / 2, np.pi / 2, nc)])
        maps, ll = mf.update(maps, poses, Measurements(np.vstack([z, clutter])))
        assert np.isfinite(ll).all()
    xy, w = mf.estimate(maps, 0)
    assert xy.shape[0] == 3
    d = np.linalg.norm(xy[:, None, :] - lms[None], axis=2).min(axis=1)
    assert np.all(d < 0.1)  # 40 looks with 5 cm / 5 mrad noise: a few cm
    assert np.all(np.abs(w - 1.0) < 0.3)
    # total expected number of features ~ 3 (+ a little clutter mass)
    assert maps.gm.total()[0] == pytest.approx(3.0, abs=0.6)


def _one_feature_at(r, w=1.0, sigma=0.01):
    return PHDMaps(GMBatch(np.array([[w]]), np.array([[[r, 0.0]]]), np.eye(2)[None, None] * sigma**2), GMBatch.empty(1, 0))


def test_buffer_zone_at_the_range_limit_is_set_by_the_sensor_noise():
    """A well-mapped feature (1 cm) 3 cm inside the 2.5 m range limit, range noise 2.2 cm: whether the
    sensor reports it is a coin toss. Missed, it keeps its weight with the buffer zone and loses 99 % without;
    the band is the sensor's 2 sigma (4.5 cm), not the feature's own 2 cm."""
    sensor = SensorModel(kind="detector", range_min=0.5, range_max=2.5, fov=2 * np.pi)
    noise = MeasurementNoise(range_sigma=0.0224, bearing_sigma=0.007)
    empty = Measurements(np.zeros((0, 2)))
    for buffer, kept in ((True, 1.0), (False, 0.01)):
        det = model(rate=1e-3, sensor=sensor, pd=0.99, noise=noise, buffer=buffer)
        mf = phd(det, prune=1e-6, adaptive_birth=False)
        maps, _ = mf.update(_one_feature_at(2.47), np.zeros((1, 3)), empty)
        assert maps.gm.total()[0] == pytest.approx(kept, rel=1e-6)
    # deep inside the field of view a miss costs 99 % of the weight either way
    det = model(rate=1e-3, sensor=sensor, pd=0.99, noise=noise)
    maps, _ = phd(det, prune=1e-6).update(_one_feature_at(2.3), np.zeros((1, 3)), empty)
    assert maps.gm.total()[0] == pytest.approx(0.01, rel=1e-6)
    # just outside the limit but within the band, a detection still updates the feature (P_D inside)
    z = Measurements(np.array([[2.49, 0.0]]))
    maps, _ = phd(det, prune=1e-6).update(_one_feature_at(2.52), np.zeros((1, 3)), z)
    xy, w = phd(det).estimate(maps, 0)
    assert xy.shape == (1, 2) and xy[0, 0] == pytest.approx(2.5, abs=0.02) and w[0] > 0.9


def test_no_nan_over_a_full_run_at_50_clutter_per_scan():
    """A vehicle circling 25 landmarks, P_D 0.9 in a 15 m half-disc, Poisson clutter of 50 per scan, every
    weighting strategy: weights, poses and maps stay finite at every step, map weights non-negative."""
    sensor = SensorModel(kind="camera", fov=np.pi, range_max=15.0)
    for weighting in ("marginal", "multi_feature", "empty_set", "single_feature"):
        rng = np.random.default_rng(8)
        lms = rng.uniform(-15, 15, (25, 2))
        rate = 50.0
        det = model(rate=rate, sensor=sensor)
        mf = phd(det, sr=0.1, sb=0.01, weighting=weighting)
        veh = OdometryIncrement()
        pose = np.array([8.0, 0.0, np.pi / 2])
        slam = RBSlam(veh, mf, 10, pose, np.random.default_rng(1))
        inc = np.array([0.5, 0.0, 0.5 / 8.0])  # a circle of radius 8 m
        for _ in range(120):
            pose = veh.mean(pose[None], inc, 0.2)[0]
            slam.predict(inc[None], np.array([0.2]))
            z, _ = mf.feature.predict(pose, lms)
            z = z[det.in_fov(z) & (rng.uniform(size=len(lms)) < 0.9)]
            z = z + rng.normal(0, 1, z.shape) * [0.1, 0.01]
            n = rng.poisson(rate)
            clutter = np.column_stack([rng.uniform(0, 15, n), rng.uniform(-np.pi / 2, np.pi / 2, n)])
            info = slam.update(Measurements(np.vstack([z, clutter])))
            g = slam.maps.gm
            assert np.isfinite(slam.logw).all() and np.isfinite(slam.x).all() and np.isfinite(info.ess)
            assert np.isfinite(g.w).all() and np.isfinite(g.mu).all() and np.isfinite(g.cov).all() and (g.w >= 0).all()
        assert np.isfinite(slam.trajectory()).all() and np.isfinite(slam.mean_pose()).all()


@pytest.mark.slow  # end to end: whole simulated runs, tens of CPU seconds; make test-slow (CI) runs it
def test_rbphd_on_a_cluttered_park_beats_odometry_and_the_profile_maps_better_than_constant_pd():
    """The park of the comparison (benchmarks/configs/small_park.yaml: bushes that fit circles,
    walls, posts, dust), world seed 1, the whole run, filter seeds 0-2. Truth: the simulator's poses and trees.

    The filter with the calibrated profile beats dead reckoning in every run, and its map is closer to the
    trees (OSPA c = 1 m, p = 1) than with a constant P_D, which forgets what it cannot see: the mean map OSPA
    over the three seeds lower by at least 5 %, and more features kept in every run. Measured: 0.505 / 0.471 /
    0.520 against 0.544 / 0.603 / 0.569 (the mean 13 % lower; seeds 3-5: 0.498 / 0.472 / 0.471 against 0.525 /
    0.532 / 0.580), 46-49 features against 34-36. One run alone is not enough: its ratio ranged 0.78-0.95
    over seeds 0-5, and the packages of a fresh install (2026-11-27), which round differently in the last
    bits, moved seed 0's from under 0.9 (what this test asked of it alone before) to 0.93. The eight-world
    figures come from `detcal slam sweep` (see the README).
    """
    from pathlib import Path

    from calib.config import load_yaml_model
    from calib.sim.park import ParkConfig, simulate_park
    from profiles.store import resolve
    from slam_runtime.config import SlamConfig, override
    from slam_runtime.run import evaluate, run_slam

    cfg = load_yaml_model(ParkConfig, Path(__file__).resolve().parents[2] / "benchmarks/configs/small_park.yaml")
    log = simulate_park(cfg, 1).log
    prof = resolve("sim-park-laser@1.0.0")
    runs = {"profile": [], "constant": []}
    for seed in range(3):
        for m, evals in runs.items():
            res = run_slam(log, prof, override(SlamConfig(), **{"detection.pd_mode": m}), seed=seed)
            evals.append(evaluate(log, res))
            assert np.isfinite(res.trajectory).all()
    for pm, cm in zip(runs["profile"], runs["constant"], strict=True):
        assert pm["trajectory_rmse_vs_ground_truth_m"] < 0.5 * pm["odometry_rmse_vs_ground_truth_m"]
        assert pm["map_features"] > cm["map_features"]
    ospa = {m: float(np.mean([r["map_ospa"] for r in evals])) for m, evals in runs.items()}
    assert ospa["profile"] < 0.95 * ospa["constant"], ospa


@pytest.mark.slow  # end to end: whole simulated runs, tens of CPU seconds; make test-slow (CI) runs it
def test_the_optimal_proposal_keeps_three_particles_on_the_path():
    """rfs-sim, 300 steps, only 3 particles, 4 filter seeds: drawing each pose from the motion prior updated
    by the measurements the particle's map explains keeps it within 5 cm of the true path, and closer on
    average than drawing from the motion model alone (measured: 0.027 m against 0.042 m)."""
    from pathlib import Path

    from calib.config import load_yaml_model
    from calib.sim.rfs import RfsSimConfig, simulate_rfs, truth_profile
    from slam_runtime.config import SlamConfig, override
    from slam_runtime.run import evaluate, run_slam

    sim = RfsSimConfig(steps=300)
    log = simulate_rfs(sim, 3)
    base = load_yaml_model(SlamConfig, Path(__file__).resolve().parents[2] / "benchmarks/configs/rfs_sim.yaml")
    rmse = {}
    for prop in ("prior", "optimal"):
        cfg = override(base, particles=3, proposal=prop)
        rmse[prop] = [evaluate(log, run_slam(log, truth_profile(sim), cfg, sd))["trajectory_rmse_vs_ground_truth_m"] for sd in range(4)]
    assert max(rmse["optimal"]) < 0.05
    assert np.mean(rmse["optimal"]) < 0.8 * np.mean(rmse["prior"])


def test_merging_only_what_changed_gives_the_maps_of_merging_every_pair():
    """merge_scope fresh tests only the pairs with a component this step updated, created or merged; the
    rest was tested before with the moments it still has. A cluttered rfs-sim run (clutter 20 per scan, so
    that merges happen everywhere) must give the same maps and trajectory, byte for byte, as testing every
    pair (Vo & Ma). Why the last merge's flags are needed: tests/slam_runtime/test_gm.py."""
    from pathlib import Path

    from calib.config import load_yaml_model
    from calib.sim.rfs import RfsSimConfig, simulate_rfs, truth_profile
    from slam_runtime.config import SlamConfig, override
    from slam_runtime.run import run_slam

    sim = RfsSimConfig(steps=300, clutter_intensity=2e-3)
    log = simulate_rfs(sim, 5)
    base = override(load_yaml_model(SlamConfig, Path(__file__).resolve().parents[2] / "benchmarks/configs/rfs_sim.yaml"), particles=5)
    runs = {sc: run_slam(log, truth_profile(sim), override(base, **{"filter.merge_scope": sc}), 0) for sc in ("fresh", "all")}
    np.testing.assert_array_equal(runs["fresh"].trajectory, runs["all"].trajectory)
    np.testing.assert_array_equal(runs["fresh"].map_xy, runs["all"].map_xy)
    assert runs["fresh"].map_xy.shape[0] >= 20


def test_the_optimal_proposal_associates_under_the_motion_prior_uncertainty():
    """One mapped landmark 10 m ahead, the measurement taken from the true pose (0, 0, 0); the motion prior's
    mean is 0.03 rad off in heading (1 sigma of the prior, 6 sigma of the bearing noise). The measurement is
    gated with the pose uncertainty included (FastSLAM 2.0), so it is used, and the proposal's mean heading
    returns to the truth within a fifth of the offset (the exact Gaussian posterior, prior 0.03 rad and
    bearing 0.005 rad, puts it 0.0008 rad off)."""
    mf = phd(model(buffer=False), sr=0.05, sb=0.005)
    lm = np.array([[[10.0, 0.0]]])
    maps = PHDMaps(GMBatch(np.array([[1.0]]), lm, np.array([[np.eye(2) * 1e-4]])), GMBatch.empty(1, 0, 2))
    z, _ = mf.feature.predict(np.zeros(3), lm[0])
    xbar = np.array([[0.0, 0.0, 0.03]])
    q = np.diag([0.01**2, 0.01**2, 0.03**2])[None]
    mean, cov, used = mf.pose_proposal(maps, xbar, q, Measurements(z))
    assert used[0] == 1
    assert abs(mean[0, 2]) < 0.006
    assert cov[0, 2, 2] < 0.1 * q[0, 2, 2]  # the measurement, not the prior, sets the heading


def _static_run(mf, lms, p_true, steps, rng, misses_at_end=0):
    """A static sensor at the origin looking at ``lms``, each detected with probability ``p_true`` per step (the filter
    assumes its model's P_D), 5 cm / 5 mrad noise, Poisson clutter of 0.5 per scan; the last ``misses_at_end`` steps
    detect nothing of the landmarks. Returns the final maps."""
    fm = mf.feature
    maps = mf.empty(1)
    for k in range(steps):
        z, _ = fm.predict(np.zeros(3), lms)
        z = z[(rng.uniform(size=len(lms)) < p_true) & (k < steps - misses_at_end)]
        z = z + rng.normal(0, 1, z.shape) * [0.05, 0.005]
        nc = rng.poisson(0.5)
        clutter = np.column_stack([rng.uniform(0, 20, nc), rng.uniform(-np.pi / 2, np.pi / 2, nc)])
        maps, _ = mf.update(maps, np.zeros((1, 3)), Measurements(np.vstack([z, clutter])))
    return maps


def _mass_near(maps, lms, radius=0.3):
    """(L,) the summed weight of the components within ``radius`` of each landmark."""
    d = np.linalg.norm(maps.gm.mu[0][:, None, :] - lms[None], axis=2)
    return np.array([maps.gm.w[0][d[:, i] < radius].sum() for i in range(len(lms))])


def test_existence_rule_removes_the_weight_bias_of_a_low_pd():
    """The PHD's bias under a low P_D (UTIAS's camera: P_D 0.1-0.6 from the profile, landmarks seen more often than
    that by some robots): with the model's P_D 0.25 and landmarks detected at every other step (true rate 0.5), the
    weight near each landmark climbs towards 1 / P_D while detected (the PHD's fixed point of (1 - P_D) w + 1) and
    drops by (1 - P_D) per miss, so what counts as one feature swings between ~0.5 and 4 (2 in the mean). With
    ``update_rule: existence`` each landmark is one component of weight at most existence_max, and eight misses in
    a row (a landmark occluded) leave it mapped: (1 - P_D)^8 = 0.1 of the PHD's weight is gone, while a Bernoulli of
    existence 0.99 keeps r (1 - P_D) / (1 - r P_D) per miss (0.99 -> 0.74 after eight).
    The tolerances: one landmark is one feature (the count must be exact), the weight may not exceed
    existence_max, and 60 looks at 5 cm / 5 mrad place each within a few cm (0.1 m allowed)."""
    lms = np.array([[5.0, 2.0], [8.0, -3.0], [12.0, 1.0]])
    det = model(pd=0.25, buffer=False)
    biased = _mass_near(_static_run(phd(det), lms, 0.5, 60, np.random.default_rng(3)), lms)
    # the bias: in the mean a landmark weighs p_true / P_D = 2 features (the fixed point of w = (1 - P_D) w + p_true);
    # at any one step each lies between ~0.5 and 4, so the three together are asked for more than 4.5, not 6
    assert biased.sum() > 4.5
    mf = phd(det, update_rule="existence")
    maps = _static_run(mf, lms, 0.5, 60, np.random.default_rng(3))
    mass = _mass_near(maps, lms)
    assert np.all(mass <= 0.99 + 1e-9) and np.all(mass > 0.9)
    xy, w = mf.estimate(maps, 0)
    assert xy.shape[0] == 3  # one feature per landmark, no clutter feature
    assert np.all(np.linalg.norm(xy[:, None, :] - lms[None], axis=2).min(axis=1) < 0.1)
    # eight misses in a row at the end: the PHD loses the landmarks from its map, the existence rule keeps them
    lost = phd(det).estimate(_static_run(phd(det), lms, 0.5, 60, np.random.default_rng(3), misses_at_end=8), 0)[0]
    kept = mf.estimate(_static_run(mf, lms, 0.5, 60, np.random.default_rng(3), misses_at_end=8), 0)[0]
    assert lost.shape[0] < 3 and kept.shape[0] == 3
