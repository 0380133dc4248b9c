"""Compiled kernels of the labelled map filters (delta-GLMB, LMB): optimal assignment, the Gibbs
sampler of the joint prediction/update (Vo, Vo & Hoang 2017; delta-GLMB-SLAM paper eqs. 11-17), the
reduction of its hypotheses, and the detections' log eta of point landmarks (:func:`detection_costs`).

The joint prediction/update of one prior hypothesis ``(I, xi)`` with weight w
draws association maps gamma over the hypothesis's candidate tracks (its
tracks in the field of view and this step's birth tracks): for candidate i,
gamma_i = -1 (dead / not born), 0 (exists, missed) or j + 1 (exists, detected
by measurement j), no measurement used twice. The weight of the child
hypothesis (eqs. 12-13, 15) is

    w * prod_i eta_i(gamma_i),
    eta_i(-1) = 1 - r_i P_S,i,  eta_i(0) = r_i P_S,i (1 - P_D,i),  eta_i(j + 1) = r_i P_S,i P_D,i g(z_j | i) / kappa(z_j)

with r_i = 1 for a track of the hypothesis and r_B for a birth (P_S = 1 for a
birth); tracks outside the field of view (P_D = 0, P_S = 1) are carried over
unchanged with a factor 1. The kernels work on log eta: ``l_death``,
``l_miss`` (P, A) and ``l_det`` (P, A, M) for the A active tracks of each of
the P particles (-inf where an option is impossible or a measurement lies
outside the gate).

For every prior hypothesis, the chain starts at the optimal assignment (the
highest-weight child, :func:`hungarian`: a shortest-augmenting-path solver
checked against ``scipy.optimize.linear_sum_assignment`` in the tests) and then
makes one Gibbs sweep per further sample (Vo, Vo & Hoang 2017, Algorithm 1:
each gamma_i drawn from its conditional given the others, with the
measurements the others hold locked out). Samples are allocated to the prior
hypotheses in proportion to sqrt(w) (their Algorithm 2); duplicate samples of
one prior are counted once, and children of different priors that are the same
labelled hypothesis (the same set of track versions) are merged by adding their
weights. The sum of the children's weights is the normalisation constant of
eq. 25, the particle's measurement likelihood.

Common random numbers: the uniform behind each draw is a hash of (the step's
seed, the prior hypothesis's position, the sample, the candidate's label), not the
next number of a stream, so particles whose maps and costs agree draw the same
children and their weights differ only by what differs between them, and one
particle having a candidate more (a track the other's map lacks) does not
shift every later draw of its chains. Labels are shared by the particles
(a birth's label is its measurement's), so the keys line up across them.
The seed is per particle: one filter gives all its particles the same; islands
(independent filters) give each island its own, so their draws are independent
(``draws: particle`` gives every particle its own).

Held candidates: a candidate that is a candidate of every prior hypothesis
with the same options (a birth, a released track) and independent of every
other candidate (no measurement it gates is gated by another) multiplies every
child's weight by the same sum over its own options. The sampler leaves it out
of the children and adds the log of that sum to the normalisation constant,
exactly; the caller updates it on its own (``held``, ``l_held``):

* a birth that gates no measurement and is likelier not born (r_B <
  1 / (2 - P_D): any birth probability of the paper's kind) is dropped by
  delta-GLMB (its born-but-missed children are not kept) and given its exact
  existence, r_B (1 - P_D) / (1 - r_B P_D), by LMB (``sum_idle_births``).
  Sampled, these births (one per measurement of the previous scan: 15-17 at
  15 false alarms per scan) took a share of the samples that changed from
  particle to particle, and with it each particle's missing mass, its weight;
* delta-GLMB updates the other independent births and released tracks exactly
  as Bernoulli components outside the hypotheses (``factor_independent``):
  existence the share of its options in which it exists, density the moment
  match of its missed and detected versions. Sampled, a new landmark's first
  detections (a child of weight r_B P_D g / kappa, 0.01 x 3.5 at 15 false
  alarms per scan) were drawn in only some steps with 60 samples, and the
  tentative track's existence stayed 5-10 times below the exact one (measured
  against 2,000 samples on glmb-paper), so landmarks seen 14-18 times were
  never confirmed.

Why compiled: the sweep is sequential by nature (each gamma_i is drawn given
the current values of all the others, so no two draws of one chain can be
vectorised), and the chains are short (tens of candidates) and many (one per
prior hypothesis per particle, hundreds per step); in numpy that would be a
Python loop per (hypothesis, candidate), the pattern the project rules out.
numba runs every particle's chains in one call.
"""

from __future__ import annotations

import numba
import numpy as np

_BIG = 1e15  # a forbidden pair in the assignment (every row has a finite option: its own dummy column)


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
def _maha2(c, ci, x, a, b, work):  # pragma: no cover - compiled
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
def _grow_i(a, need):  # pragma: no cover - compiled
    if need <= a.shape[0]:
        return a
    b = np.empty(max(need, 2 * a.shape[0]), a.dtype)
    b[: a.shape[0]] = a
    return b


