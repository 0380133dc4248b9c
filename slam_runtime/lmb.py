"""LMB-SLAM's map filter (Deusch, Reuter & Dietmayer 2015) with the Gibbs-sampled joint prediction/update
of the fast LMB filter (Reuter et al. 2017), for the delta-GLMB-SLAM paper's comparison.

Each particle's map is a labelled multi-Bernoulli density: tracks (label,
existence r, Gaussian) (P, T). One step is the delta-GLMB step of
:mod:`slam_runtime.glmb` applied to the LMB seen as a single hypothesis whose
candidates are the tracks that can be seen (P_D > 0) and the births: a
candidate with existence r has the options dead (1 - r P_S), missed
(r P_S (1 - P_D)) and detected by z (r P_S P_D g(z) / kappa(z)); the Gibbs
sampler (:mod:`slam_runtime.gibbs`) draws the joint associations, and the
resulting delta-GLMB is approximated by an LMB again (Reuter et al. 2014,
eq. 20): each label's existence is the summed weight of the hypotheses that
hold it, and its density the mixture of its updated versions, moment-matched to
one Gaussian. Tracks out of view keep their existence and density. Tracks of
existence below ``prune_tracks`` are removed (the paper prunes LMB-SLAM's features at
0.08; the default keeps weaker tracks, which a landmark born under heavy
clutter needs: one detection lifts a 0.01 birth to about 0.02 at 15 false
alarms per scan). The particle's log-likelihood is the log of the
normalisation constant, the sum of the drawn associations' weights (eq. 25).
Births that gate no measurement are summed out of the sampler
(:mod:`slam_runtime.gibbs`) and given their exact existence afterwards; with
``factor_independent`` so is every candidate that shares no gated measurement
with another (its exact Bernoulli update, as delta-GLMB's independent births
and released tracks; the grouping of Reuter et al. 2014), off by default.
P_D, the buffer zone, kappa, survival and adaptive birth as in
:mod:`slam_runtime.glmb`.

With ``merge_alternatives`` (off by default) the update's delta-GLMB goes
through delta-GLMB's reduction (:func:`slam_runtime.hypotheses.reduce_hypotheses`)
before the LMB approximation, so that labels it holds as alternatives of one
landmark become one track (docs/results/labelled-paper.md).

P_D learned per track (``learn_pd``): :mod:`slam_runtime.pd_factor`, per track.

The map estimate: the tracks of existence >= ``map_threshold``, placed as
``map_estimate`` says (:mod:`slam_runtime.glmb`: by default the particle's own
states; ``seen_mean`` each at the particles' weighted mean of its label at
the last step it was in view).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np
from pydantic import Field

from slam_runtime.features import FeatureModel, lookup
from slam_runtime.hypotheses import reduce_hypotheses
from slam_runtime.glmb import GLMBConfig
from slam_runtime.labelled import Births, JointResult, LabelledFilter, LabelledSettings, Tracks
from slam_runtime.gm import moment_match
from slam_runtime.mapfilter import MAP_FILTERS, Measurements
from slam_runtime.pd_factor import beta_update, mean_factor, prior_ab, store_key

#: merge_alternatives: the squared Mahalanobis distance within which two labels' updated densities are alternatives
#: of one landmark (delta-GLMB's default merge)
ALTERNATIVES_GATE = GLMBConfig.model_fields["merge"].default


class LMBConfig(LabelledSettings):
    """Settings of the LMB map filter (``filter: {kind: lmb, ...}``)."""

    kind: Literal["lmb"] = "lmb"
    prune_tracks: float = Field(default=1e-3, gt=0.0, lt=1.0, description="tracks of smaller existence probability are removed")
    factor_independent: bool = Field(default=False, description="update candidates that share no gated measurement outside the sampler, exactly (Reuter et al. 2014)")
    merge_alternatives: float = Field(default=0.0, ge=0.0, le=1.0, description="merge labels the hypotheses hold as alternatives of one landmark up to this weight share (0: off)")


@dataclass
class LMBMaps:
    """The LMB maps of P particles: tracks (P, T), existence r (P, T) (0 for an empty slot), the births of the next step;
    with ``learn_pd`` each track's Beta density of its factor on P_D, pd_ab (P, T, 2) = (a, b) (None without)."""

    tracks: Tracks
    r: np.ndarray
    births: Births
    pd_ab: np.ndarray | None = None

    def take(self, idx: np.ndarray) -> LMBMaps:
        return LMBMaps(self.tracks.take(idx), self.r[idx], self.births.take(idx), None if self.pd_ab is None else self.pd_ab[idx])


