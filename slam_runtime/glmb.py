"""delta-GLMB-SLAM's map filter (Moratuwage, Adams & Inostroza): a delta-GLMB map per particle,
propagated by the Gibbs-sampled joint prediction/update of Vo, Vo & Hoang (2017).

Each particle's map is a delta-GLMB density (eqs. 10, 19-20): hypotheses
(I^(h), w^(h)) over labelled tracks, a track being one (label, association
history) version of a landmark with a Gaussian density (eq. 29 with one
component: an EKF update of a Gaussian stays Gaussian, and births are single
Gaussians). All particles are held together, padded: tracks (P, T) and
hypotheses (P, H) with their track sets as a membership mask (P, H, T).

One step (:meth:`GLMB.update`, eqs. 11-17):

* the candidates of every hypothesis are its tracks and this step's birth
  tracks, made from the previous step's measurements through the inverse
  measurement model (adaptive birth, eq. 28; Reuter et al. 2014), with birth
  probability ``birth_unassociated`` (0.01) for a measurement no existing track
  could explain (outside the gate of every track of existence >= 0.5) and
  ``birth_associated`` (0.005) otherwise, as in the paper;
* P_D and the buffer zone come from the detection model
  (:meth:`detectors.model.DetectionModel.pd_features`), kappa(z) from its
  clutter intensity (divided by the descriptor likelihood ratio when there is
  one, eq. 2.26 with 5.6 of the thesis); with ``learn_pd`` (off by default)
  each label's P_D is the model's times a factor learned from the label's
  detections and misses (:mod:`slam_runtime.pd_factor`);
* survival (eqs. 7-8, 14): P_S = ``survival`` for a track in the field of
  view (P_D > 0), ``survival_outside`` (1) out of it, so a mapped landmark
  stays in the map when it leaves the view; the paper takes 0.95 in view, the
  default is 1 (static landmarks: with 0.95 per scan a landmark missed twice is
  believed gone with probability 0.42); a track in the buffer zone (thesis
  eq. 3.21) neither dies nor pays for a miss; with ``survival_duplicate`` < 1
  a track in view that an older track lies near (in measurement space:
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
  numbers; islands each have their own step seeds, so they draw independently), so
  particles whose maps and poses agree draw the same hypotheses and their
  weights differ by what differs between them, not by sampling luck, even when
  one holds a track the other lacks (``draws: particle``: a seed per particle,
  independent draws among which the weights select; measured in the docs:
  better with the poses given, level in full SLAM); a birth that gates no measurement and is
  likelier absent is summed out of the sampler (``sum_idle_births``: exact for
  the weight, its born-but-missed children are not kept; :mod:`slam_runtime.gibbs`);
* reduction (:func:`slam_runtime.hypotheses.reduce_hypotheses`): the versions of
  one label under different association histories whose Gaussians lie within
  squared Mahalanobis distance ``merge`` (4) of each other are merged (moment
  match; eq. 29 with the mixture reduced to one component), hypotheses that
  then coincide are one; ``merge: 0`` keeps every version, the exact filter;
  tracks of different labels within that distance that the hypotheses hold
  together with at most ``merge_alternatives`` (0.1) of the lighter's weight
  are alternative labels of one landmark (two births of it, either of which
  the hypotheses took for it) and become one track under the heavier's label,
  existence the weight of the hypotheses that held either, each holding a label
  once (one that held the lighter beside another version of the heavier's label
  keeps that version; see the reduction) (released one by one,
  a landmark split 0.4 / 0.35 / 0.25 between three labels was in no map
  estimate, measured on glmb-paper);
* births and released tracks that share no gated measurement with another
  candidate are updated exactly, outside the sampler, as independent Bernoulli
  components (``factor_independent``; :mod:`slam_runtime.gibbs`, held
  candidates): the delta-GLMB factorises over them;
* tracks the sensor could not see this step (P_D = 0: out of view or occluded)
  leave the hypotheses as independent Bernoulli components (existence = the
  weight of the hypotheses that held them, density = the moment match of their
  versions), and rejoin every hypothesis as candidates of that existence when
  they come back into view (``release_unseen``). The exact delta-GLMB leaves
  an unseen track's existence unchanged and independent of new evidence; with
  a few tens of hypotheses it cannot hold the 2^n combinations of n unseen
  uncertain tracks, and the truncation lets their existences random-walk to 0
  or 1 (measured on the glmb-paper scenario: false landmarks of existence 1
  and true ones lost). ``release_unseen: false`` is the exact filter;
* hypotheses below ``prune`` (1e-5, the paper's value) are dropped, at most
  ``max_hypotheses`` are kept (the cap; :attr:`capped_steps` counts the steps
  at which it bound), and tracks no hypothesis holds are removed; released
  tracks below ``prune_released`` are removed.

The map estimate (sec. III-B): the maximum a posteriori cardinality n of the
particle's hypotheses, then the heaviest hypothesis of cardinality n, each of
its tracks with its label's existence probability (the summed weight of the
hypotheses that hold the label); and the released tracks of existence >=
``map_threshold``. Where it puts them (``map_estimate``): ``best`` (the
default, the paper's) at the particle's own states; ``seen_mean`` each of its
labels at the particles' weighted mean of the label's state (each particle's
versions weighted by their existence) at the last step the sensor could see it
in some particle (P_D > 0), recorded after the weights took that step's
likelihood (:meth:`LabelledFilter.record`, called by the particle loop). A
label is one landmark in every particle (its step and measurement), so the
mean is the landmark's filtering posterior mean given the data up to then;
the best particle's state is one draw from the smoothing posterior (its map
carries the error of its own history, which resampling made the history of
every particle for all but the last steps). Neither is better everywhere
(glmb-paper, 60 runs per clutter rate, README): on world 1 the mean gives
0.057-0.087 of map OSPA against 0.101-0.126; on worlds 2-5, where the filtering
estimate drifts up to 0.45 m before a loop closure corrects the particles'
histories (and so the best particle's map, not the record), 0.129-0.139
against 0.108-0.116. The set of features is the particle's either way.

The filter is generic in the feature model (``dim_x``, ``dim_z``,
``predict_sensor``, ``inverse_sensor``, ``innovation``).
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from functools import cached_property
from typing import Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from profiles.errors import UsageError
from slam_runtime.features import FeatureModel, lookup, mean_by_label
from slam_runtime.gibbs import detection_costs, joint_update
from slam_runtime.hypotheses import reduce_hypotheses
from slam_runtime.gm import det, inv, matmul, matvec, moment_match, quad, transpose
from slam_runtime.mapfilter import MAP_FILTERS, MapFilter, Measurements
from slam_runtime.pd_factor import LabelFactors, beta_update, mean_factor, prior_ab, store_key

#: bits of a label that hold the measurement index: label = (step << LABEL_BITS) + measurement
LABEL_BITS = 20

#: survival_duplicate: the existence from which an older track makes a younger one near it a possible second
#: track of its landmark. 0.5 (likelier there than not) was measured first: on the paper's worlds at 15 false alarms
#: per scan LMB then missed more landmarks (0.57 per run against 0.33), most likely because an uncertain older track
#: made a landmark's younger track mortal and LMB lost both; 0.99 (a landmark's confirmed track) missed 0.48
#: (docs/labelled-filters.md)
DUPLICATE_OF = 0.99


def label_parts(label: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(step, measurement) a label was born from: the filter step whose measurement gave the birth track."""
    label = np.asarray(label, dtype=np.int64)
    return label >> LABEL_BITS, label & ((1 << LABEL_BITS) - 1)


