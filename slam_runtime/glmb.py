"""delta-GLMB-SLAM's map filter (Moratuwage, Adams & Inostroza): a delta-GLMB map per particle,
propagated by the Gibbs-sampled joint prediction/update of Vo, Vo & Hoang (2017).

Each particle's map is a delta-GLMB density (eqs. 10, 19-20): hypotheses
(I^(h), w^(h)) over labelled tracks, a track being one (label, association
history) version of a landmark with a Gaussian density (eq. 29 with one
component: an EKF update of a Gaussian stays Gaussian, and births are single
Gaussians). All particles are held together, padded: tracks (P, T) and
hypotheses (P, H) with their track sets as a membership mask (P, H, T). What
delta-GLMB and LMB share (candidates, births, costs, the sampler's call, EKF
updates, the map estimate's placement) is :class:`slam_runtime.labelled.LabelledFilter`.

One step (:meth:`GLMB.update`, eqs. 11-17):

* the candidates of every hypothesis are its tracks and this step's birth
  tracks, made from the previous step's measurements through the inverse
  measurement model (adaptive birth, eq. 28; Reuter et al. 2014), with birth
  probability ``birth_unassociated`` for a measurement no existing track
  could explain (outside the gate of every track of existence >= 0.5) and
  ``birth_associated`` otherwise, as in the paper;
* P_D and the buffer zone come from the detection model
  (:meth:`detectors.model.DetectionModel.pd_features`), kappa(z) from its
  clutter intensity (divided by the descriptor likelihood ratio when there is
  one, eq. 2.26 with 5.6 of the thesis); with ``learn_pd`` each label's P_D is
  the model's times a factor learned from the label's detections and misses
  (:mod:`slam_runtime.pd_factor`);
* survival (eqs. 7-8, 14): P_S = ``survival`` for a track in the field of
  view (P_D > 0), ``survival_outside`` out of it, so a mapped landmark stays in
  the map when it leaves the view; a track in the buffer zone (thesis eq. 3.21)
  neither dies nor pays for a miss; with ``survival_duplicate`` < 1 a track in
  view that an older track lies near (in measurement space:
  :meth:`LabelledFilter._duplicates`) takes that P_S instead, so that a second
  track of one landmark can end while the landmark's first stays;
* the costs eta (eqs. 5, 13, 15, 27) of every (track, measurement) pair of all
  particles in one numpy pass (only the tracks that can be seen, inside the
  gate); the Gibbs sampler (:mod:`slam_runtime.gibbs`, compiled) draws the
  children of every hypothesis, starting at its optimal assignment;
* the children's tracks are EKF updates (eqs. 17, 26-27, 30) of the pairs
  that were drawn, computed once per distinct (track, measurement) pair;
* the particle's log-likelihood is the log of the normalisation constant
  (eq. 25): the sum of the unnormalised weights of all the children drawn.
  The uniforms of the draws are keyed by (step, hypothesis rank, sample,
  candidate label), the same for every particle of a filter (common random
  numbers; islands each have their own step seeds, so they draw
  independently; ``draws: particle`` gives every particle its own); a birth
  that gates no measurement and is likelier absent is summed out of the
  sampler (``sum_idle_births``: exact for the weight, its born-but-missed
  children are not kept);
* reduction (:func:`slam_runtime.hypotheses.reduce_hypotheses`): the versions of
  one label under different association histories whose Gaussians lie within
  squared Mahalanobis distance ``merge`` of each other are merged (moment
  match; eq. 29 with the mixture reduced to one component), hypotheses that
  then coincide are one; ``merge: 0`` keeps every version, the exact filter;
  tracks of different labels within that distance that the hypotheses hold
  together with at most ``merge_alternatives`` of the lighter's weight are
  alternative labels of one landmark (two births of it, either of which the
  hypotheses took for it) and become one track under the heavier's label,
  existence the weight of the hypotheses that held either, each holding a
  label once;
* births and released tracks that share no gated measurement with another
  candidate are updated exactly, outside the sampler, as independent Bernoulli
  components (``factor_independent``; :mod:`slam_runtime.gibbs`, held
  candidates): the delta-GLMB factorises over them;
* tracks the sensor could not see this step (P_D = 0: out of view or occluded)
  leave the hypotheses as independent Bernoulli components (existence = the
  weight of the hypotheses that held them, density = the moment match of their
  versions), and rejoin every hypothesis as candidates of that existence when
  they come back into view (``release_unseen``; the exact delta-GLMB, which
  cannot hold the 2^n combinations of n unseen uncertain tracks in a few tens
  of hypotheses, is ``release_unseen: false``);
* hypotheses below ``prune`` (the paper's 1e-5) are dropped, at most
  ``max_hypotheses`` are kept (the cap; :attr:`capped_steps` counts the steps
  at which it bound), and tracks no hypothesis holds are removed; released
  tracks below ``prune_released`` are removed.

The map estimate (sec. III-B): the maximum a posteriori cardinality n of the
particle's hypotheses, then the heaviest hypothesis of cardinality n, each of
its tracks with its label's existence probability (the summed weight of the
hypotheses that hold the label); and the released tracks of existence >=
``map_threshold``. Where it puts them (``map_estimate``): ``best`` (the
paper's) at the particle's own states; ``seen_mean`` each of its labels at the
particles' weighted mean of the label's state at the last step the sensor
could see it (:meth:`LabelledFilter.record`): the landmark's filtering
posterior mean, where the best particle's state is one draw from the smoothing
posterior. How the two compare on the simulated worlds is in the docs
(docs/results.md). The set of features is the particle's either way.

The filter is generic in the feature model (``dim_x``, ``dim_z``,
``predict_sensor``, ``inverse_sensor``, ``innovation``).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np
from pydantic import Field

from slam_runtime.features import FeatureModel
from slam_runtime.hypotheses import reduce_hypotheses
from slam_runtime.labelled import Births, JointResult, LabelledFilter, LabelledSettings, Tracks, _Costs, _Slots
from slam_runtime.mapfilter import MAP_FILTERS, Measurements
from slam_runtime.pd_factor import LabelFactors, beta_update, mean_factor, prior_ab, store_key

class GLMBConfig(LabelledSettings):
    """Settings of the delta-GLMB map filter (``filter: {kind: glmb, ...}``)."""

    kind: Literal["glmb"] = "glmb"
    prune: float = Field(default=1e-5, gt=0.0, lt=1.0, description="hypotheses of smaller normalised weight are dropped")
    max_hypotheses: int = Field(default=50, ge=1, le=100_000, description="hypotheses per particle at most (the heaviest)")
    merge: float = Field(
        default=4.0, ge=0.0, description="squared Mahalanobis distance within which versions of one label merge (0: none, the exact delta-GLMB)"
    )
    release_unseen: bool = Field(default=True, description="tracks the sensor cannot see leave the hypotheses as independent components (false: exact delta-GLMB)")
    merge_alternatives: float = Field(default=0.1, ge=0.0, le=1.0, description="merge tracks the hypotheses hold as alternatives of one landmark up to this weight share (0: off)")
    factor_independent: bool = Field(default=True, description="update candidates that share no gated measurement outside the hypotheses, exactly")
    prune_released: float = Field(default=1e-3, gt=0.0, lt=1.0, description="released tracks of smaller existence probability are removed")


@dataclass
class GLMBMaps:
    """The delta-GLMB maps of P particles: the tracks of the hypotheses (P, T), the hypotheses' normalised
    log weights logw (P, H) (-inf for an empty slot) and track sets member (P, H, T) bool; the released
    tracks (independent Bernoulli components) free (P, F) with existence free_r (P, F); the births of
    the next step; with ``learn_pd`` each label's factor on P_D (:mod:`slam_runtime.pd_factor`; None without)."""

    tracks: Tracks
    logw: np.ndarray
    member: np.ndarray
    free: Tracks
    free_r: np.ndarray
    births: Births
    pd: LabelFactors | None = None

    def take(self, idx: np.ndarray) -> GLMBMaps:
        return GLMBMaps(
            self.tracks.take(idx), self.logw[idx], self.member[idx], self.free.take(idx), self.free_r[idx], self.births.take(idx),
            None if self.pd is None else self.pd.take(idx),
        )


