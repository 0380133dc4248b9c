"""Validation scores against hand-computed values and seeded truth."""

import numpy as np
import pytest

from calib.scoring import ece_noise_blocks, score_counts, score_coverage, score_pd
from profiles.schema import ClutterParams


def test_scores_of_a_small_hand_computed_case():
    s, t = score_pd(np.array([0.0, 0.0, 0.25, 0.25, 0.75]), np.array([0, 1, 0, 1, 1], dtype=bool))
    assert (s["pairs_predicted_zero"], s["detections_where_zero_predicted"], s["pairs_informative"]) == (2, 1, 3)
    # bins (0.2, 0.3]: 2 pairs, observed 0.5 vs 0.25; (0.7, 0.8]: 1 pair, observed 1 vs 0.75
    assert s["ece"] == pytest.approx(2 / 3 * 0.25 + 1 / 3 * 0.25)
    assert s["brier"] == pytest.approx((0 + 1 + 0.0625 + 0.5625 + 0.0625) / 5)
    assert s["loglik_per_pair"] == pytest.approx(np.mean(np.log([1 - 1e-3, 1e-3, 0.75, 0.25, 0.75])))
    assert t.loc[0, "pairs"] == 2 and t.loc[3, "pairs"] == 2 and t.loc[8, "pairs"] == 1


def test_calibrated_predictions_score_near_their_noise_and_biased_ones_do_not():
    rng = np.random.default_rng(1)
    p = rng.uniform(0.05, 0.95, 50000)
    y = rng.uniform(size=p.size) < p
    s, _ = score_pd(p, y)
    assert s["ece"] < 3 * s["ece_if_calibrated"] and s["ece_if_calibrated"] < 0.01
    assert s["brier"] == pytest.approx(np.mean(p * (1 - p)), abs=0.003)
    biased, _ = score_pd(0.7 * p, y)
    assert biased["ece"] == pytest.approx(0.3 * p.mean(), abs=0.01)  # every bin is off by 30 % of its P_D


def test_block_noise_floor_grows_with_correlated_outcomes():
    rng = np.random.default_rng(2)
    p = np.full(20000, 0.4)
    cl = np.repeat(np.arange(2000), 10)
    y_ind = rng.uniform(size=p.size) < p
    y_cl = np.repeat(rng.uniform(size=2000) < 0.4, 10)
    f_ind = ece_noise_blocks(p, y_ind, cl)
    f_cl = ece_noise_blocks(p, y_cl, cl)
    binom = np.sqrt(2 * 0.4 * 0.6 / (np.pi * p.size))
    assert f_ind == pytest.approx(binom, rel=0.15) and f_cl == pytest.approx(np.sqrt(10) * binom, rel=0.2)


def test_false_alarm_scores():
    rng = np.random.default_rng(3)
    clutter = ClutterParams(rate=2.0, volume=10.0)
    ok = score_counts(rng.poisson(2.0, 5000), clutter)
    lo, hi = ok["false_alarm_relative_error_ci95"]
    assert lo < 0 < hi and ok["clutter_chi2_p_value"] > 0.001 and ok["clutter_chi2_dof"] >= 5
    high = score_counts(rng.poisson(2.4, 5000), clutter)
    assert high["false_alarm_relative_error"] == pytest.approx(0.2, abs=0.03) and high["clutter_chi2_p_value"] < 1e-10
    nb = ClutterParams(rate=2.0, volume=10.0, count_model="negative_binomial", size=1.0)
    assert score_counts(rng.poisson(rng.gamma(1.0, 2.0, 5000)), nb)["clutter_chi2_p_value"] > 0.001


def test_coverage():
    s = score_coverage(np.r_[np.ones(990, bool), np.zeros(10, bool)], 0.999)
    assert s["hotelling_coverage"] == 0.99 and s["hotelling_misses_vs_stated"] == pytest.approx(10)
    assert s["hotelling_coverage_ci95"][0] < 0.99 < s["hotelling_coverage_ci95"][1]