@numba.njit(cache=True, nogil=True)
def _grow_f(a, need):  # pragma: no cover - compiled
    if need <= a.shape[0]:
        return a
    b = np.empty(max(need, 2 * a.shape[0]), a.dtype)
    b[: a.shape[0]] = a
    return b


@numba.njit(cache=True, nogil=True)
def _splitmix(x):  # pragma: no cover - compiled
    x = (x + np.uint64(0x9E3779B97F4A7C15))
    x = (x ^ (x >> np.uint64(30))) * np.uint64(0xBF58476D1CE4E5B9)
    x = (x ^ (x >> np.uint64(27))) * np.uint64(0x94D049BB133111EB)
    return x ^ (x >> np.uint64(31))


@numba.njit(cache=True, nogil=True)
def _key(x, part):  # pragma: no cover - compiled
    """One link of the key chain: the uniform of a draw is a function of (seed, prior hypothesis rank, sample,
    candidate label) only, hashed link by link so that a chain's prefix (seed, rank) and a sweep's (sample) are
    hashed once, not once per draw."""
    return _splitmix(x ^ np.uint64(part))


@numba.njit(cache=True, nogil=True)
def _uniform(x):  # pragma: no cover - compiled
    """The top 53 bits of a key as a uniform in [0, 1)."""
    return float(x >> np.uint64(11)) * (1.0 / 9007199254740992.0)


@numba.njit(cache=True, nogil=True)
def _mix(h, x):  # pragma: no cover - compiled
    """One step of a polynomial hash over int64 (wrapping)."""
    return h * np.int64(1000003) + np.int64(x) + np.int64(7)


@numba.njit(cache=True, nogil=True)
def _sample_option(e_d, e_m, e_row, gl, ng, i, taken, k, u01):  # pragma: no cover - compiled
    """Draw gamma_k (candidate i, row k of the chain) from its conditional: death, miss, or a gated measurement no
    other candidate holds.

    e_d, e_m: the weights eta of death and miss, e_row[i, :ng] those of the measurements gl[i, :ng] it gates, scaled
    by the row's largest (precomputed once per step); the arrays are passed whole and indexed here (a row view per
    draw costs more than the draw)."""
    tot = e_d + e_m
    for q in range(ng):
        t = taken[gl[i, q]]
        if t == -1 or t == k:
            tot += e_row[i, q]
    x = u01 * tot
    if x < e_d:
        return -1
    x -= e_d
    if x < e_m:
        return 0
    x -= e_m
    last = -1
    for q in range(ng):
        t = taken[gl[i, q]]
        if t == -1 or t == k:
            last = q
            if x < e_row[i, q]:
                return gl[i, q] + 1
            x -= e_row[i, q]
    # round-off at the end of the cumulative sum: the last option that was allowed
    if last >= 0:
        return gl[i, last] + 1
    return 0 if e_m > 0.0 else -1


