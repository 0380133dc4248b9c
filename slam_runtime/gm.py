"""Gaussian-mixture maps of many particles at once: padded struct-of-arrays in d dimensions.

A batch of P maps with capacity J holds weights w (P, J) (0 = empty slot),
means mu (P, J, d) and covariances cov (P, J, d, d), in the world frame. The
linear algebra has explicit closed forms for d = 2 (point landmarks, the hot
path: no LAPACK call per 2x2 matrix) and falls back to numpy's batched
routines for other d (planes: d = 3).

Pruning and merging follow Vo & Ma (2006): drop components under a weight
threshold, then repeatedly take the heaviest remaining component and merge
every remaining one within a Mahalanobis distance of it (measured with the
head's covariance).
"""

from __future__ import annotations

from dataclasses import dataclass

from typing import TYPE_CHECKING

import numba
import numpy as np

if TYPE_CHECKING:
    from slam_runtime.features import FeatureModel


def det(c: np.ndarray) -> np.ndarray:
    """Determinants of (..., d, d)."""
    if c.shape[-1] == 2:
        return c[..., 0, 0] * c[..., 1, 1] - c[..., 0, 1] * c[..., 1, 0]
    return np.linalg.det(c)


def inv(c: np.ndarray) -> np.ndarray:
    """Inverses of (..., d, d) (near-singular 2x2 matrices get a floored determinant, not a NaN)."""
    if c.shape[-1] != 2:
        return np.linalg.inv(c)
    dt = det(c)
    out = np.empty_like(c)
    out[..., 0, 0] = c[..., 1, 1]
    out[..., 1, 1] = c[..., 0, 0]
    out[..., 0, 1] = -c[..., 0, 1]
    out[..., 1, 0] = -c[..., 1, 0]
    return out / np.where(np.abs(dt) > 1e-300, dt, 1e-300)[..., None, None]


def quad(a: np.ndarray, v: np.ndarray) -> np.ndarray:
    """v^T A v for symmetric A (..., d, d) and v (..., d), written out for d = 2."""
    if v.shape[-1] == 2:
        x, y = v[..., 0], v[..., 1]
        return a[..., 0, 0] * x * x + 2.0 * a[..., 0, 1] * x * y + a[..., 1, 1] * y * y
    return np.einsum("...i,...ij,...j->...", v, a, v)


