"""MH-FastSLAM's map filter against closed forms, a brute-force enumeration of the associations, and a seeded
simulation whose map is known."""

import itertools

import numpy as np
import pytest
from scipy.special import expit, logit
from scipy.stats import multivariate_normal

from detectors.model import DetectionModel
from profiles.schema import ClutterParams, PdTable, SensorModel
from slam_runtime.fastslam import FastSLAMMaps, MHFastSLAM, MHFastSLAMConfig, _merge_hypotheses, ekf_update
from slam_runtime.features import RangeBearing
from slam_runtime.mapfilter import Measurements

SENSOR = SensorModel(kind="camera", fov=np.pi, range_max=20.0)
PD, RATE = 0.8, 2.0
KAPPA = RATE / (np.pi * 20.0)
R = np.diag([0.15**2, 0.03**2])
POSE = np.array([0.3, -0.2, 0.05])


def _det(buffer=False, pd=PD):
    return DetectionModel(PdTable(covariate="range", edges=[0.0, 20.0], pd=[pd]), ClutterParams(rate=RATE, volume=np.pi * 20.0), SENSOR, buffer=buffer)


def _filter(**cfg) -> MHFastSLAM:
    return MHFastSLAM(RangeBearing(R), _det(), MHFastSLAMConfig(**cfg))


def _maps(mu, cov, r) -> FastSLAMMaps:
    """One particle, one hypothesis holding landmarks mu (L, 2), cov (L, 2, 2) of existence r (L,)."""
    return FastSLAMMaps(np.asarray(mu)[None, None], np.asarray(cov)[None, None], logit(np.asarray(r, dtype=float))[None, None], np.zeros((1, 1)))


def test_ekf_update_is_the_information_form():
    """The gain form of the EKF update against the information form of the same linearised Gaussian update,
    P1 = (P0^-1 + H^T R^-1 H)^-1, m1 = m0 + P1 H^T R^-1 (z - h(m0)), for landmarks at several ranges and bearings."""
    fm = RangeBearing(R)
    rng = np.random.default_rng(2)
    m0 = rng.uniform(-8, 8, (6, 2))
    a = rng.normal(0, 0.3, (6, 2, 2))
    p0 = a @ np.swapaxes(a, 1, 2) + np.eye(2) * 0.01
    sp = np.tile(POSE, (6, 1))
    zh, h = fm.predict_sensor(sp, m0)
    z = zh + rng.normal(0, 1, zh.shape) * [0.15, 0.03]
    m1, p1 = ekf_update(fm, sp, m0, p0, z, np.broadcast_to(R, (6, 2, 2)))
    ri = np.linalg.inv(R)
    for i in range(6):
        info = np.linalg.inv(p0[i]) + h[i].T @ ri @ h[i]
        pe = np.linalg.inv(info)
        nu = fm.innovation(z[i], zh[i])
        np.testing.assert_allclose(p1[i], pe, rtol=1e-9, atol=1e-12)
        np.testing.assert_allclose(m1[i], m0[i] + pe @ h[i].T @ ri @ nu, rtol=1e-9, atol=1e-12)


# ---------------------------------------------------------------------- one update, every association enumerated
MU = np.array([[5.0, 1.0], [5.0, 0.6], [9.0, -3.0]])  # A and B close (their gates overlap), C apart
COV = np.stack([np.eye(2) * 0.05**2, np.eye(2) * 0.08**2, np.eye(2) * 0.1**2])
EX = np.array([0.95, 0.7, 0.9])


def _meas(fm):
    """Near A, between A and B, near C, and one far from every landmark."""
    z, _ = fm.predict(POSE[None], np.array([[5.02, 0.95], [5.0, 0.8], [9.05, -3.02], [12.0, 4.0]]))
    return z