@numba.njit(cache=True, nogil=True)
def joint_update(seeds, logw, member, act, nact, l_death, l_miss, l_det, total, prune, cap, held, l_held, cand_label):  # pragma: no cover - compiled
    """Gibbs-sampled joint prediction/update of the labelled maps of P particles.

    seeds (P,) int64: the step's seed of each particle (drawn from the run's Generator), the same for every particle
    of one filter (an island): the uniform of each draw is a function of (seed, position of the prior hypothesis
    among the live ones, sample, candidate label) (common random numbers; the hypotheses come sorted by weight from
    the reduction);
    logw (P, H): normalised log weights of the prior hypotheses (-inf: empty slot);
    member (P, H, S) bool: slot s is a candidate of hypothesis h (its tracks, and the births);
    act (P, A) int64: slot of each active candidate (P_D > 0 or birth), nact (P,) how many;
    l_death, l_miss (P, A), l_det (P, A, M): log eta of the options (module docstring);
    total: samples per particle, shared among the prior hypotheses by sqrt(w);
    held (P, A) bool: candidates left out of the children, each adding l_held (P, A), the log of the sum of its
    options' weights, to the normalisation constant (module docstring: summed births, independent candidates);
    the caller chooses them: each must be independent of every other candidate (no measurement it gates is
    gated by another) and a candidate of every live prior hypothesis with the same options (the factor is
    added once per particle; births and released tracks are);
    cand_label (P, A) int64: the label of each active candidate;
    prune: children of normalised weight below this are dropped (the heaviest is always kept);
    cap: at most this many children per particle (the heaviest).

    Returns (loglik (P,), capped, hyp_count (P,), hyp_logw, mem_count, mem_slot, slot_count (P,),
    slot_src, slot_a): per particle its kept children (normalised log weights; each child's new
    slots as indices into the particle's new slot list, ``mem_count`` per child), and the new
    slots as (source slot, assignment: 0 carried over / missed, j + 1 updated with measurement j);
    loglik is log sum over all distinct children of their unnormalised weight (eq. 25).
    """
    P, H = logw.shape
    S = member.shape[2]
    A = act.shape[1]
    M = l_det.shape[2]
    loglik = np.zeros(P)
    capped = False
    hyp_count = np.zeros(P, np.int64)
    slot_count = np.zeros(P, np.int64)
    hyp_logw = np.empty(64)
    mem_count = np.empty(64, np.int64)
    mem_slot = np.empty(256, np.int64)
    slot_src = np.empty(256, np.int64)
    slot_a = np.empty(256, np.int64)
    n_hyp = 0
    n_mem = 0
    n_slot = 0
    gl = np.empty((A, M), np.int64)
    ng = np.zeros(A, np.int64)
    e_row = np.empty((A, M))
    e_d = np.empty(A)
    e_m = np.empty(A)
    taken = np.empty(M, np.int64)
    for p in range(P):
        na = nact[p]
        pos = np.full(S, -1, np.int64)
        # the options of a held candidate (independent of every other candidate) add a factor common to every child
        # to the normalisation constant
        l_summed = 0.0
        for i in range(na):
            pos[act[p, i]] = i
            c = 0
            mx = max(l_death[p, i], l_miss[p, i])
            for j in range(M):
                if l_det[p, i, j] > -np.inf:
                    gl[i, c] = j
                    c += 1
                    if l_det[p, i, j] > mx:
                        mx = l_det[p, i, j]
            ng[i] = c
            if held[p, i]:
                l_summed += l_held[p, i]
            # the options' weights in linear scale, relative to the row's largest (no exp in the sweeps)
            e_d[i] = np.exp(l_death[p, i] - mx) if l_death[p, i] > -np.inf else 0.0
            e_m[i] = np.exp(l_miss[p, i] - mx) if l_miss[p, i] > -np.inf else 0.0
            for q in range(c):
                e_row[i, q] = np.exp(l_det[p, i, gl[i, q]] - mx)
        # the live prior hypotheses and their share of the samples (sqrt of the weight)
        live = np.empty(H, np.int64)
        nl = 0
        for h in range(H):
            if logw[p, h] > -np.inf:
                live[nl] = h
                nl += 1
        if nl == 0:
            loglik[p] = -np.inf
            continue
        top = live[0]
        ssum = 0.0
        for q in range(nl):
            h = live[q]
            ssum += np.exp(0.5 * logw[p, h])
            if logw[p, h] > logw[p, top]:
                top = h
        alloc = np.zeros(H, np.int64)
        for q in range(nl):
            h = live[q]
            alloc[h] = int(np.floor(total * np.exp(0.5 * logw[p, h]) / ssum + 0.5))
        if alloc[top] < 1:
            alloc[top] = 1
        nmax = 0
        for q in range(nl):
            nmax += alloc[live[q]]
        ch_parent = np.empty(nmax, np.int64)
        ch_assign = np.full((nmax, na), -1, np.int64)
        ch_lw = np.empty(nmax)
        ch_hash = np.empty(nmax, np.int64)
        nch = 0
        # a hash of each prior's tracks that are carried over (not active)
        phash = np.zeros(H, np.int64)
        for q in range(nl):
            h = live[q]
            hh = np.int64(0)
            for s in range(S):
                if member[p, h, s] and pos[s] < 0:
                    hh = _mix(hh, s)
            phash[h] = hh
        rows = np.empty(na, np.int64)
        free = np.empty(na, np.int64)
        gamma = np.empty(na, np.int64)
        sub_rows = np.empty(na, np.int64)
        col_of = np.full(M, -1, np.int64)
        col_meas = np.empty(M, np.int64)
        for hq in range(nl):
            h = live[hq]
            if alloc[h] == 0:
                continue
            n = 0
            # free: the rows whose draw is not forced (a candidate that gates no measurement and has one of death
            # and miss impossible, a track of the hypothesis when P_S = 1, keeps its one option: no draw)
            nf = 0
            for i in range(na):
                if member[p, h, act[p, i]] and not held[p, i]:
                    rows[n] = i
                    if ng[i] > 0 or (e_d[i] > 0.0 and e_m[i] > 0.0):
                        free[nf] = n
                        nf += 1
                    n += 1
            # the chain starts at the optimal assignment; a candidate that gates no measurement takes its best
            # non-detection option, the others are assigned over the measurements they gate (+ one dummy each)
            nr = 0
            for k in range(n):
                i = rows[k]
                if ng[i] == 0:
                    gamma[k] = 0 if l_miss[p, i] >= l_death[p, i] else -1
                else:
                    sub_rows[nr] = k
                    nr += 1
            if nr > 0:
                nc = 0
                for q in range(nr):
                    i = rows[sub_rows[q]]
                    for g in range(ng[i]):
                        j = gl[i, g]
                        if col_of[j] < 0:
                            col_of[j] = nc
                            col_meas[nc] = j
                            nc += 1
                cost = np.full((nr, nc + nr), _BIG)
                for q in range(nr):
                    i = rows[sub_rows[q]]
                    for g in range(ng[i]):
                        j = gl[i, g]
                        cost[q, col_of[j]] = -l_det[p, i, j]
                    cost[q, nc + q] = -max(l_death[p, i], l_miss[p, i])
                asg = hungarian(cost)
                for q in range(nr):
                    k = sub_rows[q]
                    i = rows[k]
                    if asg[q] < nc:
                        gamma[k] = col_meas[asg[q]] + 1
                    elif l_miss[p, i] >= l_death[p, i]:
                        gamma[k] = 0
                    else:
                        gamma[k] = -1
                for q in range(nc):
                    col_of[col_meas[q]] = -1
            taken[:] = -1
            for k in range(n):
                if gamma[k] > 0:
                    taken[gamma[k] - 1] = k
            first = nch
            key_h = _key(_key(np.uint64(seeds[p]), 0x5851F42D4C957F2D), hq)
            for smp in range(alloc[h]):
                if smp > 0:
                    key_s = _key(key_h, smp)
                    for f in range(nf):
                        k = free[f]
                        i = rows[k]
                        # common random numbers keyed by label (module docstring)
                        g = _sample_option(e_d[i], e_m[i], e_row, gl, ng[i], i, taken, k, _uniform(_key(key_s, cand_label[p, i])))
                        if gamma[k] > 0:
                            taken[gamma[k] - 1] = -1
                        gamma[k] = g
                        if g > 0:
                            taken[g - 1] = k
                # the forced rows are the same in every child of this prior: hashed and compared over the free ones
                hh = np.int64(0)
                for f in range(nf):
                    hh = _mix(hh, gamma[free[f]])
                dup = False
                for c in range(first, nch):
                    if ch_hash[c] == hh:
                        same = True
                        for f in range(nf):
                            k = free[f]
                            if ch_assign[c, rows[k]] != gamma[k]:
                                same = False
                                break
                        if same:
                            dup = True
                            break
                if dup:
                    continue
                lw = logw[p, h]
                for k in range(n):
                    i = rows[k]
                    g = gamma[k]
                    if g < 0:
                        lw += l_death[p, i]
                    elif g == 0:
                        lw += l_miss[p, i]
                    else:
                        lw += l_det[p, i, g - 1]
                ch_parent[nch] = h
                for k in range(n):
                    ch_assign[nch, rows[k]] = gamma[k]
                ch_lw[nch] = lw
                ch_hash[nch] = hh
                nch += 1
        # children of different priors that are the same labelled hypothesis: merged (weights added)
        key = np.empty(nch, np.int64)
        for c in range(nch):
            hh = phash[ch_parent[c]]
            for i in range(na):
                hh = _mix(hh, max(ch_assign[c, i], -1))
            key[c] = hh
        order = argsort_stable(key)
        alive = np.ones(nch, np.bool_)
        for a in range(nch):
            ca = order[a]
            if not alive[ca]:
                continue
            for b in range(a + 1, nch):
                cb = order[b]
                if key[cb] != key[ca]:
                    break
                if not alive[cb]:
                    continue
                same = True
                for i in range(na):
                    if ch_assign[ca, i] != ch_assign[cb, i]:
                        same = False
                        break
                if same:
                    ha = ch_parent[ca]
                    hb = ch_parent[cb]
                    for s in range(S):
                        if pos[s] < 0 and member[p, ha, s] != member[p, hb, s]:
                            same = False
                            break
                if same:
                    hi = max(ch_lw[ca], ch_lw[cb])
                    ch_lw[ca] = hi + np.log(np.exp(ch_lw[ca] - hi) + np.exp(ch_lw[cb] - hi))
                    alive[cb] = False
        # the normalisation constant (eq. 25), then normalise, prune and cap
        mx = -np.inf
        for c in range(nch):
            if alive[c] and ch_lw[c] > mx:
                mx = ch_lw[c]
        tot = 0.0
        for c in range(nch):
            if alive[c]:
                tot += np.exp(ch_lw[c] - mx)
        ll = mx + np.log(tot)
        loglik[p] = ll + l_summed
        cand = np.empty(nch, np.int64)
        ncand = 0
        for c in range(nch):
            if alive[c]:
                cand[ncand] = c
                ncand += 1
        lws = np.empty(ncand)
        for q in range(ncand):
            lws[q] = -ch_lw[cand[q]]
        srt = argsort_stable(lws)
        kept = np.empty(ncand, np.int64)
        nk = 0
        for q in range(ncand):
            c = cand[srt[q]]
            if nk > 0 and np.exp(ch_lw[c] - ll) < prune:
                break
            if nk >= cap:
                capped = True
                break
            kept[nk] = c
            nk += 1
        kt = 0.0
        for q in range(nk):
            kt += np.exp(ch_lw[kept[q]] - mx)
        lnorm = mx + np.log(kt)
        # the new slots: (source slot, assignment), shared by the children that hold them
        table = np.full(S * (M + 1), -1, np.int64)
        ns = 0
        for q in range(nk):
            c = kept[q]
            h = ch_parent[c]
            hyp_logw = _grow_f(hyp_logw, n_hyp + 1)
            mem_count = _grow_i(mem_count, n_hyp + 1)
            hyp_logw[n_hyp] = ch_lw[c] - lnorm
            cnt = 0
            for s in range(S):
                a = -1
                if pos[s] < 0:
                    if member[p, h, s]:
                        a = 0
                else:
                    a = ch_assign[c, pos[s]]
                if a < 0:
                    continue
                t = s * (M + 1) + a
                if table[t] < 0:
                    table[t] = ns
                    slot_src = _grow_i(slot_src, n_slot + ns + 1)
                    slot_a = _grow_i(slot_a, n_slot + ns + 1)
                    slot_src[n_slot + ns] = s
                    slot_a[n_slot + ns] = a
                    ns += 1
                mem_slot = _grow_i(mem_slot, n_mem + 1)
                mem_slot[n_mem] = table[t]
                n_mem += 1
                cnt += 1
            mem_count[n_hyp] = cnt
            n_hyp += 1
        hyp_count[p] = nk
        slot_count[p] = ns
        n_slot += ns
    return (
        loglik,
        capped,
        hyp_count,
        hyp_logw[:n_hyp].copy(),
        mem_count[:n_hyp].copy(),
        mem_slot[:n_mem].copy(),
        slot_count,
        slot_src[:n_slot].copy(),
        slot_a[:n_slot].copy(),
    )



