"""The k best data associations of many small assignment problems at once (compiled): Murty's method on the
independent clusters of each problem, their solutions combined in order of total score.

A problem is a score matrix (A, M): score[a, j] the log-likelihood ratio of taking measurement j for landmark
a against leaving the landmark missed and the measurement to clutter or a new landmark (-inf: not admissible,
outside the gate or likelier clutter). An association gives each landmark at most one measurement and each
measurement at most one landmark; its score is the sum of its pairs' scores (a landmark left missed or a
measurement left free adds 0). :func:`kbest_batch` returns, for each of N problems, up to k associations in
order of decreasing score, the best first (ties in a fixed order), stopping early at the first whose score lies
more than ``max_diff`` below the best (the C++ RFS-SLAM library's ``maxDataAssocLogLikelihoodDiff``).

How: the admissible pairs split the landmarks and measurements into clusters that share no pair (connected
components of the bipartite gate graph); an association is a choice of one association per cluster, its score the
sum of theirs. Each cluster's own k best come from Murty's partitioning (Murty 1968; Cox & Miller 1995) over
the shortest-augmenting-path solver :func:`slam_runtime.kernels.hungarian` (each landmark has its own 'missed' column
of score 0, so every subproblem is square-feasible); a cluster of one landmark and one measurement has the two
solutions taken or left without a solve. The clusters' sorted lists are then merged into the k best totals by a
best-first search over index vectors in which each vector is made from exactly one parent (the one with its last
nonzero index lowered by one), so every combination is met once and in order. Most clusters of a SLAM frame are one
landmark and one measurement: the cost is a few operations per pair, not k Hungarian solves of the whole frame.

Why compiled: Murty's method and the merge are sequential searches over tiny matrices, one per (particle,
hypothesis) and step, hundreds per step; in numpy they would be a Python loop per problem.
"""

from __future__ import annotations

import numba
import numpy as np

from slam_runtime.kernels import BIG, hungarian  # BIG: a forbidden pair (a total of BIG / 2 or more: infeasible)


@numba.njit(cache=True, nogil=True)
def _solve(cost):  # pragma: no cover - compiled
    """(columns (n,), total cost) of the minimum-cost assignment of the rows of ``cost``; total >= BIG / 2: infeasible."""
    cols = hungarian(cost)
    tot = 0.0
    for i in range(cost.shape[0]):
        tot += cost[i, cols[i]]
    return cols, tot


@numba.njit(cache=True, nogil=True)
def murty(score, k, max_diff):  # pragma: no cover - compiled
    """The k best associations of one cluster, score (a, m) (-inf: not admissible), best first.

    Returns (assign (n, a) int64: the measurement of each landmark, -1 missed; total (n,) float64), n <= k
    solutions, stopping at the first more than ``max_diff`` below the best. Murty's partitioning: the solved node's
    solution (s_0 .. s_{a-1}) splits its space into a children, child i forbidding (i, s_i) and forcing
    (r, s_r) for r < i; the next best is the best unexpanded child."""
    a, m = score.shape
    w = m + a
    base = np.full((a, w), BIG)
    for i in range(a):
        for j in range(m):
            if score[i, j] > -np.inf:
                base[i, j] = -score[i, j]
        base[i, m + i] = 0.0  # left missed
    out_a = np.full((k, a), -1, np.int64)
    out_t = np.full(k, -np.inf)
    cap = 1 + k * a
    mats = np.empty((cap, a, w))
    sols = np.empty((cap, a), np.int64)
    costs = np.full(cap, np.inf)
    open_ = np.zeros(cap, np.bool_)
    cols, tot = _solve(base)
    mats[0] = base
    sols[0] = cols
    costs[0] = tot
    used = 1
    cur = 0
    n = 0
    best = tot
    while True:
        # record the current node's solution
        for i in range(a):
            c = sols[cur, i]
            out_a[n, i] = c if c < m else -1
        out_t[n] = -costs[cur]
        n += 1
        if n == k:
            break
        # partition it
        work = mats[cur].copy()
        for i in range(a):
            si = sols[cur, i]
            child = work.copy()
            child[i, si] = BIG
            ccols, ctot = _solve(child)
            if ctot < BIG / 2 and used < cap:
                mats[used] = child
                sols[used] = ccols
                costs[used] = ctot
                open_[used] = True
                used += 1
            # force (i, si) in the later children: row i takes only column si, no other row takes si
            for j in range(w):
                if j != si:
                    work[i, j] = BIG
            for r in range(a):
                if r != i:
                    work[r, si] = BIG
        # the next best: the cheapest open node (ties: the earliest made)
        nxt = -1
        for q in range(used):
            if open_[q] and (nxt < 0 or costs[q] < costs[nxt]):
                nxt = q
        if nxt < 0 or costs[nxt] - best > max_diff:
            break
        open_[nxt] = False
        cur = nxt
    return out_a[:n], out_t[:n]


@numba.njit(cache=True, nogil=True)
def _clusters(adm):  # pragma: no cover - compiled
    """Connected components of the admissible pairs adm (A, M): (row label (A,), column label (M,), count); a row
    or column with no admissible pair has label -1."""
    a, m = adm.shape
    parent = np.arange(a + m)
    for i in range(a):
        for j in range(m):
            if adm[i, j]:
                x = i
                while parent[x] != x:
                    x = parent[x]
                y = a + j
                while parent[y] != y:
                    y = parent[y]
                if x != y:
                    if x < y:
                        parent[y] = x
                    else:
                        parent[x] = y
    lab = np.full(a + m, -1, np.int64)
    any_ = np.zeros(a + m, np.bool_)
    for i in range(a):
        for j in range(m):
            if adm[i, j]:
                any_[i] = True
                any_[a + j] = True
    count = 0
    root_lab = np.full(a + m, -1, np.int64)
    for v in range(a + m):
        if not any_[v]:
            continue
        x = v
        while parent[x] != x:
            x = parent[x]
        if root_lab[x] < 0:
            root_lab[x] = count
            count += 1
        lab[v] = root_lab[x]
    return lab[:a], lab[a:], count