def _g(fm, i, z):
    zh, h = fm.predict(POSE[None], MU[i][None])
    return multivariate_normal(np.zeros(2), h[0] @ COV[i] @ h[0].T + R).pdf(fm.innovation(z[None], zh)[0])


def _admissible(fm, i, j, z):
    """The filter's gate: inside squared Mahalanobis 16 and likelier the landmark's than clutter with it missed."""
    zh, h = fm.predict(POSE[None], MU[i][None])
    s = h[0] @ COV[i] @ h[0].T + R
    nu = fm.innovation(z[j][None], zh)[0]
    return nu @ np.linalg.solve(s, nu) <= 16.0 and EX[i] * PD * _g(fm, i, z[j]) / KAPPA > 1.0 - EX[i] * PD


def _enumerate(fm, z):
    """{association (measurement of A, B, C or -1): weight relative to all-clutter}, over every admissible one."""
    out = {}
    for gam in itertools.product(range(-1, len(z)), repeat=3):
        used = [j for j in gam if j >= 0]
        if len(used) != len(set(used)) or any(j >= 0 and not _admissible(fm, i, j, z) for i, j in enumerate(gam)):
            continue
        w = 1.0
        for i, j in enumerate(gam):
            w *= EX[i] * PD * _g(fm, i, z[j]) / KAPPA if j >= 0 else 1.0 - EX[i] * PD
        out[gam] = w
    return out


def test_update_matches_the_enumerated_associations():
    """Every association kept (k large, no cut, no merge): the particle's log-likelihood is the log of the summed
    weights of every admissible association, the hypotheses are those associations with their normalised weights,
    and each hypothesis's map is its association's EKF updates, existence updates and births."""
    mf = _filter(hypotheses=100, max_loglik_diff=1e9, merge=0.0, prune_logodds=-50.0)
    fm = mf.feature
    z = _meas(fm)
    every = _enumerate(fm, z)
    total = sum(every.values())
    maps, loglik = mf.update(_maps(MU, COV, EX), POSE[None], Measurements(z))
    assert loglik[0] == pytest.approx(np.log(total), rel=1e-9)
    live = np.flatnonzero(np.isfinite(maps.logw[0]))
    assert live.size == len(every) > 2  # A and B compete for two measurements
    got = {}
    for h in live:
        v = maps.valid[0, h]
        mu, lo = maps.mu[0, h][v], maps.lo[0, h][v]
        # identify the association by which landmarks moved where, then check the whole map
        gam = []
        for i in range(3):
            cands = [j for j in range(-1, len(z)) if j < 0 or _admissible(fm, i, j, z)]
            upd = {j: (MU[i] if j < 0 else ekf_update(fm, POSE[None], MU[i][None], COV[i][None], z[j][None], R[None])[0][0]) for j in cands}
            j = min(cands, key=lambda j: np.linalg.norm(upd[j] - mu[i]))
            np.testing.assert_allclose(mu[i], upd[j], atol=1e-9)
            miss, det = np.log(1 - PD), np.logaddexp(np.log(1 - PD), np.log(PD * _g(fm, i, z[j]) / KAPPA)) if j >= 0 else 0.0
            assert lo[i] == pytest.approx(logit(EX[i]) + (det if j >= 0 else miss), abs=1e-9)
            gam.append(j)
        # one landmark started for each measurement left unassigned, at the inverse model's point, log-odds 0
        free = [j for j in range(len(z)) if j not in gam]
        births, _ = fm.inverse(POSE[None], z[free])
        np.testing.assert_allclose(mu[3:], births, atol=1e-9)
        assert np.all(lo[3:] == 0.0)
        got[tuple(gam)] = float(np.exp(maps.logw[0, h]))
    assert got.keys() == every.keys()
    for k, w in every.items():
        assert got[k] == pytest.approx(w / total, rel=1e-9)
    # the hypotheses come heaviest first
    assert np.all(np.diff(maps.logw[0, live]) <= 0)


