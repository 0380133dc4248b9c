"""Clutter statistics: counts per frame and where false alarms fall, against seeded truth."""

import numpy as np
import pytest
from scipy.stats import poisson

from calib.clutter import ClutterModelConfig, batch_means_ci, dispersion_test, fit_density, fit_negative_binomial, nb_pmf_sf, pearson
from calib.fits import fit_clutter
from detectors.sensor_log import SensorModel
from detectors.model import DetectionModel
from profiles.schema import ClutterParams, PdTable


def nb_counts(rng, n, mu, r):
    return rng.poisson(rng.gamma(r, mu / r, n))


def test_negative_binomial_is_recovered_and_the_poisson_rejected():
    c = nb_counts(np.random.default_rng(1), 5000, 3.0, 2.0)
    fit = fit_negative_binomial(c)
    # 5,000 frames: the shape's relative s.e. is ~6 % here; 20 % is three of them
    assert fit.mean == pytest.approx(3.0, rel=0.05) and fit.size == pytest.approx(2.0, rel=0.2)
    assert dispersion_test(fit).p_value < 1e-10
    f = fit_clutter(c)
    assert f.count_model == "negative_binomial" and f.size == fit.size and f.nb_gof.p_value > 0.001
    assert f.p_value < 1e-10  # the thesis's Poisson test rejects too


def test_poisson_counts_keep_the_poisson():
    c = np.random.default_rng(2).poisson(3.0, 5000)
    f = fit_clutter(c)
    assert f.count_model == "poisson" and f.size is None and f.dispersion_test.p_value > 0.05
    assert f.p_value > 0.01 and f.dispersion == pytest.approx(1.0, abs=0.06)


def test_pearson_against_a_fixed_model():
    c = nb_counts(np.random.default_rng(3), 4000, 2.0, 1.0)
    pmf, sf = nb_pmf_sf(2.0, 1.0)
    right = pearson(c, pmf, sf, fitted=0)
    wrong = pearson(c, lambda k: poisson.pmf(k, 2.0), lambda k: poisson.sf(k, 2.0), fitted=0)
    assert right.p_value > 0.001 and wrong.p_value < 1e-20
    assert right.expected.min() >= 5 and right.observed.sum() == 4000 and right.dof == right.observed.size - 1


def test_batch_means_interval_covers_the_rate_of_correlated_frames():
    # a clutter source in view for ~50 frames at a time: counts correlate over neighbouring frames
    rng = np.random.default_rng(4)
    hits, naive_hits = 0, 0
    for _ in range(200):
        on = np.repeat(rng.uniform(size=40) < 0.5, 50)
        c = rng.poisson(np.where(on, 2.0, 0.2))
        m, lo, hi = batch_means_ci(c)
        hits += lo <= 1.1 <= hi
        half = 1.96 * c.std(ddof=1) / np.sqrt(c.size)
        naive_hits += m - half <= 1.1 <= m + half
    # 200 replicates: a 95 % interval covers 190 +- 6; the naive one, blind to the correlation, far fewer
    assert 175 <= hits <= 200 and naive_hits < 120


def test_density_is_recovered_and_the_uniform_kept_when_true():
    rng = np.random.default_rng(5)
    re_, be = np.linspace(0, 6, 7), np.linspace(-0.5, 0.5, 5)
    n = 8000
    fold = np.arange(n) % 4
    r = rng.triangular(0, 0, 6, n)  # density 2 (6 - r) / 36 over range, uniform over bearing
    b = rng.uniform(-0.5, 0.5, n)
    d = fit_density(r, b, fold, re_, be, ClutterModelConfig(), "blocks (4)")
    assert d.selection.chosen != "uniform"
    mid = (re_[:-1] + re_[1:]) / 2
    truth = 2 * (6 - mid) / 36 / 1.0  # per m rad: the bearing span is 1 rad
    # cells of ~2,000 to ~170 points: 15 % + 0.005 absolute covers the statistical error and the smoothing
    np.testing.assert_allclose(np.asarray(d.density).mean(axis=1), truth, rtol=0.15, atol=0.005)
    flat = fit_density(rng.uniform(0, 6, n), rng.uniform(-0.5, 0.5, n), fold, re_, be, ClutterModelConfig(), "blocks (4)")
    dens = np.asarray(flat.density)
    assert dens.max() / dens.min() < 1.3  # uniform data: the uniform density or a histogram smoothed close to it
    one = fit_density(r, b, np.zeros(n), re_, be, ClutterModelConfig(), "one")
    assert one.selection is None and np.asarray(one.density).shape == (1, 1)


def test_spatial_kappa_integrates_to_the_rate():
    rng = np.random.default_rng(6)
    re_, be = np.linspace(0, 8, 9), np.linspace(-0.6, 0.6, 7)
    r = rng.triangular(0, 0, 8, 5000)
    d = fit_density(r, rng.uniform(-0.6, 0.6, 5000), np.arange(5000) % 3, re_, be, ClutterModelConfig(), "x")
    sensor = SensorModel(kind="camera", fov=1.2, range_max=8.0)
    clutter = ClutterParams(rate=0.7, volume=1.2 * 8.0, density=d)
    m = DetectionModel(PdTable(covariate="range", edges=[0, 8], pd=[0.5]), clutter, sensor)
    z = np.column_stack([rng.uniform(0, 10, 400_000), rng.uniform(-np.pi, np.pi, 400_000)])
    # Monte Carlo over a box of 10 m x 2 pi: s.e. ~0.5 %
    assert m.clutter_intensity(z).mean() * 10 * 2 * np.pi == pytest.approx(0.7, rel=0.02)
    k = m.clutter_intensity(np.array([[0.5, 0.0], [7.5, 0.0], [3.0, 1.0]]))
    assert k[0] > 5 * k[1] and k[2] == 0.0  # near is denser; outside the field of view nothing
