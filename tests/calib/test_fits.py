import numpy as np
import pytest
from scipy.stats import chi2

from calib.fits import PdFitConfig, auc, fit_clutter, fit_hotelling, fit_pd_table, maha2, roc_curves, wilson


def test_wilson_interval_matches_textbook_values():
    lo, hi = wilson(np.array([0, 5, 50]), np.array([10, 10, 100]))
    # Wilson score intervals (z = 1.96): 0/10 -> [0, 0.2775]; 5/10 -> [0.2366, 0.7634]; 50/100 -> [0.4038, 0.5962]
    np.testing.assert_allclose(lo, [0.0, 0.2366, 0.4038], atol=1e-4)
    np.testing.assert_allclose(hi, [0.2775, 0.7634, 0.5962], atol=1e-4)


def test_pd_table_recovers_a_seeded_truth_with_thesis_clamping():
    rng = np.random.default_rng(0)
    truth = np.array([0.0, 0.02, 0.07, 0.36, 0.76, 0.89, 0.9, 0.9, 0.9])
    n_p = rng.integers(0, 9, 200_000)
    det = rng.uniform(size=n_p.size) < truth[n_p]
    tab = fit_pd_table(n_p, det, "n_p", PdFitConfig(min_count=100, tail="last"))
    est = np.asarray(tab.pd)
    ok = truth >= 0.1
    # each bin has ~22,000 pairs: s.e. <= 0.0034, so 0.015 is more than 4 s.e.
    np.testing.assert_allclose(est[ok], truth[ok], atol=0.015)
    assert np.all(est[~ok] == 0.0)  # below 0.1 -> 0
    lo, hi = np.asarray(tab.wilson_low), np.asarray(tab.wilson_high)
    assert np.all((lo[ok] <= truth[ok]) & (truth[ok] <= hi[ok]) | (np.abs(est[ok] - truth[ok]) < 0.01))
    assert tab.lookup(np.array([50]))[0] == est[-1]  # above the last bin: the last bin's value


def test_pd_tail_is_pooled_above_the_last_populated_bin():
    n_p = np.array([0] * 500 + [1] * 500 + [2] * 300 + [3] * 10 + [4] * 10)
    det = np.array([False] * 500 + [True] * 250 + [False] * 250 + [True] * 300 + [True] * 10 + [False] * 10)
    tab = fit_pd_table(n_p, det, "n_p", PdFitConfig(min_count=300, tail="pool", zero_below=0.0))
    assert tab.edges == [0.0, 1.0, 2.0, 3.0] and tab.counts == [500, 500, 320]
    assert tab.pd[2] == pytest.approx(310 / 320)


def test_poisson_clutter_fit_recovers_the_rate_and_is_not_rejected():
    rng = np.random.default_rng(1)
    c = fit_clutter(rng.poisson(6.18, 5000))
    assert c.rate == pytest.approx(6.18, abs=3 * np.sqrt(6.18 / 5000))
    assert c.p_value > 0.01 and c.dispersion == pytest.approx(1.0, abs=0.06)
    assert np.all(c.expected >= 5.0) and c.dof == c.observed.size - 2


def test_overdispersed_clutter_is_rejected_as_the_thesis_reports():
    rng = np.random.default_rng(2)
    counts = rng.negative_binomial(3, 3 / (3 + 6.18), 5000)  # mean 6.18, variance 6.18 (1 + 6.18/3)
    c = fit_clutter(counts)
    assert c.p_value < 1e-10 and c.dispersion > 2.5


def test_hotelling_recovers_a_gaussian_and_covers_its_confidence():
    rng = np.random.default_rng(3)
    mean = np.array([-10.0, -1.3, 0.75])
    a = rng.normal(size=(3, 3))
    cov = a @ a.T / 10 + np.eye(3) * 0.01
    x = rng.multivariate_normal(mean, cov, 50_000)
    h = fit_hotelling(x, ("a", "b", "c"), 0.999)
    np.testing.assert_allclose(h.mean, mean, atol=5 * np.sqrt(np.diag(cov).max() / 50_000))
    np.testing.assert_allclose(h.cov, cov, rtol=0.05, atol=1e-3)
    assert h.gamma == pytest.approx(chi2.ppf(0.999, 3))
    fresh = rng.multivariate_normal(mean, cov, 50_000)
    assert (maha2(fresh, h.mean, h.cov) <= h.gamma).mean() == pytest.approx(0.999, abs=0.0006)


def test_auc_and_roc_on_known_separations():
    rng = np.random.default_rng(4)
    assert auc(np.array([3.0, 4.0]), np.array([1.0, 2.0])) == 1.0
    assert auc(np.array([1.0]), np.array([1.0])) == 0.5
    # two unit Gaussians one sigma apart: AUC = Phi(1 / sqrt(2)) = 0.7602
    assert auc(rng.normal(1, 1, 40_000), rng.normal(0, 1, 40_000)) == pytest.approx(0.7602, abs=0.006)
    t = rng.multivariate_normal([0, 0], np.eye(2) * 0.1, 2000)
    f = rng.multivariate_normal([2, 2], np.eye(2), 2000)
    out = roc_curves(t, f, fit_hotelling(t, ("a", "b"), 0.999))
    assert out["auc_hotelling"] > 0.95 and out["auc_fisher"] > 0.9
    fpr, tpr = out["hotelling"]
    assert fpr[0] == tpr[0] == 0 and fpr[-1] == tpr[-1] == 1 and np.all(np.diff(tpr) >= 0)