def test_hypotheses_are_the_k_best_within_the_cut():
    """With k = 3 and a cut of 2 nats the filter keeps the enumeration's heaviest associations within 2 nats of
    the best, at most 3, renormalised; the log-likelihood sums the associations the search returned (the same ones:
    the cut stops the search)."""
    mf = _filter(hypotheses=3, max_loglik_diff=2.0, merge=0.0)
    z = _meas(mf.feature)
    every = sorted(_enumerate(mf.feature, z).values(), reverse=True)
    keep = [w for w in every[:3] if np.log(w) >= np.log(every[0]) - 2.0]
    maps, loglik = mf.update(_maps(MU, COV, EX), POSE[None], Measurements(z))
    w = np.exp(maps.logw[0][np.isfinite(maps.logw[0])])
    np.testing.assert_allclose(w, np.array(keep) / sum(keep), rtol=1e-9)
    assert len(keep) < len(every)  # the cut or k leaves some out
    assert loglik[0] == pytest.approx(np.log(sum(keep)), rel=1e-9)


def test_existence_log_odds_map_management():
    """A landmark in view and never detected loses log(1 - P_D) per step and is removed below prune_logodds; a
    locked one (log-odds above lock_logodds) keeps its log-odds; out of view nothing changes."""
    mf = _filter(prune_logodds=-5.0, lock_logodds=10.0)
    lms = np.array([[6.0, 0.0], [7.0, 2.0], [-6.0, 0.0]])  # the third behind the sensor (field of view pi)
    maps = _maps(lms, np.tile(np.eye(2) * 0.01, (3, 1, 1)), expit(np.array([0.0, 12.0, 0.0])))
    pose = np.zeros((1, 3))
    first = lambda m: np.flatnonzero(m.valid[0, 0] & (np.abs(m.mu[0, 0, :, 0] - 6.0) < 1e-9))  # noqa: E731
    steps = 0
    while first(maps).size:
        before = maps.lo[0, 0, first(maps)[0]]
        maps, _ = mf.update(maps, pose, Measurements(np.zeros((0, 2))))
        steps += 1
        if first(maps).size:
            assert maps.lo[0, 0, first(maps)[0]] == pytest.approx(before + np.log(1 - PD))
    assert steps == int(np.ceil(5.0 / -np.log(1 - PD)))
    v = maps.valid[0, 0]
    np.testing.assert_allclose(maps.mu[0, 0][v], lms[1:])
    np.testing.assert_allclose(maps.lo[0, 0][v], [12.0, 0.0])


def test_buffer_zone_excuses_a_miss():
    """A landmark just beyond the range limit (in the buffer zone) is not penalised when missed."""
    det = _det(buffer=True)
    mf = MHFastSLAM(RangeBearing(R), det, MHFastSLAMConfig())
    maps = _maps([[20.05, 0.0]], [np.eye(2) * 0.1**2], [0.9])
    pd, buf = det.pd_features(np.zeros((1, 3)), maps.mu[:, 0], maps.cov[:, 0], Measurements(np.zeros((0, 2))))
    assert buf[0, 0]
    out, _ = mf.update(maps, np.zeros((1, 3)), Measurements(np.zeros((0, 2))))
    assert out.lo[0, 0, 0] == pytest.approx(logit(0.9))


def test_merge_joins_hypotheses_that_hold_one_map():
    """Two hypotheses whose landmarks agree within the gate merge (weights summed); a third with a landmark 1 m off
    stays; the result is ordered by weight."""
    mu = np.array([[[0.0, 0.0], [5.0, 5.0]], [[0.01, 0.0], [5.0, 5.02]], [[1.0, 0.0], [5.0, 5.0]]])[None]
    cov = np.broadcast_to(np.eye(2) * 0.05**2, (1, 3, 2, 2, 2)).copy()
    lo = np.zeros((1, 3, 2))
    logw = np.log(np.array([[0.4, 0.25, 0.35]]))
    m2, c2, l2, w2 = _merge_hypotheses(mu, cov, lo, logw, 4.0)
    np.testing.assert_allclose(np.exp(w2[0]), [0.65, 0.35])
    np.testing.assert_allclose(m2[0, 0], mu[0, 0])
    np.testing.assert_allclose(m2[0, 1], mu[0, 2])


