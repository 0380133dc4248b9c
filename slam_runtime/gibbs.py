"""Compiled kernels of the labelled map filters (delta-GLMB, LMB): the Gibbs sampler of the joint
prediction/update (Vo, Vo & Hoang 2017; delta-GLMB-SLAM paper eqs. 11-17) and the detections' log eta of point
landmarks (:func:`detection_costs`); the reduction of the hypotheses it draws is :mod:`slam_runtime.hypotheses`,
the helpers both share (the optimal assignment among them) :mod:`slam_runtime.kernels`.

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
highest-weight child, :func:`slam_runtime.kernels.hungarian`) and then
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
  existence, r_B (1 - P_D) / (1 - r_B P_D), by LMB (``sum_idle_births``):
  sampled, such births would take a share of the samples that changes from
  particle to particle, and with it each particle's missing mass, its weight;
* delta-GLMB updates the other independent births and released tracks exactly
  as Bernoulli components outside the hypotheses (``factor_independent``):
  existence the share of its options in which it exists, density the moment
  match of its missed and detected versions; sampled, a new landmark's first
  detections (a child of small weight r_B P_D g / kappa) are drawn in only
  some steps, and a tentative track's existence stays below the exact one
  (docs/results.md).

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

from slam_runtime.kernels import BIG, argsort_stable, grow, hungarian, log_norm, logaddexp, prune_cap, wrap_scalar

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
                cost = np.full((nr, nc + nr), BIG)
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
                    ch_lw[ca] = logaddexp(ch_lw[ca], ch_lw[cb])
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
        kept, nk, cap_hit = prune_cap(ch_lw[:nch], alive, ll, prune, cap)
        capped = capped or cap_hit
        lnorm = log_norm(ch_lw, kept, nk)
        # the new slots: (source slot, assignment), shared by the children that hold them
        table = np.full(S * (M + 1), -1, np.int64)
        ns = 0
        for q in range(nk):
            c = kept[q]
            h = ch_parent[c]
            hyp_logw = grow(hyp_logw, n_hyp + 1)
            mem_count = grow(mem_count, n_hyp + 1)
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
                    slot_src = grow(slot_src, n_slot + ns + 1)
                    slot_a = grow(slot_a, n_slot + ns + 1)
                    slot_src[n_slot + ns] = s
                    slot_a[n_slot + ns] = a
                    ns += 1
                mem_slot = grow(mem_slot, n_mem + 1)
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
    arithmetic as the vectorised form in :meth:`slam_runtime.labelled.LabelledFilter._det_costs` (one pass instead of
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
                    y = wrap_scalar(y)
                m2 = i00 * x * x + 2.0 * i01 * x * y + i11 * y * y
                if m2 <= gate:
                    gated[p, a, j] = True
                    if pd_pos[p, a]:
                        l_det[p, a, j] = l_base[p, a] + (-0.5 * m2 - 0.5 * (dzlog + logdet)) - log_kappa[j]
    return l_det, gated


