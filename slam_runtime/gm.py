"""Gaussian-mixture maps of many particles at once: padded struct-of-arrays.

A batch of P maps with capacity J holds weights w (P, J) (0 = empty slot),
means mu (P, J, 2) and covariances cov (P, J, 2, 2), all in the world frame.
Pruning and merging follow Vo & Ma (2006): drop components under a weight
threshold, then repeatedly take the heaviest remaining component and merge
every remaining one within a Mahalanobis distance of it. The merge loop runs
once per output component, each round vectorised over all particles and
components.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass
class GMBatch:
    w: np.ndarray  # (P, J)
    mu: np.ndarray  # (P, J, 2)
    cov: np.ndarray  # (P, J, 2, 2)

    @classmethod
    def empty(cls, p: int, j: int = 0) -> GMBatch:
        return cls(np.zeros((p, j)), np.zeros((p, j, 2)), np.tile(np.eye(2), (p, j, 1, 1)))

    @property
    def shape(self) -> tuple[int, int]:
        return self.w.shape  # type: ignore[return-value]

    def take(self, idx: np.ndarray) -> GMBatch:
        """The maps of particles ``idx`` (resampling)."""
        return GMBatch(self.w[idx].copy(), self.mu[idx].copy(), self.cov[idx].copy())

    def concat(self, other: GMBatch) -> GMBatch:
        return GMBatch(
            np.concatenate([self.w, other.w], axis=1),
            np.concatenate([self.mu, other.mu], axis=1),
            np.concatenate([self.cov, other.cov], axis=1),
        )

    def total(self) -> np.ndarray:
        """(P,) expected number of features of each map."""
        return self.w.sum(axis=1)

    def density(self, pts: np.ndarray) -> np.ndarray:
        """Intensity of each map at its own points pts (P, K, 2) -> (P, K)."""
        d = pts[:, :, None, :] - self.mu[:, None, :, :]  # (P, K, J, 2)
        inv = _inv2(self.cov)[:, None]  # (P, 1, J, 2, 2)
        m2 = _quad(inv, d[..., 0], d[..., 1])
        det = _det2(self.cov)
        g = np.exp(-0.5 * m2) / (2 * np.pi * np.sqrt(np.maximum(det, 1e-300)))[:, None, :]
        return (g * self.w[:, None, :]).sum(axis=2)


def _quad(inv: np.ndarray, dx: np.ndarray, dy: np.ndarray) -> np.ndarray:
    """d^T A d for symmetric 2x2 A (..., 2, 2) and d = (dx, dy), written out (einsum is slow here)."""
    return inv[..., 0, 0] * dx * dx + 2.0 * inv[..., 0, 1] * dx * dy + inv[..., 1, 1] * dy * dy


def _det2(c: np.ndarray) -> np.ndarray:
    return c[..., 0, 0] * c[..., 1, 1] - c[..., 0, 1] * c[..., 1, 0]


def _inv2(c: np.ndarray) -> np.ndarray:
    det = _det2(c)
    inv = np.empty_like(c)
    inv[..., 0, 0] = c[..., 1, 1]
    inv[..., 1, 1] = c[..., 0, 0]
    inv[..., 0, 1] = -c[..., 0, 1]
    inv[..., 1, 0] = -c[..., 1, 0]
    return inv / np.where(np.abs(det) > 1e-300, det, 1e-300)[..., None, None]


def prune_merge(gm: GMBatch, *, prune: float = 1e-4, merge: float = 4.0, cap: int = 200) -> GMBatch:
    """Vo & Ma pruning and merging for every particle; at most ``cap`` components each.

    merge: squared Mahalanobis distance under which components merge.

    The greedy grouping (heaviest remaining component takes every remaining one
    inside its gate) runs on a precomputed adjacency, one cheap boolean round per
    output component for all particles at once; the merged moments are then
    summed in one pass with ``bincount``.
    """
    p, j = gm.shape
    if j == 0:
        return GMBatch.empty(p, 0)
    alive = gm.w > prune
    # keep the heaviest min(j, 4 cap) live components, heaviest first
    k = int(min(j, 4 * cap, max(1, alive.sum(axis=1).max())))
    order = np.argsort(-np.where(alive, gm.w, -1.0), axis=1, kind="stable")[:, :k]
    w = np.take_along_axis(gm.w, order, axis=1)
    mu = np.take_along_axis(gm.mu, order[..., None], axis=1)
    cov = np.take_along_axis(gm.cov, order[..., None, None], axis=1)
    alive = w > prune
    inv = _inv2(cov)
    # adj[p, i, l]: component l lies inside the gate of component i (Vo & Ma use the head's covariance)
    adj = np.empty((p, k, k), dtype=bool)
    step = max(1, 2_000_000 // (k * k))
    for a in range(0, p, step):
        sl = slice(a, a + step)
        d = mu[sl, None, :, :] - mu[sl, :, None, :]  # (p', K, K, 2): l - i
        adj[sl] = _quad(inv[sl, :, None], d[..., 0], d[..., 1]) <= merge
    label = np.full((p, k), -1, dtype=np.int64)
    rows = np.arange(p)
    filled = 0
    for slot in range(cap):  # one output component per round; components are sorted, so the head is the first alive
        if not alive.any():
            break
        filled = slot + 1
        has = alive.any(axis=1)
        head = np.argmax(alive, axis=1)
        grp = adj[rows, head] & alive & has[:, None]
        label[grp] = slot
        alive &= ~grp
    if filled == 0:
        return GMBatch.empty(p, 0)
    # moments of each group (weights, means, covariances with the spread of the means)
    ok = label >= 0
    idx = (rows[:, None] * filled + label)[ok]
    wt = w[ok]
    n = p * filled
    tot = np.bincount(idx, weights=wt, minlength=n)
    safe = np.where(tot > 0, tot, 1.0)
    m = np.stack([np.bincount(idx, weights=wt * mu[ok][:, c], minlength=n) for c in range(2)], axis=-1) / safe[:, None]
    dm = mu[ok] - m[idx]
    second = cov[ok] + dm[:, :, None] * dm[:, None, :]
    c = np.stack([np.bincount(idx, weights=wt * second[:, a, b], minlength=n) for a in range(2) for b in range(2)], axis=-1)
    c = c.reshape(n, 2, 2) / safe[:, None, None]
    empty = tot == 0
    c[empty] = np.eye(2)
    return GMBatch(tot.reshape(p, filled), m.reshape(p, filled, 2), c.reshape(p, filled, 2, 2))