def test_resampling_takes_whole_particles():
    mf = _filter()
    z = _meas(mf.feature)
    maps, _ = mf.update(_maps(MU, COV, EX), POSE[None], Measurements(z))
    two = maps.take(np.array([0, 0]))
    assert two.mu.shape[0] == 2
    np.testing.assert_array_equal(two.lo[1], maps.lo[0])
    assert mf.size(two).tolist() == [mf.size(maps)[0]] * 2


def test_recovers_a_simulated_map():
    """rfs-sim (the C++ library's scenario) for 400 steps, 20 particles, full SLAM: every landmark the sensor saw
    at least 10 times is mapped within 5 cm, and no mapped feature is more than 5 cm from a landmark.

    Why 5 cm: a landmark seen 10 times at up to 2.5 m with sigma_r = 2.2 cm and sigma_b = 0.4 deg is located to
    about 1 cm given the poses; the filter's pose error on this scenario stays within a few cm (RB-PHD's final
    errors at 20-200 particles: 0.6-4.6 cm), and 5 cm is below the spacing of all but the closest landmark pairs,
    so a duplicate or a landmark in the wrong place fails the test."""
    import slam_runtime.run as run
    from calib.config import load_yaml_model
    from calib.sim.rfs import RfsSimConfig, simulate_rfs, truth_profile
    from slam_runtime.config import SlamConfig, override, with_filter
    from tests.conftest import ROOT

    cfg = with_filter(override(load_yaml_model(SlamConfig, ROOT / "benchmarks/configs/rfs_sim.yaml"), particles=20), "mhfastslam")
    sim = RfsSimConfig(steps=400)
    log = simulate_rfs(sim, 1)
    res = run.run_slam(log, truth_profile(sim), cfg, 0)
    lab = np.asarray(log.detections.descriptors["landmark"])
    seen = np.bincount(lab, minlength=sim.landmarks + 1)[1:] >= 10
    truth = log.landmarks.xy
    d = np.linalg.norm(res.map_xy[:, None, :] - truth[None], axis=2)
    assert seen.sum() >= 10
    assert np.all(d[:, seen].min(axis=0) < 0.05)
    assert np.all(d.min(axis=1) < 0.05)


def test_planes(street_profile):
    """The same filter on planar features (the plane feature and detection models through the seam), 40 frames of
    the small street with noisy odometry: the tolerances of the labelled filters' plane test (one filter seed, 40
    frames: the pose bound 0.6 of dead reckoning; normal angle 0.3 deg and offset 5 cm median; OSPA c = 1 m < 0.6)."""
    import slam_runtime.run as run
    from calib.sim.street import simulate_street
    from slam_runtime.config import SlamConfig, override
    from tests.conftest import small_street_config

    sim = simulate_street(small_street_config(40, odometry={"sigma_v": 0.3, "sigma_omega": 0.08}), 31)
    cfg = override(SlamConfig(), features="planes", particles=20, **{"filter.kind": "mhfastslam", "motion.ect.sigma_v": 0.3, "motion.ect.sigma_omega": 0.08})
    res = run.run_slam(sim.log, street_profile, cfg, 0)
    m = run.evaluate(sim.log, res, 1.0, 1.0, cfg)
    assert m["trajectory_rmse_vs_ground_truth_m"] <= 0.6 * m["odometry_rmse_vs_ground_truth_m"], m
    assert m["map_normal_angle_median_deg"] < 0.3 and m["map_offset_error_median_m"] < 0.05
    assert m["map_ospa"] < 0.6