class LabelledSettings(BaseModel):
    """Settings shared by the labelled map filters (LMB, delta-GLMB)."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)
    survival: float = Field(default=1.0, gt=0.0, le=1.0, description="P_S per step of a feature in the field of view (the paper: 0.95)")
    survival_outside: float = Field(default=1.0, gt=0.0, le=1.0, description="P_S of a feature out of the field of view")
    survival_duplicate: float = Field(default=1.0, gt=0.0, le=1.0, description="P_S in view of a track an older track of its particle lies near (1: off)")
    duplicate_gate: float = Field(default=1.0, gt=0.0, description="squared Mahalanobis distance within which survival_duplicate takes two tracks for one landmark")
    birth_unassociated: float = Field(default=0.01, gt=0.0, lt=1.0, description="birth probability from a measurement outside every track's gate")
    birth_associated: float = Field(default=0.005, gt=0.0, lt=1.0, description="birth probability from a measurement some track could explain")
    gate: float = Field(default=16.0, gt=0.0, description="squared Mahalanobis distance beyond which a measurement cannot update a track")
    samples: int = Field(default=60, ge=1, le=100_000, description="Gibbs samples per particle and step, shared among the hypotheses by sqrt(weight)")
    noise_inflation: float = Field(default=1.0, ge=1.0, description="factor on the measurement noise covariance")
    landmark_noise: float = Field(default=0.0, ge=0.0, description="landmark position variance added per second [m^2/s]")
    map_threshold: float = Field(default=0.5, gt=0.0, le=1.0, description="existence probability from which a track counts as mapped (LMB)")
    map_estimate: Literal["best", "seen_mean"] = Field(default="best", description="best: features at the best particle's states; seen_mean: at the particles' mean when last seen")
    learn_pd: bool = Field(default=False, description="each track learns a factor on P_D from its detections and misses (Beta density)")
    pd_prior_mean: float = Field(
        default=0.95, gt=0.0, lt=1.0, description="learn_pd: the prior mean of a new track's factor on P_D"
    )
    pd_prior_strength: float = Field(
        default=20.0, gt=0.0, description="learn_pd: the prior's weight, in detections and misses (a + b)"
    )
    draws: Literal["filter", "particle"] = Field(default="filter", description="Gibbs sampler random numbers: one seed per step and filter (filter) or per particle (particle)")
    sum_idle_births: bool = Field(default=True, description="sum births that gate no measurement out of the Gibbs sampler (exact for the weights)")


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
class Tracks:
    """Labelled Gaussian tracks of P particles, padded: particle p's tracks fill slots 0..n_p - 1.

    mu (P, T, dx), cov (P, T, dx, dx) world frame; label (P, T) int64, -1 for an empty slot.
    """

    mu: np.ndarray
    cov: np.ndarray
    label: np.ndarray

    @classmethod
    def empty(cls, p: int, d: int, t: int = 0) -> Tracks:
        return cls(np.zeros((p, t, d)), np.tile(np.eye(d), (p, t, 1, 1)), np.full((p, t), -1, np.int64))

    @property
    def valid(self) -> np.ndarray:
        return self.label >= 0

    def take(self, idx: np.ndarray) -> Tracks:
        return Tracks(self.mu[idx], self.cov[idx], self.label[idx])


@dataclass
class Births:
    """Birth tracks for the next step, one per measurement of this one: mu (P, B, dx), cov (P, B, dx, dx),
    r (P, B) birth probabilities, label (B,)."""

    mu: np.ndarray
    cov: np.ndarray
    r: np.ndarray
    label: np.ndarray

    @classmethod
    def empty(cls, p: int, d: int) -> Births:
        return cls(np.zeros((p, 0, d)), np.zeros((p, 0, d, d)), np.zeros((p, 0)), np.zeros(0, np.int64))

    def take(self, idx: np.ndarray) -> Births:
        return Births(self.mu[idx], self.cov[idx], self.r[idx], self.label)


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


@dataclass
class JointResult:
    """The compiled sampler's output, flattened over particles (see :func:`slam_runtime.gibbs.joint_update`)."""

    loglik: np.ndarray  # (P,)
    capped: bool
    hyp_count: np.ndarray  # (P,)
    hyp_logw: np.ndarray  # (sum hyp_count,)
    mem_count: np.ndarray  # (sum hyp_count,)
    mem_slot: np.ndarray  # (sum mem_count,)
    slot_count: np.ndarray  # (P,)
    slot_src: np.ndarray  # (sum slot_count,)
    slot_a: np.ndarray  # (sum slot_count,)

    def slot_particle(self) -> tuple[np.ndarray, np.ndarray]:
        """(particle, index within the particle) of every new slot."""
        p = np.repeat(np.arange(self.slot_count.size), self.slot_count)
        start = np.concatenate([[0], np.cumsum(self.slot_count)[:-1]])
        return p, np.arange(p.size) - start[p]

    @classmethod
    def of_reduction(cls, loglik: np.ndarray, out: tuple) -> JointResult:
        """The hypotheses and slots that :func:`slam_runtime.hypotheses.reduce_hypotheses` returned (out), without sources."""
        capped, slot_count, _, _, _, hyp_count, hyp_logw, mem_count, mem_slot = out[:9]
        return cls(loglik, bool(capped), hyp_count, hyp_logw, mem_count, mem_slot, slot_count, np.zeros(0, np.int64), np.zeros(0, np.int64))

    @cached_property
    def _held(self) -> tuple[np.ndarray, np.ndarray]:
        """(new slot (flat), hypothesis (flat)) of every membership (computed once: slot_weights and group_weights
        both read it)."""
        off = np.concatenate([[0], np.cumsum(self.slot_count)[:-1]])
        mp, _, ms = self.memberships()
        return off[mp] + ms, np.repeat(np.arange(self.hyp_logw.size), self.mem_count)

    def slot_weights(self) -> np.ndarray:
        """(sum slot_count,) the summed weight of the children (hypotheses) that hold each new slot."""
        slot, hyp = self._held
        return np.bincount(slot, weights=np.exp(self.hyp_logw)[hyp], minlength=int(self.slot_count.sum()))

    def group_weights(self, group: np.ndarray, n: int) -> np.ndarray:
        """(n,) the summed weight of the children that hold some slot of each group (group (sum slot_count,): each new
        slot's group, 0..n-1), a child that holds several slots of one group counted once."""
        slot, hyp = self._held
        pair = np.unique(hyp * n + group[slot])
        return np.bincount(pair % n, weights=np.exp(self.hyp_logw)[pair // n], minlength=n)

    def memberships(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(particle, hypothesis index within the particle, slot index within the particle) of every membership."""
        hp = np.repeat(np.arange(self.hyp_count.size), self.hyp_count)
        start = np.concatenate([[0], np.cumsum(self.hyp_count)[:-1]])
        hk = np.arange(hp.size) - start[hp]
        return np.repeat(hp, self.mem_count), np.repeat(hk, self.mem_count), self.mem_slot


@dataclass
class _Slots:
    """Every slot the step works on: the tracks then the births (P, S = T + B)."""

    mu: np.ndarray
    cov: np.ndarray
    r: np.ndarray  # existence of the slot as a candidate: 1 (GLMB track), r (LMB track), r_B (birth)
    label: np.ndarray
    valid: np.ndarray
    birth: np.ndarray  # (P, S) bool


@dataclass
class _Costs:
    act: np.ndarray  # (P, A) slot of each active candidate
    nact: np.ndarray  # (P,)
    l_death: np.ndarray  # (P, A)
    l_miss: np.ndarray  # (P, A)
    l_det: np.ndarray  # (P, A, M)
    explained: np.ndarray  # (P, M) some existing track could explain the measurement (inside its gate)
    held: np.ndarray  # (P, A) bool: candidates left out of the sampler, the sum of their options in the weight
    l_held: np.ndarray  # (P, A) log of that sum (0 where not held)
    idle: np.ndarray  # (P, A) bool: the held births that gate nothing and are likelier absent (delta-GLMB drops them)
    label: np.ndarray  # (P, A) int64: the label of each active candidate


class LabelledFilter(MapFilter):
    """What the LMB and delta-GLMB map filters share: slots, costs, the sampler call, EKF updates, births."""

    labelled = True
    proposes_poses = True
    # without the occlusion test the labelled filters no longer keep the tracks of static clutter (docs/results.md)
    occlusion_default = float("inf")

    def __init__(self, feature: FeatureModel, detection, cfg: LabelledSettings, rng: np.random.Generator | None = None) -> None:
        super().__init__(feature, detection)
        self.cfg = cfg
        self.r = feature.r * cfg.noise_inflation
        self.rng, self.groups = rng, 1
        self.step = 0
        # the map estimate's positions (map_estimate: seen_mean): per label, sorted, the particles' weighted mean
        # state at the last step the sensor could see it; made by record() at step _rec_step
        self._seen = np.zeros(0, np.int64)
        self._rec_label = np.zeros(0, np.int64)
        self._rec_x = np.zeros((0, feature.dim_x))
        self._rec_step = -1

    def bind(self, rng: np.random.Generator, groups: int = 1) -> None:
        """Use the run's generator for the Gibbs sampler (the particle loop calls this); the particles come in
        ``groups`` equal contiguous groups (islands), each drawing with its own step seed."""
        self.rng, self.groups = rng, groups

    def _seeds(self, p: int) -> np.ndarray:
        """(p,) each particle's seed of this step, drawn from the run's generator: one per group (island), or with
        ``draws: particle`` one per particle."""
        if self.rng is None:
            raise UsageError(f"the {self.name} map filter needs a random generator: pass rng= or let the particle loop bind one")
        if p % self.groups:
            raise UsageError(f"the {self.name} map filter's {p} particles do not split into {self.groups} islands")
        if self.cfg.draws == "particle":
            return self.rng.integers(0, 2**62, size=p)
        return np.repeat(self.rng.integers(0, 2**62, size=self.groups), p // self.groups)

    # ------------------------------------------------------------------ pieces of a step
    def _log_kappa(self, z: np.ndarray, meas: Measurements) -> np.ndarray:
        return np.log(np.maximum(self.clutter(z, meas), 1e-300))

    def _costs(
        self, sl: _Slots, sp: np.ndarray, z: np.ndarray, rz: np.ndarray, own_cov: bool, log_kappa: np.ndarray, pd, buf,
        shared: np.ndarray | None = None, exist: np.ndarray | None = None,
    ) -> _Costs:
        """log eta of every option of the active candidates (module docstring of :mod:`slam_runtime.gibbs`);
        shared (P, S): the slots that are candidates of every hypothesis with the same options (births, released
        tracks), held out of the sampler when independent of every other candidate (None: only idle births);
        exist (P, S): each slot's existence probability (for ``survival_duplicate``; None: sl.r)."""
        cfg, fm = self.cfg, self.feature
        p, s = sl.valid.shape
        m = z.shape[0]
        pd = np.where(sl.valid, np.minimum(pd, 1.0 - 1e-9), 0.0)  # a miss always stays possible
        buf = buf & sl.valid & ~sl.birth
        active = sl.valid & ((pd > 0) | sl.birth)
        nact = active.sum(axis=1)
        a = int(nact.max()) if p and s else 0
        act = np.argsort(~active, axis=1, kind="stable")[:, :a]
        rows = np.arange(p)[:, None]
        in_a = np.arange(a)[None, :] < nact[:, None]
        pd_a, buf_a, r_a, birth_a = pd[rows, act], buf[rows, act], sl.r[rows, act], sl.birth[rows, act]
        ps = np.where(birth_a | buf_a, 1.0, np.where(pd_a > 0, cfg.survival, cfg.survival_outside))
        dup_on = cfg.survival_duplicate < 1.0 and a > 1
        if a and (m or dup_on):
            mu_a, cov_a = sl.mu[rows, act], sl.cov[rows, act]
            zhat, h = fm.predict_sensor(sp[:, None, :], mu_a)
            hph = matmul(h, matmul(cov_a, transpose(h)))
            if dup_on:  # (an active track that is not a birth has P_D > 0)
                cand = in_a & ~birth_a & ~buf_a
                dup = self._duplicates(sl.label[rows, act], cand, (sl.r if exist is None else exist)[rows, act], zhat, hph)
                ps = np.where(dup, np.minimum(ps, cfg.survival_duplicate), ps)
        pd_miss = np.where(buf_a, 0.0, pd_a)
        with np.errstate(divide="ignore"):
            l_death = np.log(np.maximum(1.0 - r_a * ps, 0.0))
            l_miss = np.log(r_a * ps * (1.0 - pd_miss))
            l_base = np.log(r_a * ps * pd_a)
        l_det = np.full((p, a, m), -np.inf)
        explained = np.zeros((p, m), dtype=bool)
        if a and m:
            l_det, gated = self._det_costs(zhat, hph, z, rz, own_cov, l_base, log_kappa, in_a, pd_a > 0)
            # a measurement 'can be associated with an existing feature' (the lower birth probability) when it lies in
            # the gate of a track that is more likely there than not: an LMB track of existence >= 0.5, any track a
            # delta-GLMB hypothesis holds (r = 1 there; a rule on the label's summed weight instead was measured: more
            # births, 40 % more CPU at 15 false alarms per scan, no better map)
            explained = (gated & (~birth_a & (r_a >= 0.5))[..., None]).any(axis=1)
        # candidates held out of the sampler (module docstring of slam_runtime.gibbs): idle births (they gate nothing and
        # absence is the likelier option) and, where shared is given, the independent births and released tracks
        fin = np.isfinite(l_det)
        idle = birth_a & in_a & ~fin.any(axis=2) & (l_death > l_miss) & cfg.sum_idle_births
        held = idle.copy()
        if shared is not None:
            # independent: no measurement it gates is gated by another candidate (module docstring)
            alone = ~(fin & (fin.sum(axis=1) > 1)[:, None, :]).any(axis=2)
            held |= shared[rows, act] & in_a & alone
        l_held = np.zeros(held.shape)
        if held.any():
            opts = np.concatenate([l_death[held][:, None], l_miss[held][:, None], l_det[held]], axis=1)
            mx = opts.max(axis=1)
            l_held[held] = mx + np.log(np.exp(opts - mx[:, None]).sum(axis=1))
        return _Costs(
            act.astype(np.int64), nact.astype(np.int64), l_death, l_miss, l_det, explained, held, l_held, idle, sl.label[rows, act].astype(np.int64)
        )

    def _duplicates(self, lab: np.ndarray, cand: np.ndarray, exist: np.ndarray, zhat: np.ndarray, hph: np.ndarray) -> np.ndarray:
        """(P, A) the candidates cand (P, A) that an older candidate of their particle lies near: a possible second
        track of one landmark (``survival_duplicate``). Versions of one label are never each other's duplicates.

        Older: a smaller label (born at an earlier step, or at the same step from an earlier measurement), of
        existence (its label's, summed over its versions among the candidates; exist (P, A)) at least
        ``DUPLICATE_OF`` (0.99).

        Near: one measurement cannot tell the two apart, the squared Mahalanobis distance of their predicted
        measurements zhat (P, A, dz) under H P H^T of both (hph (P, A, dz, dz)) plus the model's measurement noise R
        below ``duplicate_gate``. In measurement space, not in the map's: on real logs a track's covariance shrinks
        to centimetres (UTIAS: a median 1.2 cm) where its duplicates lie 6-25 cm away, distinct by the tracks'
        covariances but not by any measurement. R is the model's: where measurements carry their own covariances
        (the laser's circle fits, the planes) it is the floor added to them, so the gate is stricter there than
        'one measurement' says. While a new track's covariance is still large, a distinct landmark near a confirmed
        one can be inside the gate for its first steps, and takes survival_duplicate then."""
        same = lab[:, :, None] == lab[:, None, :]  # (P, A, A)
        lab_ex = np.einsum("pij,pj->pi", (same & cand[:, None, :]).astype(np.float64), np.where(cand, exist, 0.0))
        older = cand[:, :, None] & cand[:, None, :] & (lab[:, None, :] < lab[:, :, None]) & (lab_ex >= DUPLICATE_OF)[:, None, :]
        i, j, k = np.nonzero(older)
        nu = self.feature.innovation(zhat[i, j], zhat[i, k])
        near = quad(inv(hph[i, j] + hph[i, k] + self.r), nu) < self.cfg.duplicate_gate
        out = np.zeros(cand.shape, dtype=bool)
        out[i[near], j[near]] = True
        return out

    def _det_costs(self, zhat, hph, z, rz, own_cov: bool, l_base, log_kappa, in_a, pd_pos, compiled: bool = True):
        """log eta of the detections (P, A, M) (-inf outside the gate or where P_D = 0) and the gate (P, A, M) of the
        active candidates: predicted measurements zhat (P, A, dz), H P H^T (P, A, dz, dz), measurements z (M, dz),
        their own covariances rz (M, dz, dz) when own_cov (else the model's R), l_base (P, A) log(r P_S P_D).

        Point landmarks (dz = 2) take :func:`slam_runtime.gibbs.detection_costs`, the same arithmetic fused in one
        compiled pass: at 300 particles, ~45 candidates and 15-20 measurements per scan the vectorised form made some
        twenty (P, A, M) temporaries and was the step's second cost after the sampler. compiled=False: the vectorised
        form (other dz, and the tests' reference)."""
        cfg, fm = self.cfg, self.feature
        dz = z.shape[1]
        if compiled and dz == 2 and fm.angular in ((), (1,)):
            return detection_costs(
                np.ascontiguousarray(zhat), np.ascontiguousarray(hph), np.ascontiguousarray(z, dtype=np.float64),
                np.ascontiguousarray(rz, dtype=np.float64) if own_cov else np.zeros((0, 2, 2)), bool(own_cov), np.ascontiguousarray(self.r),
                np.zeros((0, 0)) if own_cov else np.log(np.maximum(det(hph + self.r), 1e-300)), fm.angular == (1,), float(cfg.gate),
                float(dz * np.log(2 * np.pi)), np.ascontiguousarray(l_base), np.ascontiguousarray(log_kappa, dtype=np.float64),
                np.ascontiguousarray(in_a), np.ascontiguousarray(pd_pos),
            )
        nu = fm.innovation(z[None, None, :, :], zhat[:, :, None, :])  # (P, A, M, dz)
        if own_cov:
            sm = hph[:, :, None] + rz[None, None]
            m2, logdet = quad(inv(sm), nu), np.log(np.maximum(det(sm), 1e-300))
        else:
            sm = hph + self.r
            m2, logdet = quad(inv(sm)[:, :, None], nu), np.log(np.maximum(det(sm), 1e-300))[:, :, None]
        gated = (m2 <= cfg.gate) & in_a[..., None]
        ok = gated & pd_pos[..., None]
        lq = -0.5 * m2 - 0.5 * (dz * np.log(2 * np.pi) + logdet)
        return np.where(ok, l_base[..., None] + lq - log_kappa[None, None, :], -np.inf), gated

    def _sample(self, logw: np.ndarray, member: np.ndarray, c: _Costs, prune: float, cap: int) -> JointResult:
        out = joint_update(
            self._seeds(logw.shape[0]), np.ascontiguousarray(logw), np.ascontiguousarray(member), c.act, c.nact,
            np.ascontiguousarray(c.l_death), np.ascontiguousarray(c.l_miss), np.ascontiguousarray(c.l_det),
            int(self.cfg.samples), float(prune), int(cap), np.ascontiguousarray(c.held), np.ascontiguousarray(c.l_held), np.ascontiguousarray(c.label),
        )
        return JointResult(*out)

    def _updated(self, sl: _Slots, sp: np.ndarray, z: np.ndarray, rz: np.ndarray, res: JointResult):
        """The new slots' Gaussians and labels, flat (N, dx), (N, dx, dx), (N,): the source slot's
        density, EKF-updated with measurement a - 1 where a > 0 (eqs. 17, 30)."""
        sp_, sk = res.slot_particle()
        mu = sl.mu[sp_, res.slot_src].copy()
        cov = sl.cov[sp_, res.slot_src].copy()
        label = sl.label[sp_, res.slot_src]
        upd = np.flatnonzero(res.slot_a > 0)
        if upd.size:
            jj = res.slot_a[upd] - 1
            mu[upd], cov[upd] = self._ekf(sp[sp_[upd]], mu[upd], cov[upd], z[jj], rz[jj])
        return sp_, sk, mu, cov, label

    @staticmethod
    def _miss_pd(sl: _Slots, pd_model: np.ndarray, buf: np.ndarray) -> np.ndarray:
        """(P, S) the model's P_D that a miss of each slot weighs, for learning its factor: 0 in the buffer zone (thesis
        eq. 3.21: a miss there tells nothing, as in the costs) and for an empty slot."""
        return np.where(sl.valid & ~(buf & ~sl.birth), np.minimum(pd_model, 1.0 - 1e-9), 0.0)

    def _ekf(self, sp: np.ndarray, m0: np.ndarray, c0: np.ndarray, z: np.ndarray, rz: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """EKF updates (eqs. 17, 30) of the Gaussians (m0, c0) (N, dx), (N, dx, dx) seen from sensor poses sp with
        measurements z (N, dz) of noise rz (N, dz, dz)."""
        fm = self.feature
        zhat, h = fm.predict_sensor(sp, m0)
        ph = matmul(c0, transpose(h))
        k = matmul(ph, inv(matmul(h, ph) + rz))
        c1 = c0 - matmul(k, transpose(ph))
        return m0 + matvec(k, fm.innovation(z, zhat)), 0.5 * (c1 + transpose(c1))

    def _independent(self, sl: _Slots, sp: np.ndarray, z: np.ndarray, rz: np.ndarray, c: _Costs):
        """The exact Bernoulli update of the held candidates that are not idle births: (particle (K,), candidate
        (K,), existence (K,), mean (K, dx), covariance (K, dx, dx)), the candidates in the order of
        ``np.nonzero(c.held & ~c.idle)`` (slot ``c.act[particle, candidate]``): existence the share of its options in
        which it exists, density the moment match of its missed (prior) and detected (EKF-updated) versions."""
        hp, ha = np.nonzero(c.held & ~c.idle)
        hs = c.act[hp, ha]
        mu0, cov0, lh = sl.mu[hp, hs], sl.cov[hp, hs], c.l_held[hp, ha]
        q, j = np.nonzero(np.isfinite(c.l_det[hp, ha]))
        m_det, c_det = self._ekf(sp[hp[q]], mu0[q], cov0[q], z[j], rz[j]) if q.size else (mu0[:0], cov0[:0])
        # the versions: detected by each gated measurement, then missed (the prior)
        r, mean, cov = moment_match(
            np.concatenate([q, np.arange(hp.size)]), np.exp(np.concatenate([c.l_det[hp[q], ha[q], j] - lh[q], c.l_miss[hp, ha] - lh])),
            np.concatenate([m_det, mu0]), np.concatenate([c_det, cov0]), hp.size,
        )
        return hp, ha, np.minimum(r, 1.0), mean, cov

    def _births(self, sp: np.ndarray, z: np.ndarray, rz: np.ndarray, explained: np.ndarray) -> Births:
        """Birth tracks for the next step from this step's measurements (eq. 28, adaptive birth)."""
        p, m = sp.shape[0], z.shape[0]
        d = self.feature.dim_x
        if m == 0:
            return Births.empty(p, d)
        pos, g = self.feature.inverse_sensor(sp[:, None, :], z[None, :, :])  # (P, M, dx), (P, M, dx, dz)
        cov = matmul(matmul(g, np.broadcast_to(rz, (p,) + rz.shape)), transpose(g)) + np.eye(d) * 1e-6
        r = np.where(explained, self.cfg.birth_associated, self.cfg.birth_unassociated)
        label = (np.int64(self.step) << LABEL_BITS) + np.arange(m, dtype=np.int64)
        return Births(pos, cov, r, label)

    @staticmethod
    def _slots(tracks: Tracks, r_tracks: np.ndarray, births: Births) -> _Slots:
        p, t = tracks.label.shape
        b = births.label.size
        return _Slots(
            np.concatenate([tracks.mu, births.mu], axis=1),
            np.concatenate([tracks.cov, births.cov], axis=1),
            np.concatenate([r_tracks, births.r], axis=1),
            np.concatenate([tracks.label, np.broadcast_to(births.label, (p, b))], axis=1),
            np.concatenate([tracks.valid, np.ones((p, b), dtype=bool)], axis=1),
            np.concatenate([np.zeros((p, t), dtype=bool), np.ones((p, b), dtype=bool)], axis=1),
        )

    @staticmethod
    def _pad_tracks(p: int, d: int, sp_: np.ndarray, sk: np.ndarray, mu, cov, label) -> Tracks:
        t = int(sk.max()) + 1 if sk.size else 0
        out = Tracks.empty(p, d, t)
        out.mu[sp_, sk], out.cov[sp_, sk], out.label[sp_, sk] = mu, cov, label
        return out

    def predict(self, maps, dt: float):
        q = self.cfg.landmark_noise * max(dt, 0.0)
        if q > 0 and maps.tracks.label.shape[1]:
            t = maps.tracks
            maps = replace(maps, tracks=Tracks(t.mu, t.cov + q * np.eye(self.feature.dim_x), t.label))
        return maps

    def pose_proposal(
        self, maps, xbar: np.ndarray, q: np.ndarray, meas: Measurements, *, share: float = 0.5, iterations: int = 3
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """A Gaussian approximation of the optimal importance density of each particle's pose (FastSLAM 2.0,
        as RB-PHD's): the motion prior N(xbar, q) (P, 3), (P, 3, 3) updated by the frame's measurements
        that the particle's map explains, each by its likeliest track when that track takes at least
        ``share`` of it (r P_D g(z) against kappa(z) + the sum over tracks, g with the prior's pose
        uncertainty in its covariance), with an iterated EKF
        (re-linearised ``iterations`` times). Returns the mean (P, 3), covariance (P, 3, 3) and the number
        of measurements used (P,)."""
        t, ex = self._map_tracks(maps)
        return self._proposal(
            xbar, q, meas, t.mu, t.cov, ex, t.valid,
            gate=self.cfg.gate, share=share, iterations=iterations, pd_factor=self._pd_factor(maps),
        )

    def _pd_factor(self, maps) -> np.ndarray | None:
        """(P, J) each track's learned factor on P_D, in the order of :meth:`_map_tracks` (None: not learned)."""
        return None

    # ------------------------------------------------------------------ the map estimate's positions
    def _note_seen(self, sl: _Slots, pd: np.ndarray) -> None:
        """Keep the labels the sensor could see this step in some particle (P_D > 0), for :meth:`record`."""
        if self.cfg.map_estimate == "seen_mean":
            self._seen = np.unique(sl.label[sl.valid & (pd > 0)])

    def record(self, maps, logw: np.ndarray) -> None:
        """After the particles' weights took this step's likelihood (the particle loop calls this): for every label
        some particle holds, the particles' weighted mean of its state, each particle's versions weighted by their
        existence; a label the sensor could not see this step keeps the mean of the last step it could
        (``map_estimate: seen_mean``; module docstring)."""
        if self.cfg.map_estimate != "seen_mean":
            return
        with self.timers("estimate"):
            mu, label, ex = self._map_states(maps)
            pp, ss = np.nonzero((label >= 0) & (ex > 0))
            # (a plane's versions keep the normal's orientation they were born with: plane_features)
            uniq, mean = mean_by_label(label[pp, ss], mu[pp, ss], np.exp(logw - np.max(logw))[pp] * ex[pp, ss], self.feature.state_angular)
            j, hit = lookup(self._rec_label, uniq)
            kept = hit & ~np.isin(uniq, self._seen)
            mean[kept] = self._rec_x[j[kept]]
            self._rec_label, self._rec_x, self._rec_step = uniq, mean, self.step

    def _placed(self, label: np.ndarray, x: np.ndarray) -> np.ndarray:
        """The states of a map estimate's labels: the record's (``map_estimate: seen_mean``, when it was made for
        these maps) or the particle's own x."""
        if self.cfg.map_estimate != "seen_mean" or self._rec_step != self.step or not label.size:
            return x
        j, hit = lookup(self._rec_label, label)
        x = x.copy()
        x[hit] = self._rec_x[j[hit]]
        return x

    def _begin(self, poses: np.ndarray, meas: Measurements):
        z, rz = self.measurements(meas)
        sp = self.feature.sensor_pose(np.asarray(poses, dtype=np.float64))
        return z, rz, sp, self._log_kappa(z, meas)


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
        births = self._births(sp, z, rz, c.explained)
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