class GLMB(LabelledFilter):
    """delta-GLMB map per particle (module docstring)."""

    name = "delta-GLMB"
    Config = GLMBConfig

    def __init__(self, feature: FeatureModel, detection, cfg: GLMBConfig, rng: np.random.Generator | None = None) -> None:
        super().__init__(feature, detection, cfg, rng)

    def empty(self, n: int) -> GLMBMaps:
        d = self.feature.dim_x
        return GLMBMaps(
            Tracks.empty(n, d), np.zeros((n, 1)), np.zeros((n, 1, 0), dtype=bool),
            Tracks.empty(n, d), np.zeros((n, 0)), Births.empty(n, d),
            LabelFactors.empty(n) if self.cfg.learn_pd else None,
        )

    def _factors(self, maps: GLMBMaps) -> LabelFactors:
        return maps.pd if maps.pd is not None else LabelFactors.empty(maps.logw.shape[0])

    def _pd_factor(self, maps: GLMBMaps) -> np.ndarray | None:
        """(P, T + F) the mean factor on P_D of each track's label, tracks then released ones (None without learn_pd)."""
        if not self.cfg.learn_pd:
            return None
        label = np.concatenate([maps.tracks.label, maps.free.label], axis=1)
        return mean_factor(self._factors(maps).get(label, prior_ab(self.cfg)))

    def _learn(self, sl: _Slots, ab: np.ndarray, pd_model: np.ndarray, buf: np.ndarray, res: JointResult, c: _Costs):
        """Each label's factor on P_D after this step (:mod:`slam_runtime.pd_factor`): (particle (K,), label (K,),
        density (K, 2)) of every label that was a candidate, from the summed weights of the hypotheses that hold its
        detected and its missed versions (a candidate updated outside the sampler: its options' shares)."""
        sp_, _ = res.slot_particle()
        wslot = res.slot_weights()
        det = res.slot_a > 0
        hp, ha = np.nonzero(c.held & ~c.idle)
        l_det = c.l_det[hp, ha] - c.l_held[hp, ha][:, None]
        w_det_h = np.exp(l_det).sum(axis=1) if l_det.shape[1] else np.zeros(hp.size)
        pp = np.concatenate([sp_, hp])
        ss = np.concatenate([res.slot_src, c.act[hp, ha]])
        uniq, first, inv = np.unique(store_key(pp, sl.label[pp, ss]), return_index=True, return_inverse=True)
        w_det = np.bincount(inv, weights=np.concatenate([wslot * det, w_det_h]), minlength=uniq.size)
        w_miss_h = np.exp(c.l_miss[hp, ha] - c.l_held[hp, ha])
        w_miss = np.bincount(inv, weights=np.concatenate([wslot * ~det, w_miss_h]), minlength=uniq.size)
        pd_miss = self._miss_pd(sl, pd_model, buf)  # (and where the sensor could not see, pd_model is 0)
        fp, fs = pp[first], ss[first]
        return fp, sl.label[fp, fs], beta_update(ab[fp, fs], pd_miss[fp, fs], w_det, w_miss)

    def _store(self, old: LabelFactors, learned, tracks: Tracks, free: Tracks) -> LabelFactors:
        """The factors of the labels the new tracks and released tracks hold: this step's where learned, else the old."""
        p = tracks.label.shape[0]
        label = np.concatenate([tracks.label, free.label], axis=1)
        nan = np.full(2, np.nan)
        ab = LabelFactors.build(p, *learned).get(label, nan)
        miss = np.isnan(ab[..., 0])
        ab[miss] = old.get(label, prior_ab(self.cfg))[miss]
        pp, kk = np.nonzero(label >= 0)
        return LabelFactors.build(p, pp, label[pp, kk], ab[pp, kk])

    def size(self, maps: GLMBMaps) -> np.ndarray:
        """(P,) tracks per particle (versions in the hypotheses and released ones)."""
        return maps.tracks.valid.sum(axis=1) + maps.free.valid.sum(axis=1)

    def hypotheses(self, maps: GLMBMaps) -> np.ndarray:
        """(P,) hypotheses per particle."""
        return np.isfinite(maps.logw).sum(axis=1)

    def update(self, maps: GLMBMaps, poses: np.ndarray, meas: Measurements) -> tuple[GLMBMaps, np.ndarray]:
        tm, cfg = self.timers, self.cfg
        z, rz, sp, log_kappa = self._begin(poses, meas)
        p = sp.shape[0]
        d = self.feature.dim_x
        tr, fr = maps.tracks, maps.free
        t, f = tr.label.shape[1], fr.label.shape[1]
        both = Tracks(np.concatenate([tr.mu, fr.mu], axis=1), np.concatenate([tr.cov, fr.cov], axis=1), np.concatenate([tr.label, fr.label], axis=1))
        sl = self._slots(both, np.concatenate([tr.valid.astype(np.float64), maps.free_r], axis=1), maps.births)
        s = sl.valid.shape[1]
        with tm("pd"):
            ex = np.concatenate([self._slot_existence(maps), maps.free_r, maps.births.r], axis=1)
            pd, buf = self.detection.pd_features(sp, sl.mu, sl.cov, meas, ex)
            self._note_seen(sl, pd)
            pd_model, ab = pd, None
            if cfg.learn_pd:
                ab = self._factors(maps).get(sl.label, prior_ab(cfg))
                pd = pd * mean_factor(ab)
            if self.frame_clutter:  # the expected detections with the learned P_D
                log_kappa = log_kappa + np.log(self.frame_clutter_scale(z.shape[0], self.expected_detections(pd, ex, sl.valid)))
        with tm("costs"):
            shared = np.concatenate([np.zeros((p, t), dtype=bool), fr.valid, np.ones((p, s - t - f), dtype=bool)], axis=1)
            c = self._costs(sl, sp, z, rz, meas.cov is not None, log_kappa, pd, buf, shared if cfg.factor_independent else None, ex)
            active = np.zeros((p, s), dtype=bool)
            in_a = np.arange(c.act.shape[1])[None, :] < c.nact[:, None]
            active[np.nonzero(in_a)[0], c.act[in_a]] = True
            live = np.isfinite(maps.logw)
            # candidates of every hypothesis: its tracks, the released tracks in view, the births
            extra = np.concatenate([fr.valid & active[:, t : t + f], np.ones((p, s - t - f), dtype=bool)], axis=1)
            member = np.concatenate([maps.member, live[:, :, None] & extra[:, None, :]], axis=2)
        with tm("gibbs"):
            res = self._sample(maps.logw, member, c, cfg.prune, 1 << 30)
        with tm("update"):
            sp_, _, mu, cov, label = self._updated(sl, sp, z, rz, res)
            ip, ia, i_r, i_mu, i_cov = self._independent(sl, sp, z, rz, c)
            i_label = sl.label[ip, c.act[ip, ia]]
            # tracks of the hypotheses that the sensor could not see leave them (module docstring)
            release = (res.slot_a == 0) & (res.slot_src < t) & ~active[sp_, res.slot_src] if cfg.release_unseen else np.zeros(sp_.size, bool)
        with tm("merge"):
            out = reduce_hypotheses(
                res.slot_count, label, np.ascontiguousarray(mu), np.ascontiguousarray(cov), release, res.hyp_count, res.hyp_logw,
                res.mem_count, res.mem_slot, float(cfg.merge), float(cfg.merge_alternatives), float(cfg.prune), int(cfg.max_hypotheses),
                self._label_identity(label),
            )
            red = JointResult.of_reduction(res.loglik, out)
            o_label, o_mu, o_cov = out[2:5]
            free_count, f_label, f_r, f_mu, f_cov = out[9:]
            self.capped_steps += int(red.capped)
            hyp_count, hyp_logw = red.hyp_count, red.hyp_logw
            sp2, sk = red.slot_particle()
            tracks = self._pad_tracks(p, d, sp2, sk, o_mu, o_cov, o_label)
            logw = np.full((p, max(int(hyp_count.max()) if p else 0, 1)), -np.inf)
            mp, mh, ms = red.memberships()
            hp = np.repeat(np.arange(p), hyp_count)
            hk = np.arange(hp.size) - np.concatenate([[0], np.cumsum(hyp_count)[:-1]])[hp]
            logw[hp, hk] = hyp_logw
            member = np.zeros((p, logw.shape[1], tracks.label.shape[1]), dtype=bool)
            member[mp, mh, ms] = True
            # released tracks: those released now, the independent candidates' exact updates, those still out of view
            keep_old = fr.valid & ~active[:, t : t + f]
            fp = np.concatenate([np.repeat(np.arange(p), free_count), ip, np.nonzero(keep_old)[0]])
            f_all = (
                np.concatenate([f_mu, i_mu, fr.mu[keep_old]]), np.concatenate([f_cov, i_cov, fr.cov[keep_old]]),
                np.concatenate([f_label, i_label, fr.label[keep_old]]), np.concatenate([f_r, i_r, maps.free_r[keep_old]]),
            )
            ok = f_all[3] >= cfg.prune_released
            fp = fp[ok]
            order = np.argsort(fp, kind="stable")
            fp = fp[order]
            fk = np.arange(fp.size) - np.searchsorted(fp, fp, side="left")
            free = self._pad_tracks(p, d, fp, fk, *(a[ok][order] for a in f_all[:3]))
            free_r = np.zeros(free.label.shape)
            free_r[fp, fk] = f_all[3][ok][order]
            factors = None
            if ab is not None:
                factors = self._store(self._factors(maps), self._learn(sl, ab, pd_model, buf, res, c), tracks, free)
        births = self._births(sp, z, rz, c.explained, c.piece)
        self.step += 1
        return GLMBMaps(tracks, logw, member, free, free_r, births, factors), res.loglik

    @staticmethod
    def _slot_existence(maps: GLMBMaps) -> np.ndarray:
        """(P, T) the summed weight of the hypotheses that hold each track (version)."""
        return np.einsum("ph,pht->pt", np.exp(maps.logw), maps.member.astype(np.float64))

    def _map_states(self, maps: GLMBMaps) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(P, T + F) means, labels and existences of the tracks in the hypotheses and the released ones."""
        tr, fr = maps.tracks, maps.free
        ex = np.concatenate([self._slot_existence(maps), maps.free_r], axis=1)
        return np.concatenate([tr.mu, fr.mu], axis=1), np.concatenate([tr.label, fr.label], axis=1), ex

    def _map_tracks(self, maps: GLMBMaps) -> tuple[Tracks, np.ndarray]:
        mu, label, ex = self._map_states(maps)
        return Tracks(mu, np.concatenate([maps.tracks.cov, maps.free.cov], axis=1), label), ex

    # ------------------------------------------------------------------ estimates
    def components(self, maps: GLMBMaps, i: int) -> tuple[np.ndarray, np.ndarray]:
        """Particle i's every track (versions in the hypotheses, released ones) and its existence."""
        t, r = self._map_tracks(maps)
        keep = t.valid[i] & (r[i] > 0)
        return t.mu[i][keep], r[i][keep]

    def existence(self, maps: GLMBMaps, i: int) -> np.ndarray:
        """(T,) existence probability of the label of each of particle i's tracks in the hypotheses."""
        w = np.exp(maps.logw[i])
        per_slot = (w[:, None] * maps.member[i]).sum(axis=0)
        lab = maps.tracks.label[i]
        ok = lab >= 0
        out = np.zeros(lab.size)
        if ok.any():
            uniq, inv_ = np.unique(lab[ok], return_inverse=True)
            out[ok] = np.bincount(inv_, weights=per_slot[ok], minlength=uniq.size)[inv_]
        return out

    def labels(self, maps: GLMBMaps, i: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Particle i's map estimate with labels: (labels (K,), states (K, dx), existence (K,)).

        The MAP cardinality of the hypotheses, then their heaviest hypothesis of that cardinality
        (sec. III-B), and the released tracks of existence >= ``map_threshold``."""
        lw = maps.logw[i]
        live = np.isfinite(lw)
        fk = (maps.free_r[i] >= self.cfg.map_threshold) & maps.free.valid[i]
        lab_f, x_f, r_f = maps.free.label[i, fk], maps.free.mu[i, fk], maps.free_r[i, fk]
        if not live.any():
            return lab_f, self._placed(lab_f, x_f), r_f
        card = maps.member[i].sum(axis=1)
        rho = np.bincount(card[live], weights=np.exp(lw[live]))
        n = int(np.argmax(rho))
        h = int(np.argmax(np.where(live & (card == n), lw, -np.inf)))
        slots = np.flatnonzero(maps.member[i, h])
        r = self.existence(maps, i)
        lab = np.concatenate([maps.tracks.label[i, slots], lab_f])
        return lab, self._placed(lab, np.concatenate([maps.tracks.mu[i, slots], x_f])), np.concatenate([r[slots], r_f])

    def estimate(self, maps: GLMBMaps, i: int) -> tuple[np.ndarray, np.ndarray]:
        _, x, r = self.labels(maps, i)
        return x, r

    def cardinality(self, maps: GLMBMaps, i: int) -> np.ndarray:
        """Particle i's cardinality distribution of the tracks in the hypotheses (n_max + 1,)."""
        lw = maps.logw[i]
        live = np.isfinite(lw)
        return np.bincount(maps.member[i].sum(axis=1)[live], weights=np.exp(lw[live]))


MAP_FILTERS.add("glmb", GLMB)