def matmul(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """a @ b for stacks of small matrices, written out for 2x2 (numpy's matmul is slow on tiny matrices)."""
    if a.shape[-2:] == (2, 2) and b.shape[-2:] == (2, 2):
        out = np.empty(np.broadcast_shapes(a.shape, b.shape))
        out[..., 0, 0] = a[..., 0, 0] * b[..., 0, 0] + a[..., 0, 1] * b[..., 1, 0]
        out[..., 0, 1] = a[..., 0, 0] * b[..., 0, 1] + a[..., 0, 1] * b[..., 1, 1]
        out[..., 1, 0] = a[..., 1, 0] * b[..., 0, 0] + a[..., 1, 1] * b[..., 1, 0]
        out[..., 1, 1] = a[..., 1, 0] * b[..., 0, 1] + a[..., 1, 1] * b[..., 1, 1]
        return out
    return a @ b


def matvec(a: np.ndarray, v: np.ndarray) -> np.ndarray:
    """a @ v for (..., d, d) and (..., d)."""
    if v.shape[-1] == 2 and a.shape[-2:] == (2, 2):
        return np.stack([a[..., 0, 0] * v[..., 0] + a[..., 0, 1] * v[..., 1], a[..., 1, 0] * v[..., 0] + a[..., 1, 1] * v[..., 1]], axis=-1)
    return (a @ v[..., None])[..., 0]


def transpose(a: np.ndarray) -> np.ndarray:
    return np.swapaxes(a, -1, -2)


def ekf_update(fm: FeatureModel, sp: np.ndarray, m0: np.ndarray, c0: np.ndarray, z: np.ndarray, rz: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """EKF updates of features (m0 (N, dx), c0 (N, dx, dx), world frame) seen from sensor poses sp (N, 3) with
    measurements z (N, dz) of noise rz (N, dz, dz) through the feature model fm: K = P H^T S^-1, S = H P H^T + R,
    m = m0 + K nu, P = (I - K H) P0 (symmetrised)."""
    zhat, h = fm.predict_sensor(sp, m0)
    ph = matmul(c0, transpose(h))
    k = matmul(ph, inv(matmul(h, ph) + rz))
    c1 = c0 - matmul(k, transpose(ph))
    return m0 + matvec(k, fm.innovation(z, zhat)), 0.5 * (c1 + transpose(c1))


def birth_gaussians(fm: FeatureModel, sp: np.ndarray, z: np.ndarray, rz: np.ndarray, jitter: float) -> tuple[np.ndarray, np.ndarray]:
    """The features measurements z (M, dz) of noise rz (M, dz, dz) put in the world from each of the sensor poses sp
    (P, 3): means (P, M, dx) by the inverse sensor model, covariances G R G^T + jitter I (P, M, dx, dx), G its Jacobian
    in the measurement (the adaptive birth of every map filter)."""
    pos, g = fm.inverse_sensor(sp[:, None, :], z[None, :, :])  # (P, M, dx), (P, M, dx, dz)
    cov = matmul(matmul(g, np.broadcast_to(rz, (sp.shape[0],) + rz.shape)), transpose(g)) + np.eye(fm.dim_x) * jitter
    return pos, cov


def moment_match(key: np.ndarray, w: np.ndarray, mu: np.ndarray, cov: np.ndarray, n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Moment match of the weighted Gaussians w (N,), mu (N, d), cov (N, d, d) into the n groups key (N,) names,
    summed in index order: each group's weight (n,), mean (n, d) and covariance (n, d, d) (zero where it has no weight)."""
    d = mu.shape[1]
    tot = np.bincount(key, weights=w, minlength=n)
    safe = np.where(tot > 0, tot, 1.0)
    mean = np.stack([np.bincount(key, weights=w * mu[:, a], minlength=n) for a in range(d)], axis=-1) / safe[:, None]
    dm = mu - mean[key]
    second = cov + dm[:, :, None] * dm[:, None, :]
    c = np.stack([np.bincount(key, weights=w * second[:, a, b], minlength=n) for a in range(d) for b in range(d)], axis=-1)
    return tot, mean, c.reshape(n, d, d) / safe[:, None, None]


def gaussian(m2: np.ndarray, detc: np.ndarray, d: int) -> np.ndarray:
    """Normal density from the squared Mahalanobis distance and the covariance determinant."""
    return np.exp(-0.5 * m2) / np.sqrt((2 * np.pi) ** d * np.maximum(detc, 1e-300))


@dataclass
class GMBatch:
    w: np.ndarray  # (P, J)
    mu: np.ndarray  # (P, J, d)
    cov: np.ndarray  # (P, J, d, d)
    #: (P, J) int64 the identity of each component (the landmark a detector's reading names, e.g. a barcode; -1: none),
    #: or None when the run reads no identities; merging never joins components of different identities
    ident: np.ndarray | None = None

    @classmethod
    def empty(cls, p: int, j: int = 0, d: int = 2, ident: bool = False) -> GMBatch:
        return cls(np.zeros((p, j)), np.zeros((p, j, d)), np.tile(np.eye(d), (p, j, 1, 1)), np.full((p, j), -1, np.int64) if ident else None)

    @property
    def shape(self) -> tuple[int, int]:
        return self.w.shape  # type: ignore[return-value]

    @property
    def dim(self) -> int:
        return self.mu.shape[-1]

    def take(self, idx: np.ndarray) -> GMBatch:
        """The maps of particles ``idx`` (resampling)."""
        return GMBatch(self.w[idx], self.mu[idx], self.cov[idx], None if self.ident is None else self.ident[idx])

    def identities(self) -> np.ndarray:
        """(P, J) int64 the components' identities (-1 everywhere when the mixture carries none)."""
        return np.full(self.w.shape, -1, np.int64) if self.ident is None else self.ident

    def concat(self, other: GMBatch) -> GMBatch:
        if other.shape[1] == 0 and (other.ident is None or self.ident is not None):
            return self
        if self.shape[1] == 0 and (self.ident is None or other.ident is not None):
            return other
        ident = None if self.ident is None and other.ident is None else np.concatenate([self.identities(), other.identities()], axis=1)
        return GMBatch(
            np.concatenate([self.w, other.w], axis=1), np.concatenate([self.mu, other.mu], axis=1), np.concatenate([self.cov, other.cov], axis=1), ident
        )

    def total(self) -> np.ndarray:
        """(P,) expected number of features of each map."""
        return self.w.sum(axis=1)

    def count(self) -> np.ndarray:
        """(P,) occupied slots of each map."""
        return (self.w > 0).sum(axis=1)

    def density(self, pts: np.ndarray, gate: float | None = None) -> np.ndarray:
        """Intensity of each map at its own points pts (P, K, d) -> (P, K).

        gate: squared Mahalanobis distance beyond which a component's contribution
        is taken as 0 (``None``: exact).
        """
        d = pts[:, :, None, :] - self.mu[:, None, :, :]  # (P, K, J, d)
        m2 = quad(inv(self.cov)[:, None], d)
        g = gaussian(m2, det(self.cov)[:, None, :], self.dim)
        if gate is not None:
            g = np.where(m2 <= gate, g, 0.0)
        return (g * self.w[:, None, :]).sum(axis=2)


def prune_merge(
    gm: GMBatch,
    *,
    prune: float = 1e-4,
    merge: float = 4.0,
    cap: int = 200,
    inflate: float = 1.0,
    mutual: bool = False,
    fresh: np.ndarray | None = None,
    groups: bool = False,
):
    """Vo & Ma pruning and merging for every particle; at most ``cap`` components each.

    merge: squared Mahalanobis distance under which components merge.
    inflate: factor on the spread of the merged means (the between-component
    term of the moment match); 1 = the moment match, a group of one is never
    changed. Not the C++ RFS-SLAM library's ``covInflationFactor``, which
    multiplies the whole merged covariance: with a low P_D a mapped feature
    merges with its own missed-detection copy at every step, so that factor
    compounds (until the covariances overflow); inflating the spread adds uncertainty in proportion
    to how far apart the merged means were, and does not compound.
    mutual: a component joins the head only when each lies in the other's gate
    (Vo & Ma test only the head's): a heavy, broad head (a feature seen from
    afar, or one already grown by merging) then cannot swallow a well-localised
    neighbouring landmark, while duplicates of one landmark still merge.
    fresh: (P, J) bool, the components this step created or changed (None: all).
    A pair of two components that are not fresh is not tested. That gives the
    groups of testing every pair when the components that are not fresh came out
    of the previous call unchanged, each alone in its group (``groups=True``
    returns which outputs merged several components: pass them as fresh at the
    next call): a pair that was not merged then was tested then, with the
    weights and moments it still has. Outside the field of view lies most of a
    map, so this turns the cost from O(components^2) into O(components x fresh
    ones) per particle.
    Returns the mixture and whether the cap bound (a particle had more merged
    components than ``cap``; its lightest were dropped, as Vo & Ma do), and with
    ``groups=True`` also (P, J_out) bool: the outputs that merged more than one
    component. A mixture with identities (``gm.ident``) merges only components of
    the same identity; each output keeps its group's.

    The greedy grouping (heaviest remaining component takes every remaining one
    inside its gate) is sequential by nature: ordering, inverses, grouping
    (:func:`_group`: a head looks only at its neighbours along x) and the merged
    moments run compiled (numba), one pass per particle (:func:`_prune_merge`).
    """
    p, j = gm.shape
    d = gm.dim
    has_id = gm.ident is not None
    if j == 0:
        e = GMBatch.empty(p, 0, d, ident=has_id)
        return (e, False, np.zeros((p, 0), dtype=bool)) if groups else (e, False)
    alive = gm.w > prune
    n_alive = alive.sum(axis=1)
    # the live components, heaviest first (at most 10 cap: a bound on the cost in pathological cases)
    k = int(min(j, 10 * cap, max(1, n_alive.max())))
    new = np.ones((p, j), dtype=np.bool_) if fresh is None else np.ascontiguousarray(fresh, dtype=np.bool_)
    if d == 2:  # closed form, safe on any slot
        icov = inv(gm.cov)
    else:  # LAPACK: only the live components (an empty slot's covariance may be singular)
        icov = np.zeros_like(gm.cov)
        icov[alive] = inv(gm.cov[alive])
    # how far along x a component's gate can reach: trace >= the largest eigenvalue of its covariance
    reach = np.sqrt(merge * np.maximum(np.einsum("...ii->...", gm.cov), 0.0))
    w_out, mu_out, cov_out, id_out, size, filled = _prune_merge(
        np.ascontiguousarray(gm.w, dtype=np.float64), np.ascontiguousarray(gm.mu, dtype=np.float64),
        np.ascontiguousarray(gm.cov, dtype=np.float64), icov, reach, new, np.ascontiguousarray(gm.identities()),
        float(prune), float(merge), k, bool(mutual), float(inflate),
    )  # fmt: skip
    capped = bool(k < n_alive.max())
    if filled == 0:
        out, merged = GMBatch.empty(p, 0, d, ident=has_id), np.zeros((p, 0), dtype=bool)
        return (out, capped, merged) if groups else (out, capped)
    out = GMBatch(w_out[:, :filled], mu_out[:, :filled], cov_out[:, :filled], id_out[:, :filled] if has_id else None)
    merged = size[:, :filled] > 1
    if filled > cap:  # Vo & Ma: keep the cap heaviest merged components
        capped = capped or bool((out.w > 0).sum(axis=1).max() > cap)
        keep = np.argsort(-out.w, axis=1, kind="stable")[:, :cap]
        out = GMBatch(
            np.take_along_axis(out.w, keep, 1), np.take_along_axis(out.mu, keep[..., None], 1), np.take_along_axis(out.cov, keep[..., None, None], 1),
            None if out.ident is None else np.take_along_axis(out.ident, keep, 1),
        )
        merged = np.take_along_axis(merged, keep, 1)
    return (out, capped, merged) if groups else (out, capped)


@numba.njit(cache=True, nogil=True)
def _prune_merge(w_all, mu_all, cov_all, icov_all, reach_all, fresh_all, id_all, prune, merge, k, mutual, inflate):  # pragma: no cover - compiled
    """Prune, group (:func:`_group`) and moment-match every particle's mixture (P, J) in one pass.

    Per particle: the live components (weight > prune), heaviest first (ties in index order), at most k;
    their groups; then each group's weight, mean and covariance (with ``inflate`` times the spread of
    the means), in the order of the heads. icov_all: the inverse covariances of the live components;
    reach_all: how far along x each component's gate reaches; id_all (P, J) the identities (only equal
    ones merge). Returns w (P, k), mu (P, k, d), cov (P, k, d, d) (empty slots: weight 0, identity
    covariance), the identity of each group (P, k) (its head's; -1 in empty slots), the size of each
    group (P, k) and the largest number of groups of a particle."""
    p = w_all.shape[0]
    d = mu_all.shape[2]
    out_w = np.zeros((p, k))
    out_mu = np.zeros((p, k, d))
    out_cov = np.zeros((p, k, d, d))
    for r in range(d):
        out_cov[:, :, r, r] = 1.0
    out_n = np.zeros((p, k), dtype=np.int64)
    out_id = np.full((p, k), -1, dtype=np.int64)
    filled = 0
    for a in range(p):
        live = np.flatnonzero(w_all[a] > prune)
        order = live[np.argsort(-w_all[a][live], kind="mergesort")][:k]
        if order.size == 0:
            continue
        w, mu, cov, ids = w_all[a][order], mu_all[a][order], cov_all[a][order], id_all[a][order]
        label, used = _group(mu, icov_all[a][order], reach_all[a][order], fresh_all[a][order], ids, merge, mutual)
        filled = max(filled, used)
        # moments of each group, summed in the order of the sorted components
        tot = np.zeros(used)
        m = np.zeros((used, d))
        for q in range(order.size):
            g = label[q]
            if out_n[a, g] == 0:  # the head: the heaviest of its group
                out_id[a, g] = ids[q]
            tot[g] += w[q]
            out_n[a, g] += 1
            for r in range(d):
                m[g, r] += w[q] * mu[q, r]
        for g in range(used):
            for r in range(d):
                m[g, r] /= tot[g]
        c2 = np.zeros((used, d, d))
        for q in range(order.size):
            g = label[q]
            for r in range(d):
                dr = mu[q, r] - m[g, r]
                for c in range(d):
                    c2[g, r, c] += w[q] * (cov[q, r, c] + inflate * dr * (mu[q, c] - m[g, c]))
        for g in range(used):
            out_w[a, g] = tot[g]
            for r in range(d):
                out_mu[a, g, r] = m[g, r]
                for c in range(d):
                    out_cov[a, g, r, c] = c2[g, r, c] / tot[g]
    return out_w, out_mu, out_cov, out_id, out_n, filled


@numba.njit(cache=True, nogil=True)
def _group(mu, icov, reach, fresh, ids, merge, mutual):  # pragma: no cover - compiled
    """Vo & Ma grouping of one particle's live components, sorted by weight (heaviest first).

    mu (K, d), icov (K, d, d) the inverse covariances, reach (K,) how far along x each
    one's gate reaches, fresh (K,) the components that take part in every test (a pair
    of two others is not tested), ids (K,) their identities (a component joins only a head
    of its own). Returns label (K,) (the group of each component) and the number of groups.

    Only the components within the head's reach along x are tested: with the components
    sorted by that coordinate, a head i looks at the ones with |x_j - x_i| <= reach_i =
    sqrt(merge trace(cov_i)) (trace >= the largest eigenvalue, so no component farther
    out can lie in the gate): the same groups as testing every pair, at the cost of the
    neighbours instead of the whole map.
    """
    n, d = mu.shape
    label = np.full(n, -1, dtype=np.int64)
    by_x = np.argsort(mu[:, 0])
    xs = mu[by_x, 0]
    pos = np.empty(n, dtype=np.int64)
    pos[by_x] = np.arange(n)
    slot = 0
    for i in range(n):
        if label[i] >= 0:
            continue
        label[i] = slot
        every = fresh[i]
        for side in range(2):
            step = 1 if side == 0 else -1
            q = pos[i] + step
            while 0 <= q < n and abs(xs[q] - mu[i, 0]) <= reach[i]:
                j = by_x[q]
                q += step
                # every lighter ungrouped component inside the head's gate joins it (an old head: only fresh ones)
                if j <= i or label[j] >= 0 or not (every or fresh[j]) or ids[j] != ids[i]:
                    continue
                m2 = 0.0
                m2j = 0.0
                for r in range(d):
                    dr = mu[j, r] - mu[i, r]
                    for c in range(d):
                        dc = mu[j, c] - mu[i, c]
                        m2 += dr * icov[i, r, c] * dc
                        m2j += dr * icov[j, r, c] * dc
                if m2 <= merge and (not mutual or m2j <= merge):
                    label[j] = slot
        slot += 1
    return label, slot
