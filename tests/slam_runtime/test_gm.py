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


def _vo_ma_groups(w, mu, cov, prune, merge, mutual=False, fresh=None):
    """Brute-force Vo & Ma grouping of one mixture (every pair, no spatial window): the weights of the groups,
    heaviest head first. fresh: pairs of two non-fresh components are not tested."""
    icov = np.linalg.inv(cov)
    left = [i for i in np.argsort(-w, kind="stable") if w[i] > prune]
    out = []
    while left:
        i, rest = left[0], left[1:]
        group = [i]
        for j in rest:
            if fresh is not None and not (fresh[i] or fresh[j]):
                continue
            d = mu[j] - mu[i]
            if d @ icov[i] @ d <= merge and (not mutual or d @ icov[j] @ d <= merge):
                group.append(j)
        out.append(w[group].sum())
        left = [j for j in rest if j not in group]
    return np.array(out)


@pytest.mark.parametrize("mutual", [False, True])
def test_grouping_matches_the_brute_force_rule_on_random_mixtures(mutual):
    """The compiled grouping tests only neighbours along x (within sqrt(merge trace(cov)) of the head) and,
    given fresh flags, only pairs with a fresh component: the groups must be those of testing every pair."""
    rng = np.random.default_rng(11)
    for trial in range(30):
        j = int(rng.integers(5, 120))
        centres = rng.uniform(-30, 30, (max(1, j // 3), 2))
        mu = centres[rng.integers(0, len(centres), j)] + rng.normal(0, 0.3, (j, 2))
        a = rng.normal(0, 1, (j, 2, 2)) * rng.uniform(0.05, 0.6, (j, 1, 1))
        cov = a @ np.swapaxes(a, 1, 2) + 1e-3 * np.eye(2)
        w = rng.uniform(0, 1.2, j)
        fresh = rng.random(j) < 0.3 if trial % 2 else None
        out, _ = prune_merge(
            GMBatch(w[None], mu[None], cov[None]), prune=1e-3, merge=4.0, cap=500, mutual=mutual, fresh=None if fresh is None else fresh[None]
        )
        want = _vo_ma_groups(w, mu, cov, 1e-3, 4.0, mutual, fresh)
        got = out.w[0][out.w[0] > 0]
        np.testing.assert_allclose(np.sort(got), np.sort(want), rtol=1e-12)
        assert len(want) < (w > 1e-3).sum() or trial > 25  # merges happen


def test_a_merged_component_is_tested_again_at_the_next_merge():
    """A and B merge into one broad component; C lay outside A's gate (A's own covariance) but lies inside the
    merged one's. At the next merge, with nothing in view (no fresh component), C joins only when the merged
    component is flagged as formed by the last merge, as testing every pair does."""
    tight = 0.1**2 * np.eye(2)
    mu = np.array([[[0.0, 0.0], [0.25, 0.0], [-0.35, 0.0]]])  # A, B, C
    w = np.array([[1.0, 0.9, 0.3]])
    first, _, merged = prune_merge(GMBatch(w[:, :2], mu[:, :2], np.stack([tight, tight])[None]), prune=1e-3, merge=9.0, cap=10, groups=True)
    assert first.shape == (1, 1) and merged.tolist() == [[True]]
    assert (mu[0, 2] - mu[0, 0]) @ np.linalg.inv(tight) @ (mu[0, 2] - mu[0, 0]) > 9.0  # C was outside A's gate
    gm = first.concat(GMBatch(w[:, 2:], mu[:, 2:], tight[None, None]))
    every, _ = prune_merge(gm, prune=1e-3, merge=9.0, cap=10)
    flagged, _ = prune_merge(gm, prune=1e-3, merge=9.0, cap=10, fresh=np.array([[True, False]]))
    unflagged, _ = prune_merge(gm, prune=1e-3, merge=9.0, cap=10, fresh=np.array([[False, False]]))
    assert every.shape == flagged.shape == (1, 1) and unflagged.shape == (1, 2)
    np.testing.assert_array_equal(flagged.mu, every.mu)
