"""LMB tracks that learn a factor on the detection model's P_D (``learn_pd``, slam_runtime.lmb)."""

import numpy as np
import pytest
from scipy import stats

from detectors.model import DetectionModel
from profiles.schema import ClutterParams, PdTable, SensorModel
from slam_runtime.features import RangeBearing
from slam_runtime.glmb import GLMB, GLMBConfig
from slam_runtime.lmb import LMB, LMBConfig
from slam_runtime.mapfilter import Measurements
from slam_runtime.pd_factor import beta_update, mean_factor, prior_ab
from tests.slam_runtime.test_glmb import _Last

SENSOR = SensorModel(kind="camera", fov=np.pi, range_max=20.0)
FILTERS = [(GLMB, GLMBConfig), (LMB, LMBConfig)]


@pytest.mark.parametrize(
    "a,b,pd,w_det", [(19.0, 1.0, 0.7, 0.3), (3.0, 2.0, 0.95, 0.6), (50.0, 8.0, 0.4, 0.0), (2.0, 2.0, 0.9, 1.0)]
)
def test_beta_update_matches_the_moments_of_the_exact_posterior(a, b, pd, w_det):
    """The exact posterior of the factor q after a step is w_det Beta(a + 1, b) + w_miss (1 - q pd) Beta(a, b) / Z; the
    update's Beta has its mean and variance (integrated on a grid of 200,001 points: error about 1e-9)."""
    q = np.linspace(0.0, 1.0, 200_001)
    prior = stats.beta.pdf(q, a, b)
    miss = (1.0 - pd * q) * prior
    post = w_det * stats.beta.pdf(q, a + 1, b) + (1.0 - w_det) * miss / np.trapezoid(miss, q)
    mean = np.trapezoid(q * post, q)
    var = np.trapezoid((q - mean) ** 2 * post, q)
    a1, b1 = beta_update(np.array([a, b]), np.array(pd), np.array(w_det), np.array(1.0 - w_det))
    assert a1 / (a1 + b1) == pytest.approx(mean, abs=1e-7)
    assert a1 * b1 / ((a1 + b1) ** 2 * (a1 + b1 + 1)) == pytest.approx(var, rel=1e-5)


def test_beta_update_is_exact_where_the_posterior_is_a_beta():
    """A detection gives Beta(a + 1, b); a miss with P_D 1 gives Beta(a, b + 1); no weight leaves it unchanged."""
    ab = np.array([[4.0, 3.0], [4.0, 3.0], [4.0, 3.0]])
    out = beta_update(ab, np.array([0.8, 1.0 - 1e-12, 0.8]), np.array([1.0, 0.0, 0.0]), np.array([0.0, 1.0, 0.0]))
    np.testing.assert_allclose(out, [[5.0, 3.0], [4.0, 4.0], [4.0, 3.0]], rtol=1e-6)


def _scene(cls, cfg_cls, learn: bool, seed: int, steps: int = 150):
    """A sensor at the origin, P_D 0.95 in the model; landmark 0 is detected with P_D 0.95 (a tree, as the model says),
    landmark 1 with 0.5 (a bush: half the model's); 0.5 false alarms per scan. Two particles, resampled (reversed) every
    tenth step."""
    rng = np.random.default_rng(seed)
    lms = np.array([[6.0, 2.0], [9.0, -3.0]])
    true_pd = np.array([0.95, 0.5])
    pdt = PdTable(covariate="range", edges=[0.0, 20.0], pd=[0.95])
    det = DetectionModel(pdt, ClutterParams(rate=0.5, volume=SENSOR.field_of_view * 20.0), SENSOR, buffer=False)
    mf = cls(RangeBearing(np.diag([0.1**2, 0.01**2])), det, cfg_cls(learn_pd=learn), rng=np.random.default_rng(seed))
    maps = mf.empty(2)
    for k in range(steps):
        z, _ = mf.feature.predict(np.zeros(3), lms)
        z = z[rng.uniform(size=len(lms)) < true_pd]
        z = z + rng.normal(0, 1, z.shape) * [0.1, 0.01]
        nc = rng.poisson(0.5)
        clutter = np.column_stack([rng.uniform(0, 20, nc), rng.uniform(-np.pi / 2, np.pi / 2, nc)])
        maps, ll = mf.update(maps, np.zeros((2, 3)), Measurements(np.vstack([z, clutter])))
        assert np.isfinite(ll).all()
        if k % 10 == 9:
            maps = maps.take(np.array([1, 0]))
    return mf, maps, lms


