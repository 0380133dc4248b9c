"""The k best associations (Murty on clusters, merged) against a brute-force enumeration of every association."""

import numpy as np
import pytest

from slam_runtime.kbest import kbest_batch, kbest_one, murty


def _enumerate(score: np.ndarray) -> list[tuple[float, tuple[int, ...]]]:
    """Every association of score (A, M) (-inf: not admissible): (total, the measurement of each row or -1), best first."""
    a, m = score.shape
    out = []

    def rec(i, used, cur, tot):
        if i == a:
            out.append((tot, tuple(cur)))
            return
        rec(i + 1, used, [*cur, -1], tot)
        for j in range(m):
            if j not in used and np.isfinite(score[i, j]):
                rec(i + 1, used | {j}, [*cur, j], tot + score[i, j])

    rec(0, frozenset(), [], 0.0)
    return sorted(out, key=lambda t: -t[0])


def _check(score, assign, total, k, max_diff):
    """The solver's list is the enumeration's k best (totals to rounding; ties may come in any order), each solution
    valid, distinct and scored right, and the cut at max_diff below the best honoured."""
    every = _enumerate(score)
    expect = [t for t, _ in every if t >= every[0][0] - max_diff][:k]
    np.testing.assert_allclose(total, expect, rtol=0, atol=1e-9)
    seen = set()
    for q in range(total.size):
        row = assign[q]
        used = [j for j in row if j >= 0]
        assert len(used) == len(set(used))
        assert total[q] == pytest.approx(sum(score[i, j] for i, j in enumerate(row) if j >= 0), abs=1e-9)
        seen.add(tuple(row))
    assert len(seen) == total.size


@pytest.mark.parametrize("density", [0.25, 0.6, 1.0])
def test_kbest_matches_brute_force(density):
    """Random problems of up to 5 x 5 with scores of either sign, k up to 8: the same list as the enumeration."""
    rng = np.random.default_rng(int(density * 100))
    for _ in range(150):
        a, m = rng.integers(0, 6), rng.integers(0, 6)
        s = rng.normal(1.0, 2.0, (a, m))
        s[rng.uniform(size=(a, m)) > density] = -np.inf
        k = int(rng.integers(1, 9))
        assign, total = kbest_one(s, k, 1e9)
        _check(s, assign, total, k, 1e9)


def test_max_diff_cuts_the_list():
    """Only associations within max_diff nats of the best are returned."""
    rng = np.random.default_rng(3)
    for _ in range(100):
        s = rng.normal(2.0, 2.0, (4, 4))
        s[rng.uniform(size=(4, 4)) > 0.5] = -np.inf
        assign, total = kbest_one(s, 10, 1.5)
        _check(s, assign, total, 10, 1.5)


def test_murty_alone_on_one_cluster():
    """Murty's method on a dense 4 x 3 problem (one cluster) against the enumeration."""
    rng = np.random.default_rng(7)
    s = rng.normal(1.0, 1.0, (4, 3))
    assign, total = murty(s, 6, 1e9)
    _check(s, assign, total, 6, 1e9)


def test_batch_is_each_problem_alone():
    """kbest_batch over padded problems gives each problem's own list, padding rows left at -1."""
    rng = np.random.default_rng(11)
    n, a, m, k = 20, 5, 4, 3
    s = rng.normal(1.0, 2.0, (n, a, m))
    s[rng.uniform(size=s.shape) > 0.5] = -np.inf
    nact = rng.integers(0, a + 1, n)
    assign, total, count = kbest_batch(s, nact, k, 1e9)
    for p in range(n):
        one_a, one_t = kbest_one(s[p, : nact[p]], k, 1e9)
        assert count[p] == one_t.size
        np.testing.assert_array_equal(total[p, : count[p]], one_t)
        np.testing.assert_array_equal(assign[p, : count[p], : nact[p]], one_a)
        assert (assign[p, :, nact[p] :] == -1).all()
        assert np.isneginf(total[p, count[p] :]).all()
