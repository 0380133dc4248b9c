"""Particles of a Rao-Blackwellised SLAM filter: states, log-weights and an ancestry.

The vehicle states of every step are stored once, as they were sampled, with
the index of each particle's parent in the previous step (the ancestry,
(T, P) int32). Resampling only re-indexes the current states and records the
parents, so its cost does not grow with the length of the log; a trajectory is
rebuilt by walking the ancestry back when it is asked for (O(T)).

Resamplers are free functions taking normalised weights (P,) and a
``numpy.random.Generator`` and returning parent indices (P,) int64, sorted:

* :func:`systematic` (low variance): one uniform draw, P evenly spaced pointers;
* :func:`stratified`: one uniform draw per stratum;
* :func:`multinomial`: P independent draws;
* :func:`residual`: floor(P w) copies, the rest multinomial.

Example::

    >>> rng = np.random.default_rng(0)
    >>> systematic(np.array([0.5, 0.5, 0.0, 0.0]), rng)
    array([0, 0, 1, 1])
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

Resampler = Callable[[np.ndarray, np.random.Generator], np.ndarray]


def _pointers(w: np.ndarray, u: np.ndarray) -> np.ndarray:
    c = np.cumsum(w)
    c[-1] = 1.0  # guard against round-off: every pointer in [0, 1) finds a particle
    return np.minimum(np.searchsorted(c, u, side="right"), w.size - 1)


def systematic(w: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Low-variance resampling: pointers (u + i) / P, i = 0..P-1, u ~ U[0, 1)."""
    p = w.size
    return _pointers(w, (rng.uniform() + np.arange(p)) / p)


def stratified(w: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """One uniform pointer in each of the P strata [i / P, (i + 1) / P)."""
    p = w.size
    return _pointers(w, (rng.uniform(size=p) + np.arange(p)) / p)


def multinomial(w: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """P independent draws from the weights (sorted indices)."""
    return _pointers(w, np.sort(rng.uniform(size=w.size)))


def residual(w: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """floor(P w_i) copies of particle i, the remaining draws multinomial on the residual weights."""
    p = w.size
    copies = np.floor(p * w).astype(np.int64)
    idx = np.repeat(np.arange(p), copies)
    rest = p - idx.size
    if rest:
        r = p * w - copies
        idx = np.concatenate([idx, _pointers(r / r.sum(), np.sort(rng.uniform(size=rest)))])
    return np.sort(idx)


RESAMPLERS: dict[str, Resampler] = {"systematic": systematic, "stratified": stratified, "multinomial": multinomial, "residual": residual}


def normalise_log(logw: np.ndarray) -> tuple[np.ndarray, float]:
    """Normalised log-weights and the log of the normaliser (log-sum-exp)."""
    m = float(np.max(logw))
    if not np.isfinite(m):
        raise FloatingPointError("every particle has zero weight")
    s = m + float(np.log(np.sum(np.exp(logw - m))))
    return logw - s, s


def ess(logw: np.ndarray) -> float:
    """Effective sample size 1 / sum w^2 of normalised log-weights."""
    w = np.exp(logw - np.max(logw))
    w /= w.sum()
    return float(1.0 / np.sum(w * w))


class ParticleHistory:
    """Vehicle states of every step (T, P, d) and the ancestry (T, P), grown in chunks.

    Row t holds the states after step t's motion, as sampled, and ``parent[t]``
    the index (into row t - 1) each of them came from. Resampling after step t
    is recorded in ``parent[t + 1]`` implicitly: the caller appends the
    resampled states' parents with the next row.
    """

    def __init__(self, first: np.ndarray, capacity: int = 1024) -> None:
        first = np.asarray(first, dtype=np.float64)
        p, d = first.shape
        self._states = np.empty((max(capacity, 1), p, d))
        self._parent = np.empty((max(capacity, 1), p), dtype=np.int32)
        self._states[0] = first
        self._parent[0] = np.arange(p, dtype=np.int32)
        self._t = 1

    def __len__(self) -> int:
        return self._t

    def append(self, states: np.ndarray, parent: np.ndarray) -> None:
        """Add a step: states (P, d) and their parents (P,) in the previous step."""
        if self._t == self._states.shape[0]:  # double the capacity: amortised O(1) per step
            self._states = np.concatenate([self._states, np.empty_like(self._states)])
            self._parent = np.concatenate([self._parent, np.empty_like(self._parent)])
        self._states[self._t] = states
        self._parent[self._t] = parent
        self._t += 1

    def lineage(self, i: int) -> np.ndarray:
        """(T,) index of particle ``i``'s ancestor at every step."""
        idx = np.empty(self._t, dtype=np.int64)
        k = int(i)
        for t in range(self._t - 1, -1, -1):  # O(T) scalar walk: asked for once per run or per plot
            idx[t] = k
            k = int(self._parent[t, k])
        return idx

    def trajectory(self, i: int) -> np.ndarray:
        """(T, d) the states of particle ``i``'s ancestors (its trajectory), oldest first."""
        idx = self.lineage(i)
        return self._states[np.arange(self._t), idx]

    @property
    def states(self) -> np.ndarray:
        """(T, P, d) view of the stored states (not re-indexed by resampling)."""
        return self._states[: self._t]

    @property
    def parents(self) -> np.ndarray:
        """(T, P) view of the ancestry."""
        return self._parent[: self._t]