def _mapped(mf, maps, lms):
    """Each landmark's (learned factor, existence) in particle 0's map estimate: the feature within 0.5 m of it."""
    lab, x, r = mf.labels(maps, 0)
    if isinstance(mf, LMB):
        ab = maps.pd_ab[0][[int(np.flatnonzero(maps.tracks.label[0] == lb)[0]) for lb in lab]]
    else:
        ab = maps.pd.get(lab[None], prior_ab(mf.cfg))[0]
    out = []
    for lm in lms:
        near = np.flatnonzero(np.linalg.norm(x - lm, axis=1) < 0.5)
        assert near.size == 1, (lm, x)
        out.append((mean_factor(ab[near[0]]), r[near[0]]))
    return np.array(out)


@pytest.mark.parametrize("cls,cfg_cls", FILTERS)
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_each_track_learns_its_factor_on_p_d(cls, cfg_cls, seed):
    """After 150 scans the tree's factor stays near 1 and the bush's comes to its true 0.5 / 0.95 = 0.53: within 0.1
    (150 looks give the ratio to about +-0.04, one standard deviation, and the prior of 20 pseudo-looks at 0.95 pulls it
    up by about 0.05); both are mapped, with existence above 0.9."""
    mf, maps, lms = _scene(cls, cfg_cls, True, seed)
    (f_tree, r_tree), (f_bush, r_bush) = _mapped(mf, maps, lms)
    assert f_tree > 0.9
    assert f_bush == pytest.approx(0.5 / 0.95, abs=0.1)
    assert min(r_tree, r_bush) > 0.9


@pytest.mark.parametrize("cls,cfg_cls", FILTERS)
def test_a_learned_factor_stops_the_weights_preferring_poses_that_hide_the_bush(cls, cfg_cls):
    """The park's mechanism, on a small case. A sensor that sees 10 m (model P_D 0.95); a tree 2 m ahead (detected
    with P_D 0.95) and a bush at 9.9 m (detected with 0.5), learned for 100 scans from the origin by both particles.
    Then a scan that detects the tree and misses the bush, with particle 0 at the true pose and particle 1 0.15 m
    behind it, from where the bush is out of range (P_D 0: its miss costs nothing) and the tree 0.15 m too far (1.5
    sigma of range noise: about 1.1 nats). With the model's P_D the miss costs particle 0 log(1 - 0.95) = -3.0 nats and
    the weights prefer the wrong pose by about 1.9 nats; with the learned factor (about 0.55) it costs about 0.7 and they
    prefer the true pose (by 0.1-0.3 nats in these seeds: the factor learned from 100 scans varies by seed)."""
    sensor = SensorModel(kind="camera", fov=np.pi, range_max=10.0)
    det = DetectionModel(
        PdTable(covariate="range", edges=[0.0, 10.0], pd=[0.95]),
        ClutterParams(rate=0.5, volume=np.pi * 10.0),
        sensor,
        buffer=False,
    )
    lms = np.array([[2.0, 0.0], [9.9, 0.5]])
    for seed in range(3):
        diff = {}
        for learn in (False, True):
            rng = np.random.default_rng(seed)
            mf = cls(RangeBearing(np.diag([0.1**2, 0.01**2])), det, cfg_cls(learn_pd=learn), rng=np.random.default_rng(seed))
            maps = mf.empty(2)
            for _ in range(100):
                z, _ = mf.feature.predict(np.zeros(3), lms)
                z = z[rng.uniform(size=2) < [0.95, 0.5]]
                maps, _ = mf.update(maps, np.zeros((2, 3)), Measurements(z + rng.normal(0, 1, z.shape) * [0.1, 0.01]))
            z, _ = mf.feature.predict(np.zeros(3), lms[:1])
            _, ll = mf.update(maps, np.array([[0.0, 0.0, 0.0], [-0.15, 0.0, 0.0]]), Measurements(z))
            diff[learn] = ll[1] - ll[0]
        assert diff[False] == pytest.approx(1.9, abs=0.4), diff
        assert -0.8 < diff[True] < 0.0, diff