class LMB(LabelledFilter):
    """LMB map per particle (module docstring)."""

    name = "LMB"
    Config = LMBConfig

    def __init__(self, feature: FeatureModel, detection, cfg: LMBConfig, rng: np.random.Generator | None = None) -> None:
        super().__init__(feature, detection, cfg, rng)

    def empty(self, n: int) -> LMBMaps:
        d = self.feature.dim_x
        return LMBMaps(
            Tracks.empty(n, d), np.zeros((n, 0)), Births.empty(n, d), np.zeros((n, 0, 2)) if self.cfg.learn_pd else None
        )

    def _track_ab(self, maps: LMBMaps) -> np.ndarray:
        """(P, T, 2) the tracks' Beta densities (the prior for maps made without learn_pd)."""
        if maps.pd_ab is not None:
            return maps.pd_ab
        return np.broadcast_to(prior_ab(self.cfg), maps.tracks.label.shape + (2,))

    def _slot_ab(self, maps: LMBMaps) -> np.ndarray | None:
        """(P, T + B, 2) the tracks' Beta densities then the births' prior (None without learn_pd)."""
        if not self.cfg.learn_pd:
            return None
        births = np.broadcast_to(prior_ab(self.cfg), (maps.r.shape[0], maps.births.label.size, 2))
        return np.concatenate([self._track_ab(maps), births], axis=1)

    def _pd_factor(self, maps: LMBMaps) -> np.ndarray | None:
        """(P, T) the mean factor on P_D of each track (None without learn_pd)."""
        return mean_factor(self._track_ab(maps)) if self.cfg.learn_pd else None

    def size(self, maps: LMBMaps) -> np.ndarray:
        return maps.tracks.valid.sum(axis=1)

    def hypotheses(self, maps: LMBMaps) -> np.ndarray:
        """(P,) one LMB per particle (the delta-GLMB it expands to between steps is not kept)."""
        return np.ones(maps.r.shape[0], dtype=np.int64)

    def update(self, maps: LMBMaps, poses: np.ndarray, meas: Measurements) -> tuple[LMBMaps, np.ndarray]:
        tm = self.timers
        z, rz, sp, log_kappa = self._begin(poses, meas)
        p = sp.shape[0]
        d = self.feature.dim_x
        sl = self._slots(maps.tracks, maps.r, maps.births)
        s = sl.valid.shape[1]
        ab = self._slot_ab(maps)
        with tm("pd"):
            pd, buf = self.detection.pd_features(sp, sl.mu, sl.cov, meas, sl.r)
            self._note_seen(sl, pd)
        with tm("costs"):
            pd_model = pd
            if ab is not None:
                pd = pd * mean_factor(ab)
            if self.frame_clutter:  # the expected detections with the learned P_D
                log_kappa = log_kappa + np.log(self.frame_clutter_scale(z.shape[0], self.expected_detections(pd, sl.r, sl.valid)))
            # one hypothesis: every candidate is a candidate of every hypothesis, with the same options
            c = self._costs(sl, sp, z, rz, meas.cov is not None, log_kappa, pd, buf, np.ones((p, s), dtype=bool) if self.cfg.factor_independent else None)
            member = np.zeros((p, 1, s), dtype=bool)
            in_a = np.arange(c.act.shape[1])[None, :] < c.nact[:, None]
            member[np.nonzero(in_a)[0], 0, c.act[in_a]] = True
        with tm("gibbs"):
            # the whole delta-GLMB of the joint update is kept for the LMB approximation
            res = self._sample(np.zeros((p, 1)), member, c, 0.0, 1 << 30)
        with tm("update"):
            sp_, _, mu, cov, label = self._updated(sl, sp, z, rz, res)
            wslot = res.slot_weights()
            # the LMB approximation: per label (source slot), existence and the moment-matched Gaussian
            key = sp_ * s + res.slot_src  # each new slot's source slot, over all particles
            if self.cfg.merge_alternatives > 0.0:
                r_new, m_new, c_new = self._merged(sl, res, label, mu, cov)
            else:
                r_new, m_new, c_new = moment_match(key, wslot, mu, cov, p * s)
            active = np.zeros((p, s), dtype=bool)
            active[np.nonzero(in_a)[0], c.act[in_a]] = True
            r_all = np.where(active, r_new.reshape(p, s), sl.r)
            # births the sampler held absent (they gate nothing) have their exact existence r_B (1 - P_D) / (1 - r_B P_D)
            # and their birth density
            hp, ha = np.nonzero(c.idle)
            hs = c.act[hp, ha]
            r_all[hp, hs] = 1.0 / (1.0 + np.exp(c.l_death[hp, ha] - c.l_miss[hp, ha]))
            # independent candidates (factor_independent) have their exact Bernoulli update
            ip, ia, i_r, i_mu, i_cov = self._independent(sl, sp, z, rz, c)
            i_s = c.act[ip, ia]
            r_all[ip, i_s] = i_r
            if ab is not None:
                # each label's factor on P_D, from its detected and missed versions' weights (an idle birth: missed)
                det = res.slot_a > 0
                w_det = np.bincount(key, weights=wslot * det, minlength=p * s).reshape(p, s)
                w_miss = np.bincount(key, weights=wslot * ~det, minlength=p * s).reshape(p, s)
                w_det, w_miss = np.where(active, w_det, 0.0), np.where(active, w_miss, 0.0)
                w_det[hp, hs], w_miss[hp, hs] = 0.0, 1.0
                # an independent candidate: its options' shares
                lh = c.l_held[ip, ia]
                w_det[ip, i_s] = np.exp(c.l_det[ip, ia] - lh[:, None]).sum(axis=1)
                w_miss[ip, i_s] = np.exp(c.l_miss[ip, ia] - lh)
                ab = beta_update(ab, self._miss_pd(sl, pd_model, buf), w_det, w_miss)
            active[hp, hs] = False  # keeps its prior mean and covariance below
            active[ip, i_s] = False
            mu_all = np.where(active[..., None], m_new.reshape(p, s, d), sl.mu)
            cov_all = np.where(active[..., None, None], c_new.reshape(p, s, d, d), sl.cov)
            mu_all[ip, i_s], cov_all[ip, i_s] = i_mu, i_cov
            keep = sl.valid & (r_all >= self.cfg.prune_tracks)
            cnt = keep.sum(axis=1)
            order = np.argsort(~keep, axis=1, kind="stable")[:, : int(cnt.max()) if p else 0]
            rows = np.arange(p)[:, None]
            held = np.arange(order.shape[1])[None, :] < cnt[:, None]
            tracks = Tracks(
                np.where(held[..., None], mu_all[rows, order], 0.0),
                np.where(held[..., None, None], cov_all[rows, order], np.eye(d)),
                np.where(held, sl.label[rows, order], -1),
            )
            r = np.where(held, r_all[rows, order], 0.0)
            pd_ab = None if ab is None else np.where(held[..., None], ab[rows, order], prior_ab(self.cfg))
        births = self._births(sp, z, rz, c.explained, c.piece)
        self.step += 1
        return LMBMaps(tracks, r, births, pd_ab), res.loglik

    def _merged(self, sl, res: JointResult, label: np.ndarray, mu: np.ndarray, cov: np.ndarray):
        """The LMB approximation (per source slot, flat (P S,): existence, mean, covariance) of the update's
        delta-GLMB (res; the new slots' label, mu, cov) after its alternative labels of one landmark are merged
        (``merge_alternatives``; :func:`slam_runtime.hypotheses.reduce_hypotheses`, which also merges each label's versions
        within ALTERNATIVES_GATE: the moment match of merged versions is the moment match of them all). A label merged
        into another leaves its slot empty (existence 0). The existence is the weight of the children that hold the
        track, each once (the reduction leaves every child each label once; counted by child, the existence stays
        at most 1 by construction)."""
        p, s = sl.label.shape
        out = reduce_hypotheses(
            res.slot_count, label, np.ascontiguousarray(mu), np.ascontiguousarray(cov), np.zeros(label.size, dtype=bool),
            res.hyp_count, res.hyp_logw, res.mem_count, res.mem_slot, ALTERNATIVES_GATE, float(self.cfg.merge_alternatives),
            0.0, 1 << 30, self._label_identity(label),
        )
        o_label, o_mu, o_cov = out[2:5]
        red = JointResult.of_reduction(res.loglik, out)
        sp2, _ = red.slot_particle()
        # each reduced slot's source slot: the slot of its label in its particle (an LMB holds a label once; the
        # reduction keeps only labels it was given)
        vp, vs = np.nonzero(sl.valid)
        keys = store_key(vp, sl.label[vp, vs])
        order = np.argsort(keys, kind="stable")
        j, _ = lookup(keys[order], store_key(sp2, o_label))
        key = sp2 * s + vs[order][j]
        _, mean, cov_ = moment_match(key, red.slot_weights(), o_mu, o_cov, p * s)
        return np.minimum(red.group_weights(key, p * s), 1.0), mean, cov_

    def _map_states(self, maps: LMBMaps) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        return maps.tracks.mu, maps.tracks.label, maps.r

    def _map_tracks(self, maps: LMBMaps) -> tuple[Tracks, np.ndarray]:
        return maps.tracks, maps.r

    def components(self, maps: LMBMaps, i: int) -> tuple[np.ndarray, np.ndarray]:
        """Particle i's every track and its existence."""
        keep = maps.tracks.valid[i]
        return maps.tracks.mu[i][keep], maps.r[i][keep]

    def labels(self, maps: LMBMaps, i: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Particle i's map estimate with labels: (labels (K,), states (K, dx), existence (K,)), r >= map_threshold."""
        keep = (maps.r[i] >= self.cfg.map_threshold) & maps.tracks.valid[i]
        lab = maps.tracks.label[i, keep]
        return lab, self._placed(lab, maps.tracks.mu[i, keep]), maps.r[i, keep]

    def estimate(self, maps: LMBMaps, i: int) -> tuple[np.ndarray, np.ndarray]:
        _, x, r = self.labels(maps, i)
        return x, r


MAP_FILTERS.add("lmb", LMB)
