"""Compiled helpers the labelled filters' kernels share (:mod:`slam_runtime.gibbs`, :mod:`slam_runtime.hypotheses`).

One angle's wrap (:func:`wrap_scalar`), the optimal assignment (:func:`hungarian`: a shortest-augmenting-path solver
checked against ``scipy.optimize.linear_sum_assignment`` in the tests), a stable
argsort, growing output buffers, the squared Mahalanobis distance of two
Gaussians, and the last steps both kernels take on a particle's weighted
hypotheses: add the log weights of identical ones (:func:`logaddexp`), keep the
heaviest above a pruning threshold and under a cap (:func:`prune_cap`), and the
log normaliser of those kept (:func:`log_norm`).
"""

from __future__ import annotations

import numba
import numpy as np

BIG = 1e15  # a forbidden pair in the assignment (every row has a finite option: its own dummy column)


@numba.njit(cache=True, nogil=True)
def wrap_scalar(a):  # pragma: no cover - compiled
    """One angle to (-pi, pi], one conditional shift each way: the compiled kernels' :func:`slam_runtime.features.wrap`."""
    if a > np.pi:
        a -= 2 * np.pi
    if a <= -np.pi:
        a += 2 * np.pi
    return a


@numba.njit(cache=True, nogil=True)
def hungarian(cost):  # pragma: no cover - compiled
    """Minimum-cost assignment of every row of ``cost`` (n, m), n <= m, to a distinct column.

    Shortest augmenting paths with row and column potentials (Kuhn-Munkres in
    O(n^2 m)). Returns (n,) int64 column indices. Costs must be finite (use a
    large value for forbidden pairs).
    """
    n, m = cost.shape
    u = np.zeros(n + 1)
    v = np.zeros(m + 1)
    p = np.zeros(m + 1, np.int64)
    way = np.zeros(m + 1, np.int64)
    minv = np.empty(m + 1)
    used = np.empty(m + 1, np.bool_)
    for i in range(1, n + 1):
        p[0] = i
        j0 = 0
        minv[:] = np.inf
        used[:] = False
        while True:
            used[j0] = True
            i0 = p[j0]
            delta = np.inf
            j1 = 0
            for j in range(1, m + 1):
                if not used[j]:
                    cur = cost[i0 - 1, j - 1] - u[i0] - v[j]
                    if cur < minv[j]:
                        minv[j] = cur
                        way[j] = j0
                    if minv[j] < delta:
                        delta = minv[j]
                        j1 = j
            for j in range(m + 1):
                if used[j]:
                    u[p[j]] += delta
                    v[j] -= delta
                else:
                    minv[j] -= delta
            j0 = j1
            if p[j0] == 0:
                break
        while True:
            j1 = way[j0]
            p[j0] = p[j1]
            j0 = j1
            if j0 == 0:
                break
    out = np.full(n, -1, np.int64)
    for j in range(1, m + 1):
        if p[j] != 0:
            out[p[j] - 1] = j - 1
    return out


@numba.njit(cache=True, nogil=True)
def argsort_stable(x):  # pragma: no cover - compiled
    """Stable ascending argsort (bottom-up merge sort) of a 1-d array; compiles much faster than np.argsort."""
    n = x.shape[0]
    idx = np.arange(n)
    tmp = np.empty(n, np.int64)
    width = 1
    while width < n:
        i = 0
        while i < n:
            mid = min(i + width, n)
            hi = min(i + 2 * width, n)
            a = i
            b = mid
            k = i
            while a < mid and b < hi:
                if x[idx[b]] < x[idx[a]]:
                    tmp[k] = idx[b]
                    b += 1
                else:
                    tmp[k] = idx[a]
                    a += 1
                k += 1
            while a < mid:
                tmp[k] = idx[a]
                a += 1
                k += 1
            while b < hi:
                tmp[k] = idx[b]
                b += 1
                k += 1
            i += 2 * width
        idx, tmp = tmp, idx
        width *= 2
    return idx


@numba.njit(cache=True, nogil=True)
def maha2(c, ci, x, a, b, work):  # pragma: no cover - compiled
    """dd^T c[ci]^-1 dd with dd = x[a] - x[b], for a small symmetric positive definite c[ci] (d, d), by Gaussian
    elimination in the scratch ``work`` (d, d + 3) (rows indexed here, not sliced: a view or a temporary per pair
    costs more than the elimination)."""
    d = x.shape[1]
    for r in range(d):
        for k in range(d):
            work[r, k] = c[ci, r, k]
        work[r, d] = x[a, r] - x[b, r]
        work[r, d + 1] = work[r, d]
    for i in range(d):
        piv = work[i, i]
        if piv <= 1e-300:
            return np.inf
        for r in range(i + 1, d):
            f = work[r, i] / piv
            for k in range(i, d):
                work[r, k] -= f * work[i, k]
            work[r, d] -= f * work[i, d]
    for i in range(d - 1, -1, -1):
        t = work[i, d]
        for k in range(i + 1, d):
            t -= work[i, k] * work[k, d + 2]
        work[i, d + 2] = t / work[i, i]
    m2 = 0.0
    for i in range(d):
        m2 += work[i, d + 1] * work[i, d + 2]
    return m2


@numba.njit(cache=True, nogil=True)
def grow(a, need):  # pragma: no cover - compiled
    """``a`` (an output buffer of ints or floats) with room for ``need`` entries: itself, or a copy twice as long."""
    if need <= a.shape[0]:
        return a
    b = np.empty(max(need, 2 * a.shape[0]), a.dtype)
    b[: a.shape[0]] = a
    return b


@numba.njit(cache=True, nogil=True)
def logaddexp(a, b):  # pragma: no cover - compiled
    """log(exp(a) + exp(b)), from the larger: the weight of two identical hypotheses merged."""
    hi = max(a, b)
    return hi + np.log(np.exp(a - hi) + np.exp(b - hi))


@numba.njit(cache=True, nogil=True)
def prune_cap(lw, alive, ref, prune, cap):  # pragma: no cover - compiled
    """The hypotheses to keep, heaviest first: of those ``alive`` (N,), by their log weights lw (N,), the heaviest
    always, then each whose weight relative to exp(ref) is at least ``prune``, at most ``cap`` of them.
    Returns (kept (N,) indices, how many, whether the cap bound)."""
    n = lw.shape[0]
    cand = np.empty(n, np.int64)
    nc = 0
    for h in range(n):
        if alive[h]:
            cand[nc] = h
            nc += 1
    neg = np.empty(nc)
    for q in range(nc):
        neg[q] = -lw[cand[q]]
    srt = argsort_stable(neg)
    kept = np.empty(nc, np.int64)
    nk = 0
    capped = False
    for q in range(nc):
        h = cand[srt[q]]
        if nk > 0 and np.exp(lw[h] - ref) < prune:
            break
        if nk >= cap:
            capped = True
            break
        kept[nk] = h
        nk += 1
    return kept, nk, capped


@numba.njit(cache=True, nogil=True)
def log_norm(lw, kept, nk):  # pragma: no cover - compiled
    """log of the summed weight of the kept hypotheses (kept[:nk], heaviest first), from the heaviest; 0 for none."""
    if nk == 0:
        return 0.0
    mx = lw[kept[0]]
    tot = 0.0
    for q in range(nk):
        tot += np.exp(lw[kept[q]] - mx)
    return mx + np.log(tot)
