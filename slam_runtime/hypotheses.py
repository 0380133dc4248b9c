"""The reduction of the labelled filters' hypotheses after the joint update (delta-GLMB; LMB before its
approximation): versions of one label merged, alternative labels of one landmark merged, unseen labels released
as independent Bernoulli components, identical hypotheses merged, pruned and capped (:func:`reduce_hypotheses`).

Compiled for the reason the sampler is (:mod:`slam_runtime.gibbs`): the grouping and the merges are sequential
over a particle's few versions and hypotheses, and numba runs every particle in one call.
"""

from __future__ import annotations

import numba
import numpy as np

from slam_runtime.kernels import argsort_stable, log_norm, logaddexp, maha2, prune_cap

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
def reduce_hypotheses(slot_count, label, mu, cov, release, hyp_count, hyp_logw, mem_count, mem_slot, merge, together, prune, cap, ident):  # pragma: no cover - compiled
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
    * Alternatives: groups of different labels of one identity (ident (N,), each slot's: the landmark its
      label's birth measurement read, -1 everywhere without identities), both released or both kept,
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
                            if grp[o] < 0 and maha2(cov, s0 + first, mu, s0 + o, s0 + first, work) <= merge:
                                grp[o] = ng
                    ng += 1
            a = b
        # moments of each group
        glab = np.empty(ng, np.int64)
        gid = np.empty(ng, np.int64)
        for k in range(ns):
            glab[grp[k]] = lab[k]
            gid[grp[k]] = ident[s0 + k]
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
                    if head[i] != i or gfree[i] != gfree[j] or glab[i] == glab[j] or gid[i] != gid[j]:
                        continue
                    dd2 = 0.0
                    for k in range(d):
                        dd2 += (gmu[j, k] - gmu[i, k]) ** 2
                    if dd2 > merge * gtr[i] or maha2(gcov, i, gmu, j, i, work) > merge:
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
                    lw[ha] = logaddexp(lw[ha], lw[hb])
                    alive[hb] = False
        # prune, cap, renormalise
        kept, nk, cap_hit = prune_cap(lw, alive, 0.0, prune, cap)
        capped = capped or cap_hit
        lnorm = log_norm(lw, kept, nk)
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
