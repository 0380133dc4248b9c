"""Gaussian-mixture batches: Vo & Ma pruning and merging in 2 and 3 dimensions, the cap, densities."""

import numpy as np
import pytest
from scipy.stats import multivariate_normal

from slam_runtime.gm import GMBatch, det, inv, prune_merge


def test_prune_merge_follows_vo_and_ma():
    w = np.array([[0.6, 0.3, 0.05, 1e-6]])
    mu = np.array([[[0.0, 0.0], [0.1, 0.0], [5.0, 5.0], [9.0, 9.0]]])
    cov = np.tile(np.eye(2) * 0.04, (1, 4, 1, 1))
    out, capped = prune_merge(GMBatch(w, mu, cov), prune=1e-4, merge=4.0, cap=10)
    assert out.w.shape == (1, 2) and not capped
    np.testing.assert_allclose(out.w[0], [0.9, 0.05])
    np.testing.assert_allclose(out.mu[0, 0], [0.1 * 0.3 / 0.9, 0.0])  # weighted mean
    # the merged covariance adds the spread of the means
    spread = 0.6 * (0.1 * 0.3 / 0.9) ** 2 + 0.3 * (0.1 - 0.1 * 0.3 / 0.9) ** 2
    assert out.cov[0, 0, 0, 0] == pytest.approx(0.04 + spread / 0.9)
    inflated, _ = prune_merge(GMBatch(w, mu, cov), prune=1e-4, merge=4.0, cap=10, inflate=1.5)
    assert inflated.cov[0, 0, 0, 0] == pytest.approx(0.04 + 1.5 * spread / 0.9)  # the spread of the means inflated
    assert inflated.cov[0, 0, 1, 1] == pytest.approx(0.04)  # the means differ only in x
    np.testing.assert_allclose(inflated.cov[0, 1], out.cov[0, 1])  # a group of one is not inflated


def test_inflation_does_not_compound_when_a_feature_merges_with_its_own_update():
    """A feature of P_D 0.3 seen every step: its missed copy (weight 0.7, the prior covariance) and its
    updated copy merge at every step. Inflating the whole merged covariance by 1.5 grows it by
    ~1.05x per step without bound; inflating the spread of the means keeps it near the updated size."""
    rng = np.random.default_rng(0)
    r = np.eye(2) * 0.01
    for whole in (False, True):
        m, p = np.zeros(2), np.eye(2) * 0.01
        for _ in range(300):
            z = rng.normal(0.0, 0.1, 2)
            k = p @ np.linalg.inv(p + r)
            mu = np.stack([m, m + k @ (z - m)])
            cov = np.stack([p, p - k @ p])
            out, _ = prune_merge(GMBatch(np.array([[0.7, 0.3]]), mu[None], cov[None]), prune=1e-4, merge=1e9, cap=5, inflate=1.0 if whole else 1.5)
            m, p = out.mu[0, 0], out.cov[0, 0] * (1.5 if whole else 1.0)
        if whole:
            assert np.trace(p) > 1e3  # the C++-style factor explodes
        else:
            assert np.trace(p) < 0.02  # bounded by the prior it started from plus the spread of the updates


def test_merging_in_three_dimensions_and_the_cap():
    rng = np.random.default_rng(0)
    centres = rng.uniform(-50, 50, (8, 3))
    mu = np.repeat(centres, 3, axis=0) + rng.normal(0, 0.01, (24, 3))  # 8 clusters of 3
    w = rng.uniform(0.2, 1.0, 24)
    cov = np.tile(np.eye(3) * 0.1, (24, 1, 1))
    gm = GMBatch(np.stack([w, w[::-1]]), np.stack([mu, mu[::-1]]), np.stack([cov, cov]))
    out, capped = prune_merge(gm, prune=1e-3, merge=4.0, cap=50)
    assert out.shape == (2, 8) and not capped
    np.testing.assert_allclose(np.sort(out.w, axis=1), np.sort(np.add.reduceat(w, np.arange(0, 24, 3)))[None].repeat(2, 0))
    few, capped = prune_merge(gm, prune=1e-3, merge=4.0, cap=5)
    assert few.shape == (2, 5) and capped
    # the cap drops the lightest groups
    np.testing.assert_allclose(np.sort(few.w[0])[::-1], np.sort(out.w[0])[::-1][:5])


def test_density_and_small_matrix_algebra():
    rng = np.random.default_rng(3)
    a = rng.normal(size=(5, 2, 2))
    c = a @ np.swapaxes(a, 1, 2) + np.eye(2) * 0.1
    np.testing.assert_allclose(inv(c), np.linalg.inv(c), rtol=1e-10)
    np.testing.assert_allclose(det(c), np.linalg.det(c), rtol=1e-10)
    gm = GMBatch(np.array([[0.5, 2.0]]), np.array([[[0.0, 0.0], [1.0, 1.0]]]), c[None, :2])
    pts = np.array([[[0.3, -0.2], [1.0, 0.5]]])
    want = [0.5 * multivariate_normal(gm.mu[0, 0], c[0]).pdf(q) + 2.0 * multivariate_normal(gm.mu[0, 1], c[1]).pdf(q) for q in pts[0]]
    np.testing.assert_allclose(gm.density(pts)[0], want, rtol=1e-10)


def test_mutual_merge_keeps_two_close_landmarks_apart():
    """Two landmarks 0.7 m apart (closer than a broad component's gate): a broad component of the first (a
    feature seen once from afar, 0.5 m std) and tight updates of both (5 cm std), sampled around the truth.
    Vo & Ma's rule (the head's gate only) lets the heavy broad head swallow the second landmark; the
    mutual rule keeps it, and each merged mean stays on its own landmark."""
    rng = np.random.default_rng(7)
    truth = np.array([[0.0, 0.0], [0.7, 0.0]])
    tight = 0.05**2 * np.eye(2)
    mu = np.concatenate([truth[[0]] + rng.normal(0, 0.05, (1, 2)), truth[[0]] + rng.normal(0, 0.05, (3, 2)), truth[[1]] + rng.normal(0, 0.05, (3, 2))])
    cov = np.stack([0.5**2 * np.eye(2)] + [tight] * 6)
    w = np.array([[2.0, 0.3, 0.3, 0.3, 0.3, 0.3, 0.3]])
    head, _ = prune_merge(GMBatch(w, mu[None], cov[None]), prune=1e-3, merge=4.0, cap=10)
    assert head.shape == (1, 1)  # the second landmark is gone: 0.7 m is inside the broad head's 2-sigma gate
    mutual, _ = prune_merge(GMBatch(w, mu[None], cov[None]), prune=1e-3, merge=4.0, cap=10, mutual=True)
    assert (mutual.w[0] > 0.5).sum() == 2
    near = np.hypot(*(mutual.mu[0][:, None, :] - truth[None]).transpose(2, 0, 1)).min(axis=0)
    # each landmark has a component within 0.15 m: 3 std of one tight sample (the broad head pulls the first
    # landmark's group mean by at most its sampled offset)
    assert (near < 0.15).all()
    np.testing.assert_allclose(mutual.w.sum(), w.sum())  # merging moves weight, never loses it
    # duplicates of one landmark (each inside the other's gate) still merge under the mutual rule
    dup, _ = prune_merge(GMBatch(np.array([[0.6, 0.5]]), truth[[0, 0]][None] + np.array([[[0.0, 0.0], [0.05, 0.0]]]), np.stack([tight, tight])[None]), mutual=True)
    assert dup.shape == (1, 1) and dup.w[0, 0] == pytest.approx(1.1)
