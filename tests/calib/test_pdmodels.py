"""P_D models and pooling across sensors, against seeded truth."""

import numpy as np
import pandas as pd
import pytest
from scipy.special import expit

from calib.pdmodels import beta_binomial_concentration, design_effect, fit_additive_logit, pool_sensors
from profiles.schema import PdTable


def test_additive_logit_recovers_an_additive_surface():
    rng = np.random.default_rng(1)
    a, c = np.linspace(1.0, -2.0, 6), np.array([-1.0, 0.0, 0.5, 0.0, -1.0])
    p = expit(a[:, None] + c[None, :])
    n = rng.integers(300, 3000, p.shape)
    k = rng.binomial(n, p)
    est = fit_additive_logit(k, n, ridge=1.0)
    # cells of 300-3000 pairs sharing 11 parameters: errors well under 0.03
    np.testing.assert_allclose(est, p, atol=0.03)
    assert fit_additive_logit(np.zeros((3, 2)), np.full((3, 2), 100), 1.0).max() < 0.02  # no detections: finite, near 0


def test_beta_binomial_concentration():
    rng = np.random.default_rng(2)
    p = np.linspace(0.2, 0.7, 12)
    n = np.full((8, 12), 400)
    m_true = 20.0
    q = rng.beta(m_true * p, m_true * (1 - p), (8, 12))  # every sensor its own P_D per bin
    m = beta_binomial_concentration(rng.binomial(n, q), n, p)
    assert m_true / 2 < m < 2 * m_true  # 96 sensor-bins: m is known to within a factor ~1.5
    same = rng.binomial(n, np.broadcast_to(p, (8, 12)))
    assert beta_binomial_concentration(same, n, p) is None  # identical sensors: complete pooling


def test_design_effect_of_clustered_outcomes():
    rng = np.random.default_rng(3)
    p = np.full(20000, 0.3)
    y = np.repeat(rng.uniform(size=2000) < 0.3, 10)  # one draw per cluster of 10 pairs
    cl = np.repeat(np.arange(2000), 10)
    assert design_effect(y, p, cl) == pytest.approx(10, rel=0.15)
    assert design_effect(rng.uniform(size=20000) < 0.3, p, cl) == pytest.approx(1, abs=0.15)


def test_partial_pooling_helps_the_sensor_with_little_data():
    rng = np.random.default_rng(4)
    edges = np.arange(0.0, 6.5, 0.5)
    mid = (edges[:-1] + edges[1:]) / 2
    base = 0.9 - 0.12 * mid
    levels = [0.0, 0.05, -0.05, -0.15]  # sensor offsets; the last has little data
    rows = []
    for s, off in enumerate(levels):
        n = 20000 if s < 3 else 600
        r = rng.uniform(0, 6, n)
        rows.append(pd.DataFrame({"range": r, "detected": rng.uniform(size=n) < np.clip(0.9 - 0.12 * r + off, 0, 1), "s": s}))
    pairs = pd.concat(rows, ignore_index=True)
    i = np.clip(np.searchsorted(edges, pairs["range"], side="right") - 1, 0, mid.size - 1)
    pooled_rate = np.bincount(i, weights=pairs["detected"], minlength=mid.size) / np.bincount(i, minlength=mid.size)
    pooled = PdTable(covariate="range", edges=edges.tolist(), pd=pooled_rate.tolist())
    pool = pool_sensors(pooled, pairs, pairs["s"].to_numpy(), ["a", "b", "c", "d"])
    assert pool.concentration is not None and pool.between_sd > 0.02
    small = np.asarray(pool.tables[3].pd)
    w = pairs["s"] == 3
    k = np.bincount(i[w], weights=pairs.loc[w, "detected"], minlength=mid.size)
    raw = k / np.maximum(np.bincount(i[w], minlength=mid.size), 1)
    truth = np.clip(base - 0.15, 0, 1)
    # shrinking ~50 pairs per bin toward the pooled table beats the raw rates on average
    assert np.abs(small - truth).mean() < np.abs(raw - truth).mean()
    assert pool.tables[3].model == "partial_pooling" and pool.tables[0].counts == np.bincount(i[pairs["s"] == 0], minlength=mid.size).tolist()
    assert pool.pd_observed[3] < pool.pd_predicted[3]  # the low sensor sees less than the pooled model predicts