@pytest.mark.parametrize("cls,cfg_cls", FILTERS)
def test_learn_pd_off_carries_nothing(cls, cfg_cls):
    """Off (the default) the maps carry no factors and the model's P_D is used as it is."""
    pdt = PdTable(covariate="range", edges=[0.0, 20.0], pd=[0.95])
    det = DetectionModel(pdt, ClutterParams(rate=0.5, volume=SENSOR.field_of_view * 20.0), SENSOR, buffer=False)
    mf = cls(RangeBearing(np.diag([0.1**2, 0.01**2])), det, cfg_cls(), rng=np.random.default_rng(0))
    maps, _ = mf.update(mf.empty(2), np.zeros((2, 3)), Measurements(np.array([[5.0, 0.1]])))
    assert getattr(maps, "pd_ab" if cls is LMB else "pd") is None and mf._pd_factor(maps) is None


@pytest.mark.parametrize("kind", ["glmb", "lmb"])
def test_a_run_with_the_true_p_d_learns_factors_near_one_and_repeats_its_bytes(kind):
    """glmb-paper (world 1, 5 false alarms per scan, 150 scans), 20 particles as two islands (resampled, so the factors
    follow their particles), the profile the simulator's true statistics: the labels in the map estimate learn a mean
    factor above 0.85 (the data say 1, the prior 0.95; a miss counted as a detection or the reverse, or factors left
    behind when particles are resampled, move it away), the map's features are where the landmarks are, and the same
    seed gives the same trajectory and map."""
    from calib.sim.glmb_paper import GlmbPaperConfig, simulate_glmb_paper, truth_profile
    from slam_runtime.config import SlamConfig, override
    from slam_runtime.run import run_slam

    sim = GlmbPaperConfig(clutter=5.0)
    log, prof = simulate_glmb_paper(sim, 1), truth_profile(sim)
    cfg = override(
        SlamConfig(), particles=20, islands=2, **{"filter.kind": kind, "filter.learn_pd": True, "detection.buffer_zone": False}
    )
    runs = []
    for _ in range(2):
        last = _Last()
        res = run_slam(log, prof, cfg, seed=3, max_frames=150, hooks=(last,))
        runs.append(res)
    np.testing.assert_array_equal(runs[0].map_xy, runs[1].map_xy)
    np.testing.assert_array_equal(runs[0].trajectory, runs[1].trajectory)
    slam = last.slam
    i = int(np.argmax(slam.logw))
    lab, _, _ = slam.mf.labels(slam.maps, i)
    assert lab.size >= 5
    if kind == "lmb":
        ab = slam.maps.pd_ab[i][[int(np.flatnonzero(slam.maps.tracks.label[i] == lb)[0]) for lb in lab]]
    else:
        ab = slam.maps.pd.get(lab[None], prior_ab(slam.mf.cfg))[0]
    assert mean_factor(ab).mean() > 0.85, mean_factor(ab)
    d = np.linalg.norm(runs[0].map_xy[:, None] - log.landmarks.xy[None], axis=2)
    assert np.median(d.min(axis=1)) < 0.3


def test_label_factors_store_one_density_per_particle_and_label():
    """delta-GLMB's store: one entry per (particle, label), the first given; a label a particle does not hold (or an
    empty slot) reads as the prior; resampling takes whole rows."""
    from slam_runtime.pd_factor import LabelFactors

    store = LabelFactors.build(
        3, np.array([0, 0, 2, 0]), np.array([7, 5, 7, 7]), np.array([[1.0, 1.0], [2.0, 1.0], [3.0, 1.0], [9.0, 9.0]])
    )
    prior = np.array([19.0, 1.0])
    got = store.get(np.array([[7, 5, -1], [7, 5, 7], [5, 7, 8]]), prior)
    np.testing.assert_array_equal(got[0], [[1.0, 1.0], [2.0, 1.0], prior])
    np.testing.assert_array_equal(got[1], [prior, prior, prior])
    np.testing.assert_array_equal(got[2], [prior, [3.0, 1.0], prior])
    np.testing.assert_array_equal(
        store.take(np.array([2, 2, 0])).get(np.array([[7], [7], [5]]), prior), [[[3.0, 1.0]], [[3.0, 1.0]], [[2.0, 1.0]]]
    )