@numba.njit(cache=True, nogil=True)
def _members(lab, nc):  # pragma: no cover - compiled
    """The members of each of nc clusters, in order: (nc, len(lab)) indices padded with -1, and their counts (nc,);
    lab (n,) each index's cluster (-1: none)."""
    n = lab.shape[0]
    out = np.full((nc, n), -1, np.int64)
    cnt = np.zeros(nc, np.int64)
    for i in range(n):
        c = lab[i]
        if c >= 0:
            out[c, cnt[c]] = i
            cnt[c] += 1
    return out, cnt


@numba.njit(cache=True, nogil=True)
def kbest_one(score, k, max_diff):  # pragma: no cover - compiled
    """The k best associations of one problem score (A, M) (module docstring): (assign (n, A) int64, total (n,))."""
    a, m = score.shape
    adm = np.zeros((a, m), np.bool_)
    for i in range(a):
        for j in range(m):
            adm[i, j] = score[i, j] > -np.inf
    rlab, clab, nc = _clusters(adm)
    if nc == 0:
        return np.full((1, a), -1, np.int64), np.zeros(1)
    # each cluster's k best, as (score, its rows' assignments) in flat arrays
    ncl = np.zeros(nc, np.int64)
    sc = np.full((nc, k), -np.inf)
    rows_of, nrows = _members(rlab, nc)
    cols_of, ncols = _members(clab, nc)
    asg = np.full((nc, k, a), -1, np.int64)  # per cluster, per solution: the global column of each global row
    for c in range(nc):
        ra, ma = nrows[c], ncols[c]
        if ra == 1 and ma == 1:  # taken or left: no solve
            i, j = rows_of[c, 0], cols_of[c, 0]
            s = score[i, j]
            first, second = (s, 0.0) if s >= 0.0 else (0.0, s)
            sc[c, 0] = first
            asg[c, 0, i] = j if s >= 0.0 else -1
            ncl[c] = 1
            if k > 1 and first - second <= max_diff:
                sc[c, 1] = second
                asg[c, 1, i] = -1 if s >= 0.0 else j
                ncl[c] = 2
            continue
        sub = np.empty((ra, ma))
        for x in range(ra):
            for y in range(ma):
                sub[x, y] = score[rows_of[c, x], cols_of[c, y]]
        sa, st = murty(sub, k, max_diff)
        ncl[c] = st.size
        for q in range(st.size):
            sc[c, q] = st[q]
            for x in range(ra):
                y = sa[q, x]
                asg[c, q, rows_of[c, x]] = cols_of[c, y] if y >= 0 else -1
    # merge: best-first over index vectors (one index per cluster)
    best = 0.0
    for c in range(nc):
        best += sc[c, 0]
    cap = 1 + k * nc
    vec = np.zeros((cap, nc), np.int64)
    vsc = np.full(cap, -np.inf)
    vpos = np.zeros(cap, np.int64)
    vopen = np.zeros(cap, np.bool_)
    vsc[0] = best
    vopen[0] = True
    used = 1
    out_a = np.full((k, a), -1, np.int64)
    out_t = np.full(k, -np.inf)
    n = 0
    while n < k:
        q = -1
        for t in range(used):
            if vopen[t] and (q < 0 or vsc[t] > vsc[q]):
                q = t
        if q < 0 or best - vsc[q] > max_diff:
            break
        vopen[q] = False
        for c in range(nc):
            src = asg[c, vec[q, c]]
            for r in range(nrows[c]):
                i = rows_of[c, r]
                out_a[n, i] = src[i]
        out_t[n] = vsc[q]
        n += 1
        for c in range(vpos[q], nc):
            nxt = vec[q, c] + 1
            if nxt < ncl[c] and used < cap:
                vec[used] = vec[q]
                vec[used, c] = nxt
                vsc[used] = vsc[q] - sc[c, nxt - 1] + sc[c, nxt]
                vpos[used] = c
                vopen[used] = True
                used += 1
    return out_a[:n], out_t[:n]


@numba.njit(cache=True, nogil=True)
def kbest_batch(score, nact, k, max_diff):  # pragma: no cover - compiled
    """The k best associations of N problems at once: score (N, A, M) (-inf: not admissible), nact (N,) the rows in
    use of each (the rest padding). Returns assign (N, k, A) int64 (the measurement of each landmark, -1 missed or
    padding), total (N, k) float64 (-inf past a problem's last solution) and count (N,) int64 (1 <= count <= k)."""
    n_p, a, m = score.shape
    assign = np.full((n_p, k, a), -1, np.int64)
    total = np.full((n_p, k), -np.inf)
    count = np.zeros(n_p, np.int64)
    for p in range(n_p):
        na = nact[p]
        sa, st = kbest_one(score[p, :na], k, max_diff)
        count[p] = st.size
        for q in range(st.size):
            total[p, q] = st[q]
            for i in range(na):
                assign[p, q, i] = sa[q, i]
    return assign, total, count
