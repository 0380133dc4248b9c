"""A factor on the detection model's P_D learned per track (``learn_pd`` of the
labelled filters, off by default).

The detection model gives P_D from where a feature is and what occludes it,
for the detector's true features; a static object that the detector reports
less often than that (a bush that fits a circle in some scans) is tracked
with the wrong P_D, and each of its misses weighs the particles by 1 - P_D.
With ``learn_pd`` each track carries a Beta(a, b) density of a factor q on
the model's P_D (P_D = q P_D(model); the prior mean ``pd_prior_mean`` with
``pd_prior_strength`` pseudo-looks): the costs take its mean, and after each
update the label's detected versions give Beta(a + 1, b), its missed version
(1 - q P_D) Beta(a, b) (a mixture of Beta(a, b) and Beta(a, b + 1)), and the
mixture of the two, weighted as the versions are, is moment-matched to one
Beta (as Mahler, Vo & Vo 2011 do for an unknown P_D with a Beta density,
there without a model of P_D). A miss in the buffer zone, or out of view,
tells nothing.

LMB keeps one density per track (:mod:`slam_runtime.lmb`); delta-GLMB keeps
one per label of a particle (:class:`LabelFactors`), over all the versions and
hypotheses that hold the label (the LMB approximation of the factor alone), so
that versions, merges, released tracks and alternatives need no density of
their own; the weights of its detected and missed versions are the summed
weights of the hypotheses that hold them (for a candidate updated outside the
sampler, its options' shares).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from slam_runtime.features import lookup

#: bits of a store key that hold the label (key = particle << KEY_BITS + label)
KEY_BITS = 42


def store_key(particle: np.ndarray, label: np.ndarray) -> np.ndarray:
    """One int64 key per (particle, label): ordered by particle, then label."""
    return (np.asarray(particle, dtype=np.int64) << KEY_BITS) + label


def prior_ab(cfg) -> np.ndarray:
    """(2,) a new track's Beta density (a, b) of its factor on P_D, from the settings' ``pd_prior_mean`` and ``pd_prior_strength``."""
    return np.array([cfg.pd_prior_mean, 1.0 - cfg.pd_prior_mean]) * cfg.pd_prior_strength


def beta_update(ab: np.ndarray, pd: np.ndarray, w_det: np.ndarray, w_miss: np.ndarray) -> np.ndarray:
    """The Beta densities ab (..., 2) = (a, b) of tracks' factors q on P_D after a step in which each was detected with
    weight w_det and missed with weight w_miss (...,), P_D = q pd: the mixture of Beta(a + 1, b) and the missed
    posterior (1 - q pd) Beta(a, b) / (1 - pd E[q]), moment-matched to one Beta (module docstring). Where
    w_det + w_miss is 0 the density is unchanged."""
    a, b = ab[..., 0], ab[..., 1]
    n = a + b
    m1 = a / n
    m2 = m1 * (a + 1) / (n + 1)
    m3 = m2 * (a + 2) / (n + 2)
    d1 = (a + 1) / (n + 1)
    d2 = d1 * (a + 2) / (n + 2)
    z = 1.0 - pd * m1
    e1, e2 = (m1 - pd * m2) / z, (m2 - pd * m3) / z
    wt = w_det + w_miss
    ok = wt > 0
    safe = np.where(ok, wt, 1.0)
    mean = (w_det * d1 + w_miss * e1) / safe
    var = (w_det * d2 + w_miss * e2) / safe - mean**2
    mean = np.clip(mean, 1e-9, 1.0 - 1e-9)
    strength = np.clip(mean * (1.0 - mean) / np.maximum(var, 1e-300) - 1.0, 1e-6, 1e9)
    return np.where(ok[..., None], np.stack([mean * strength, (1.0 - mean) * strength], axis=-1), ab)


def mean_factor(ab: np.ndarray) -> np.ndarray:
    """The mean a / (a + b) of Beta densities ab (..., 2)."""
    return ab[..., 0] / ab.sum(axis=-1)


@dataclass
class LabelFactors:
    """Each particle's labels and their Beta densities, padded: label (P, L) int64 (-1: empty), ab (P, L, 2).

    Each row holds its labels in ascending order from slot 0 (:meth:`build` makes them so; :meth:`take` moves
    whole rows), so the valid entries read row by row are in :func:`store_key` order without a sort."""

    label: np.ndarray
    ab: np.ndarray

    @classmethod
    def empty(cls, p: int) -> LabelFactors:
        return cls(np.full((p, 0), -1, np.int64), np.zeros((p, 0, 2)))

    def take(self, idx: np.ndarray) -> LabelFactors:
        return LabelFactors(self.label[idx], self.ab[idx])

    def get(self, label: np.ndarray, prior: np.ndarray) -> np.ndarray:
        """(P, S, 2) the densities of the labels (P, S) of each particle; the prior for a label it does not hold."""
        pp, ll = np.nonzero(self.label >= 0)
        j, hit = lookup(store_key(pp, self.label[pp, ll]), store_key(np.arange(label.shape[0])[:, None], label))
        hit &= label >= 0
        out = np.broadcast_to(prior, label.shape + (2,)).copy()
        out[hit] = self.ab[pp[j[hit]], ll[j[hit]]]
        return out

    @staticmethod
    def build(p: int, particle: np.ndarray, label: np.ndarray, ab: np.ndarray) -> LabelFactors:
        """The store of the (particle (N,), label (N,), density (N, 2)) given, one entry per distinct (particle, label)
        (the first given)."""
        _, first = np.unique(store_key(particle, label), return_index=True)
        pp, ll, aa = particle[first], label[first], ab[first]
        cnt = np.bincount(pp, minlength=p)
        k = np.arange(pp.size) - np.concatenate([[0], np.cumsum(cnt)[:-1]])[pp]
        out = LabelFactors(
            np.full((p, int(cnt.max()) if p and pp.size else 0), -1, np.int64),
            np.zeros((p, int(cnt.max()) if p and pp.size else 0, 2)),
        )
        out.label[pp, k], out.ab[pp, k] = ll, aa
        return out