@numba.njit(cache=True, nogil=True)
def _inv2(s00, s01, s10, s11):  # pragma: no cover - compiled
    """The entries (0, 0), (0, 1), (1, 1) of the inverse of a symmetric 2x2 matrix and its determinant, with the
    floored determinant of :func:`slam_runtime.gm.inv` (the same operations, so the same bits)."""
    dt = s00 * s11 - s01 * s10
    dd = dt if np.abs(dt) > 1e-300 else 1e-300
    return s11 / dd, -s01 / dd, s00 / dd, dt


@numba.njit(cache=True, nogil=True)
def detection_costs(zhat, hph, z, rz, own_cov, r, logdet_r, wrap_bearing, gate, dzlog, l_base, log_kappa, in_a, pd_pos):  # pragma: no cover - compiled
    """log eta of the detections of 2-d measurements, fused over (particle, candidate, measurement): the same
    arithmetic as the vectorised form in :meth:`slam_runtime.glmb.LabelledFilter._det_costs` (one pass instead of
    some twenty (P, A, M) temporaries).

    zhat (P, A, 2), hph (P, A, 2, 2): the candidates' predicted measurements and H P H^T; z (M, 2); the innovation
    covariance is hph + rz[j] when own_cov (each measurement's own covariance, rz (M, 2, 2)), else hph + r, whose
    log determinants logdet_r (P, A) the caller takes (numpy's vectorised log, so that the result is the same to the
    last bit as the vectorised form's); the second component is an angle when wrap_bearing. gate: squared Mahalanobis gate; dzlog = dz log(2 pi);
    l_base (P, A) log(r P_S P_D); log_kappa (M,); in_a (P, A) the active candidates; pd_pos (P, A) P_D > 0.

    Returns l_det (P, A, M) (-inf outside the gate or where P_D = 0) and gated (P, A, M) (in the gate, active)."""
    P, A = l_base.shape
    M = z.shape[0]
    l_det = np.full((P, A, M), -np.inf)
    gated = np.zeros((P, A, M), np.bool_)
    for p in range(P):
        for a in range(A):
            if not in_a[p, a]:
                continue
            h00, h01, h10, h11 = hph[p, a, 0, 0], hph[p, a, 0, 1], hph[p, a, 1, 0], hph[p, a, 1, 1]
            if not own_cov:
                i00, i01, i11, _ = _inv2(h00 + r[0, 0], h01 + r[0, 1], h10 + r[1, 0], h11 + r[1, 1])
                logdet = logdet_r[p, a]
            for j in range(M):
                if own_cov:
                    i00, i01, i11, dt = _inv2(h00 + rz[j, 0, 0], h01 + rz[j, 0, 1], h10 + rz[j, 1, 0], h11 + rz[j, 1, 1])
                    logdet = np.log(max(dt, 1e-300))
                x = z[j, 0] - zhat[p, a, 0]
                y = z[j, 1] - zhat[p, a, 1]
                if wrap_bearing:
                    if y > np.pi:
                        y = y - 2 * np.pi
                    if y <= -np.pi:
                        y = y + 2 * np.pi
                m2 = i00 * x * x + 2.0 * i01 * x * y + i11 * y * y
                if m2 <= gate:
                    gated[p, a, j] = True
                    if pd_pos[p, a]:
                        l_det[p, a, j] = l_base[p, a] + (-0.5 * m2 - 0.5 * (dzlog + logdet)) - log_kappa[j]
    return l_det, gated


@numba.njit(cache=True, nogil=True)
def _moments(w, mu, cov, key, n):  # pragma: no cover - compiled
    """Moment match of the weighted Gaussians w (N,), mu (N, d), cov (N, d, d) into the n groups key (N,) names:
    each group's summed weight (n,), mean (n, d) and covariance (n, d, d) (zero where its weight is)."""
    d = mu.shape[1]
    gw = np.zeros(n)
    gmu = np.zeros((n, d))
    gcov = np.zeros((n, d, d))
    for k in range(w.shape[0]):
        g = key[k]
        gw[g] += w[k]
        for i in range(d):
            gmu[g, i] += w[k] * mu[k, i]
    for g in range(n):
        if gw[g] > 0.0:
            for i in range(d):
                gmu[g, i] /= gw[g]
    for k in range(w.shape[0]):
        g = key[k]
        for i in range(d):
            for j in range(d):
                gcov[g, i, j] += w[k] * (cov[k, i, j] + (mu[k, i] - gmu[g, i]) * (mu[k, j] - gmu[g, j]))
    for g in range(n):
        if gw[g] > 0.0:
            for i in range(d):
                for j in range(d):
                    gcov[g, i, j] /= gw[g]
    return gw, gmu, gcov


@numba.njit(cache=True, nogil=True)
def reduce_hypotheses(slot_count, label, mu, cov, release, hyp_count, hyp_logw, mem_count, mem_slot, merge, together, prune, cap):  # pragma: no cover - compiled
    """Merge close versions of each label and alternative labels of one landmark, release unseen labels,
    merge identical hypotheses; prune and cap.

    Input, flat over the P particles as :func:`joint_update` returns it: the new
    slots (slot_count (P,), label (N,), mu (N, d), cov (N, d, d), release (N,)
    bool) and the hypotheses (hyp_count (P,), normalised hyp_logw, mem_count,
    mem_slot: slot indices within the particle).

    * The weight of a version (a label's density under one association
      history, eq. 29) is the summed weight of the hypotheses that hold it.
    * A label all of whose versions are flagged ``release`` (tracks the sensor
      could not see this step) leaves the hypotheses: it becomes one Bernoulli
      component, existence = its summed weight, density = the moment match of
      its versions.
    * The other versions of a label are merged greedily, heaviest first, when
      within squared Mahalanobis distance ``merge`` of the head (Vo & Ma's rule,
      within one label); a merged version is the moment match of its members.
      ``merge`` <= 0 merges nothing.
    * Alternatives: groups of different labels, both released or both kept,
      within squared Mahalanobis distance ``merge`` of the heavier, that the
      hypotheses hold together (with any version of the heavier's labels)
      with at most ``together`` x the lighter's weight, become one group under
      the heavier's label: the moment match of its members, a released one of
      existence the weight of the hypotheses that hold any member; a kept one
      is held once by each hypothesis that held any. A hypothesis that held a
      merged alternative beside another version of the head's label, or beside
      an alternative merged under another version of it (both counted in the
      ``together`` share), keeps one: its own version of the label, else the
      group of the label's heavier version. Every hypothesis holds a label
      once. ``together`` <= 0 merges none.
    * Hypotheses that then hold the same versions are one hypothesis (weights
      added); those below ``prune`` are dropped (the heaviest is kept), at most
      ``cap`` are kept, the weights renormalised, and versions no hypothesis
      holds removed.

    Returns (capped, slot_count, label, mu, cov, hyp_count, hyp_logw, mem_count,
    mem_slot, free_count (P,), free_label, free_r, free_mu, free_cov).
    """
    P = slot_count.shape[0]
    d = mu.shape[1]
    capped = False
    n_in = label.shape[0]
    o_slot_count = np.zeros(P, np.int64)
    o_hyp_count = np.zeros(P, np.int64)
    o_free_count = np.zeros(P, np.int64)
    o_label = np.empty(n_in, np.int64)
    o_mu = np.empty((n_in, d))
    o_cov = np.empty((n_in, d, d))
    f_label = np.empty(n_in, np.int64)
    f_r = np.empty(n_in)
    f_mu = np.empty((n_in, d))
    f_cov = np.empty((n_in, d, d))
    o_logw = np.empty(hyp_logw.shape[0])
    o_mem_count = np.empty(hyp_logw.shape[0], np.int64)
    o_mem_slot = np.empty(mem_slot.shape[0], np.int64)
    n_out_slot = 0
    n_out_hyp = 0
    n_out_mem = 0
    n_free = 0
    s0 = 0
    h0 = 0
    m0 = 0
    work = np.empty((d, d + 3))
    for p in range(P):
        ns = slot_count[p]
        nh = hyp_count[p]
        wv = np.zeros(ns)
        hm0 = np.empty(nh + 1, np.int64)
        hm0[0] = m0
        for h in range(nh):
            hm0[h + 1] = hm0[h] + mem_count[h0 + h]
            w = np.exp(hyp_logw[h0 + h])
            for q in range(hm0[h], hm0[h + 1]):
                wv[mem_slot[q]] += w
        # group the versions of each label (heaviest first); a released label is one group
        lab = label[s0 : s0 + ns]
        order0 = argsort_stable(lab)
        grp = np.full(ns, -1, np.int64)
        gfree = np.zeros(ns, np.bool_)
        sub = np.empty(ns, np.int64)
        key = np.empty(ns)
        ng = 0
        a = 0
        while a < ns:
            b = a
            while b < ns and lab[order0[b]] == lab[order0[a]]:
                b += 1
            # the label's versions, heaviest first (a stable insertion sort: a label has a few versions)
            nb = b - a
            allrel = True
            for q in range(nb):
                t = order0[a + q]
                if not release[s0 + t]:
                    allrel = False
                r = q - 1
                while r >= 0 and wv[sub[r]] < wv[t]:
                    sub[r + 1] = sub[r]
                    r -= 1
                sub[r + 1] = t
            if allrel:
                for q in range(nb):
                    grp[sub[q]] = ng
                gfree[ng] = True
                ng += 1
            else:
                for q in range(nb):
                    first = sub[q]
                    if grp[first] >= 0:
                        continue
                    grp[first] = ng
                    if merge > 0.0:
                        for r in range(q + 1, nb):
                            o = sub[r]
                            if grp[o] < 0 and _maha2(cov, s0 + first, mu, s0 + o, s0 + first, work) <= merge:
                                grp[o] = ng
                    ng += 1
            a = b
        # moments of each group
        glab = np.empty(ng, np.int64)
        for k in range(ns):
            glab[grp[k]] = lab[k]
        gw, gmu, gcov = _moments(wv, mu[s0 : s0 + ns], cov[s0 : s0 + ns], grp, ng)
        # alternatives of one landmark: groups of different labels, both released or both kept, within squared
        # Mahalanobis distance merge of the heavier, that the hypotheses hold together with at most ``together``
        # of the lighter's weight, become one group under the heavier's label (its existence: the weight of the
        # hypotheses that hold any of them)
        head = np.arange(ng)
        merged = False
        if merge > 0.0 and together > 0.0 and ng > 1:
            gtr = np.zeros(ng)  # each group's covariance trace: a cheap bound before the Mahalanobis test
            for g in range(ng):
                for k in range(d):
                    gtr[g] += gcov[g, k, k]
            hg = np.zeros((nh, ng), np.bool_)
            for h in range(nh):
                for q in range(hm0[h], hm0[h + 1]):
                    hg[h, grp[mem_slot[q]]] = True
            for g in range(ng):
                key[g] = -gw[g]
            gord = argsort_stable(key[:ng])
            inl = np.zeros(ng, np.bool_)
            for y in range(1, ng):
                j = gord[y]
                for x in range(y):
                    i = gord[x]
                    if head[i] != i or gfree[i] != gfree[j] or glab[i] == glab[j]:
                        continue
                    dd2 = 0.0
                    for k in range(d):
                        dd2 += (gmu[j, k] - gmu[i, k]) ** 2
                    if dd2 > merge * gtr[i] or _maha2(gcov, i, gmu, j, i, work) > merge:
                        continue
                    # held together: j beside any version of a label already in i's group (also a version
                    # too far from i to be in it) or beside an alternative merged under another version of i's
                    # label; within the allowance such a hypothesis keeps one of them (the drop below), so that
                    # the tracks it loses are at most ``together`` of j's weight
                    inl[:] = False
                    for m in range(ng):
                        if head[m] == i:
                            for k in range(ng):
                                if glab[k] == glab[m]:
                                    inl[k] = True
                    for k in range(ng):
                        if glab[head[k]] == glab[i]:
                            inl[k] = True
                    both = 0.0
                    for h in range(nh):
                        if hg[h, j]:
                            for k in range(ng):
                                if k != j and hg[h, k] and inl[k]:
                                    both += np.exp(hyp_logw[h0 + h])
                                    break
                    if both <= together * gw[j]:
                        head[j] = i
                        merged = True
                        break
        if merged:
            # existence of the merged groups, their moments (a mixture of the members by their weights)
            un = np.zeros(ng)
            mark = np.full(ng, -1, np.int64)
            for h in range(nh):
                w = np.exp(hyp_logw[h0 + h])
                for q in range(hm0[h], hm0[h + 1]):
                    g = head[grp[mem_slot[q]]]
                    if mark[g] != h:
                        mark[g] = h
                        un[g] += w
            mw, mm, mc = _moments(gw, gmu, gcov, head, ng)
            for g in range(ng):
                if head[g] == g and mw[g] > gw[g]:
                    gmu[g] = mm[g]
                    gcov[g] = mc[g]
                    gw[g] = un[g]
        # released labels: independent Bernoulli components
        nf = 0
        for g in range(ng):
            if gfree[g] and head[g] == g and gw[g] > 0.0:
                f_label[n_free + nf] = glab[g]
                f_r[n_free + nf] = min(gw[g], 1.0)
                f_mu[n_free + nf] = gmu[g]
                f_cov[n_free + nf] = gcov[g]
                nf += 1
        # hypotheses as sorted lists of their (kept) groups; identical ones merged
        hl = np.empty(hm0[nh] - m0, np.int64)
        hn = np.zeros(nh, np.int64)
        hkey = np.empty(nh, np.int64)
        own = np.full(ng, -1, np.int64)  # own[g] == h: hypothesis h holds group g through a version of g's label
        for h in range(nh):
            a0 = hm0[h] - m0
            n = 0
            for q in range(hm0[h + 1] - hm0[h]):
                k = grp[mem_slot[hm0[h] + q]]
                g = head[k]
                if not gfree[g]:
                    hl[a0 + n] = g
                    n += 1
                    if glab[k] == glab[g]:
                        own[g] = h
            for q in range(1, n):  # sorted in place (insertion sort: a hypothesis holds a few groups)
                t = hl[a0 + q]
                r = q - 1
                while r >= 0 and hl[a0 + r] > t:
                    hl[a0 + r + 1] = hl[a0 + r]
                    r -= 1
                hl[a0 + r + 1] = t
            u = 0
            for q in range(n):  # a group once, also where the hypothesis held two of the alternatives it merged
                if u == 0 or hl[a0 + q] != hl[a0 + u - 1]:
                    hl[a0 + u] = hl[a0 + q]
                    u += 1
            n = u
            if merged:
                # a label once: an alternative merged into a group of label l, held beside a version of l outside
                # that group (within the ``together`` allowance), leaves the hypothesis, which keeps its own version
                # of l (of two alternatives' groups of one label, the first: the group of l's heavier head version;
                # a label's groups are numbered by their head versions' weights, heaviest first)
                u = 0
                for q in range(n):
                    g = hl[a0 + q]
                    drop = False
                    if own[g] != h:
                        for x in range(n):
                            o = hl[a0 + x]
                            if o != g and glab[o] == glab[g] and (own[o] == h or o < g):
                                drop = True
                                break
                    if not drop:
                        hl[a0 + u] = g
                        u += 1
                n = u
            hn[h] = n
            hh = np.int64(n)
            for q in range(n):
                hh = hh * np.int64(1000003) + hl[a0 + q] + np.int64(7)
            hkey[h] = hh
        lw = hyp_logw[h0 : h0 + nh].copy()
        alive = np.ones(nh, np.bool_)
        order = argsort_stable(hkey)
        for x in range(nh):
            ha = order[x]
            if not alive[ha]:
                continue
            for y in range(x + 1, nh):
                hb = order[y]
                if hkey[hb] != hkey[ha]:
                    break
                if not alive[hb] or hn[hb] != hn[ha]:
                    continue
                same = True
                for q in range(hn[ha]):
                    if hl[hm0[ha] - m0 + q] != hl[hm0[hb] - m0 + q]:
                        same = False
                        break
                if same:
                    hi = max(lw[ha], lw[hb])
                    lw[ha] = hi + np.log(np.exp(lw[ha] - hi) + np.exp(lw[hb] - hi))
                    alive[hb] = False
        # prune, cap, renormalise
        cand = np.empty(nh, np.int64)
        nc = 0
        for h in range(nh):
            if alive[h]:
                cand[nc] = h
                nc += 1
        neg = np.empty(nc)
        for q in range(nc):
            neg[q] = -lw[cand[q]]
        srt = argsort_stable(neg)
        kept = np.empty(nc, np.int64)
        nk = 0
        for q in range(nc):
            h = cand[srt[q]]
            if nk > 0 and np.exp(lw[h]) < prune:
                break
            if nk >= cap:
                capped = True
                break
            kept[nk] = h
            nk += 1
        mx = lw[kept[0]] if nk > 0 else 0.0
        tot = 0.0
        for q in range(nk):
            tot += np.exp(lw[kept[q]] - mx)
        lnorm = mx + np.log(tot) if nk > 0 else 0.0
        # the versions the kept hypotheses hold, renumbered in order of first use
        newid = np.full(ng, -1, np.int64)
        nn = 0
        for q in range(nk):
            h = kept[q]
            o_logw[n_out_hyp] = lw[h] - lnorm
            o_mem_count[n_out_hyp] = hn[h]
            for r in range(hn[h]):
                g = hl[hm0[h] - m0 + r]
                if newid[g] < 0:
                    newid[g] = nn
                    o_label[n_out_slot + nn] = glab[g]
                    o_mu[n_out_slot + nn] = gmu[g]
                    o_cov[n_out_slot + nn] = gcov[g]
                    nn += 1
                o_mem_slot[n_out_mem] = newid[g]
                n_out_mem += 1
            n_out_hyp += 1
        o_slot_count[p] = nn
        o_hyp_count[p] = nk
        o_free_count[p] = nf
        n_out_slot += nn
        n_free += nf
        s0 += ns
        h0 += nh
        m0 = hm0[nh]
    return (
        capped,
        o_slot_count,
        o_label[:n_out_slot].copy(),
        o_mu[:n_out_slot].copy(),
        o_cov[:n_out_slot].copy(),
        o_hyp_count,
        o_logw[:n_out_hyp].copy(),
        o_mem_count[:n_out_hyp].copy(),
        o_mem_slot[:n_out_mem].copy(),
        o_free_count,
        f_label[:n_free].copy(),
        f_r[:n_free].copy(),
        f_mu[:n_free].copy(),
        f_cov[:n_free].copy(),
    )
