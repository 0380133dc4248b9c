"""What the labelled map filters (LMB, delta-GLMB) share: labels, tracks and births held for all particles,
the costs of the joint prediction/update, the compiled sampler's call, the EKF updates of the pairs it drew,
adaptive birth, survival of duplicates, the map estimate's placement, and the motion of the features.

Features are static by default (a track moves only by ``landmark_noise``). With ``feature_motion:
constant_velocity`` (point features) each track is a moving point (x, y, vx, vy) predicted through the
constant-velocity transition of Li & Yang (Sensors 2022, sec. 4; :mod:`slam_runtime.cv_transition`):
mu' = F mu, P' = F P F^T + sigma^2 B B^T at every step, for the tracks and the births alike; it is measured
through its position (:class:`slam_runtime.cv_transition.MovingPoint`, whose P_D and buffer zone the detection
model reads from the position part, :class:`slam_runtime.cv_transition.PositionView`), and a birth's velocity
starts at 0 with standard deviation ``birth_speed`` per axis.

A label is the (step, measurement) a track's birth came from (:func:`label_parts`), so particles that gave birth
to a landmark from the same measurement share its label. Tracks (P, T) and births (P, B) are padded over the P
particles. :class:`LabelledFilter` is the base; :class:`slam_runtime.glmb.GLMB` keeps hypotheses over its tracks,
:class:`slam_runtime.lmb.LMB` one Bernoulli component per label.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from functools import cached_property
from typing import Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from profiles.errors import UsageError
from slam_runtime.cv_transition import ConstantVelocity, MovingPoint, PositionView
from slam_runtime.features import FeatureModel, RangeBearing, lookup, mean_by_label
from slam_runtime.gibbs import joint_update
from slam_runtime.gm import birth_gaussians, ekf_update, inv, matmul, moment_match, quad, transpose
from slam_runtime.mapfilter import MapFilter, Measurements
from slam_runtime.proposal import identity_match

#: bits of a label that hold the measurement index: label = (step << LABEL_BITS) + measurement
LABEL_BITS = 20

#: survival_duplicate: the existence from which an older track makes a younger one near it a possible second
#: track of its landmark (a landmark's confirmed track; how it was chosen: docs/results.md)
DUPLICATE_OF = 0.99


def _room(buf: np.ndarray, size: int) -> np.ndarray:
    """``buf`` with room for ``size`` entries: itself, or a copy twice as long (amortised appends)."""
    if buf.size >= size:
        return buf
    out = np.zeros(max(size, 2 * buf.size), buf.dtype)
    out[: buf.size] = buf
    return out


def label_parts(label: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(step, measurement) a label was born from: the filter step whose measurement gave the birth track."""
    label = np.asarray(label, dtype=np.int64)
    return label >> LABEL_BITS, label & ((1 << LABEL_BITS) - 1)


class LabelledSettings(BaseModel):
    """Settings shared by the labelled map filters (LMB, delta-GLMB)."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)
    survival: float = Field(default=1.0, gt=0.0, le=1.0, description="P_S per step of a feature in the field of view (the paper: 0.95)")
    survival_outside: float = Field(default=1.0, gt=0.0, le=1.0, description="P_S of a feature out of the field of view")
    survival_duplicate: float | None = Field(
        default=None, gt=0.0, le=1.0,
        description="P_S in view of a track an older track of its particle lies near (1: off; null: planes 0.5, points 1)",
    )
    duplicate_gate: float = Field(default=1.0, gt=0.0, description="points: squared Mahalanobis distance within which survival_duplicate takes two tracks for one landmark")
    duplicate_sigmas: float = Field(
        default=3.0, gt=0.0,
        description="planes: two tracks are one landmark within this many sqrt(2) x R's sigmas of normal and offset",
    )
    birth_unassociated: float = Field(default=0.01, gt=0.0, lt=1.0, description="birth probability from a measurement outside every track's gate")
    birth_associated: float = Field(default=0.005, gt=0.0, lt=1.0, description="birth probability from a measurement some track could explain")
    birth_piece: float = Field(
        default=1e-4, gt=0.0, lt=1.0,
        description="planes: birth probability from a measurement within duplicate_sigmas of a confirmed track",
    )
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
    feature_motion: Literal["static", "constant_velocity"] = Field(
        default="static", description="static features, or point features in constant-velocity motion (x, y, vx, vy; Li & Yang sec. 4)"
    )
    feature_acceleration: float = Field(
        default=0.5, ge=0.0, description="constant_velocity: sigma of the acceleration noise, Q = sigma^2 B B^T [m/s^2] (Li & Yang: 0.5)"
    )
    birth_speed: float = Field(default=1.0, gt=0.0, description="constant_velocity: standard deviation of a new feature's velocity per axis [m/s]")


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
    piece: np.ndarray  # (P, M) planes: the measurement lies within the duplicate distance of a confirmed track
    held: np.ndarray  # (P, A) bool: candidates left out of the sampler, the sum of their options in the weight
    l_held: np.ndarray  # (P, A) log of that sum (0 where not held)
    idle: np.ndarray  # (P, A) bool: the held births that gate nothing and are likelier absent (delta-GLMB drops them)
    label: np.ndarray  # (P, A) int64: the label of each active candidate


class LabelledFilter(MapFilter):
    """What the LMB and delta-GLMB map filters share: slots, costs, the sampler call, EKF updates, births."""

    labelled = True
    proposes_poses = True
    takes_identities = True
    # without the occlusion test the labelled filters no longer keep the tracks of static clutter (docs/results.md)
    occlusion_default = float("inf")

    def __init__(self, feature: FeatureModel, detection, cfg: LabelledSettings, rng: np.random.Generator | None = None) -> None:
        #: the features' transition (None: static)
        self.transition: ConstantVelocity | None = None
        if cfg.feature_motion == "constant_velocity":
            if type(feature) is not RangeBearing:
                raise UsageError(f"filter.feature_motion: constant_velocity moves point features (features: points), not {type(feature).__name__}")
            feature = MovingPoint(feature.r, feature.mount, cfg.birth_speed)
            detection = PositionView(detection)
            self.transition = ConstantVelocity(cfg.feature_acceleration)
        super().__init__(feature, detection)
        self.cfg = cfg
        self.r = feature.r * cfg.noise_inflation
        #: planar features (the plane metric's duplicate test, which also sees tracks in the buffer zone)
        self._plane_features = type(feature).plane_gap is not FeatureModel.plane_gap
        #: the plane metric's limits (normal angle, offset): duplicate_sigmas x sqrt(2) x R's normal and offset sigmas
        sig, lim = np.sqrt(np.diag(self.r)), cfg.duplicate_sigmas * np.sqrt(2.0)
        self._plane_limits = (lim * max(sig[0], sig[1]), lim * sig[2]) if self._plane_features else None
        #: P_S of a possible second track (survival_duplicate; null: the feature model's own)
        self.survival_duplicate = feature.survival_duplicate if cfg.survival_duplicate is None else cfg.survival_duplicate
        self.rng, self.groups = rng, 1
        self.step = 0
        # the map estimate's positions (map_estimate: seen_mean): per label, sorted, the particles' weighted mean
        # state at the last step the sensor could see it; made by record() at step _rec_step
        self._seen = np.zeros(0, np.int64)
        self._rec_label = np.zeros(0, np.int64)
        self._rec_x = np.zeros((0, feature.dim_x))
        self._rec_step = -1
        # identities (detection.identities): the identity each recorded step's measurements read, flat, the steps
        # recorded (ascending) and each one's offset into it (a label names the step and the measurement it was born
        # from: its identity is that one's; a step without identities has none); buffers that grow by doubling, the
        # first _id_n steps (and _id_n + 1 offsets) in use
        self._id_n = 0
        self._id_step = np.zeros(0, np.int64)
        self._id_off = np.zeros(1, np.int64)
        self._id_flat = np.zeros(0, np.int64)
        self._frame_ident: np.ndarray | None = None

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
        dup_on = self.survival_duplicate < 1.0 and a > 1
        if a and (m or dup_on):
            mu_a, cov_a = sl.mu[rows, act], sl.cov[rows, act]
            zhat, h = fm.predict_sensor(sp[:, None, :], mu_a)
            hph = matmul(h, matmul(cov_a, transpose(h)))
            if dup_on:  # (an active track that is not a birth has P_D > 0)
                # planes: the buffer zone (P_D uncertain at the edge of a plane's visibility) is where a partly seen
                # plane leaves its pieces, so its tracks take the test too; point features' buffer tracks do not
                cand = in_a & ~birth_a & (~buf_a | self._plane_features)
                dup = self._duplicates(sl.label[rows, act], cand, (sl.r if exist is None else exist)[rows, act], zhat, hph)
                ps = np.where(dup, np.minimum(ps, self.survival_duplicate), ps)
        pd_miss = np.where(buf_a, 0.0, pd_a)
        with np.errstate(divide="ignore"):
            l_death = np.log(np.maximum(1.0 - r_a * ps, 0.0))
            l_miss = np.log(r_a * ps * (1.0 - pd_miss))
            l_base = np.log(r_a * ps * pd_a)
        l_det = np.full((p, a, m), -np.inf)
        explained = np.zeros((p, m), dtype=bool)
        if a and m:
            l_det, gated = self._det_costs(zhat, hph, z, rz, own_cov, l_base, log_kappa, in_a, pd_a > 0)
            if self._frame_ident is not None:  # a track may make only the measurements of its own identity
                match = identity_match(self._label_identity(sl.label[rows, act]), self._frame_ident)
                l_det, gated = np.where(match, l_det, -np.inf), gated & match
            # a measurement 'can be associated with an existing feature' (the lower birth probability) when it lies in
            # the gate of a track that is more likely there than not: an LMB track of existence >= 0.5, any track a
            # delta-GLMB hypothesis holds (r = 1 there; a rule on the label's summed weight instead made more births and
            # cost more CPU for no better map: docs/results.md)
            explained = (gated & (~birth_a & (r_a >= 0.5))[..., None]).any(axis=1)
        piece = np.zeros((p, m), dtype=bool)
        if a and m:
            # planes: a measurement as near a confirmed track as a piece of its plane (the duplicate test's plane
            # metric) is that plane seen in pieces, not a new landmark (birth_piece)
            near = self._plane_near(zhat[:, :, None, :], z[None, None, :, :])
            if near is not None:
                conf = in_a & ~birth_a & (r_a >= DUPLICATE_OF)
                piece = (near & conf[..., None]).any(axis=1)
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
            act.astype(np.int64), nact.astype(np.int64), l_death, l_miss, l_det, explained, piece, held, l_held, idle,
            sl.label[rows, act].astype(np.int64),
        )

    def _plane_near(self, za: np.ndarray, zb: np.ndarray) -> np.ndarray | None:
        """(...) bool: planes za, zb (..., 3) (sensor-frame charts, broadcast) one landmark could give, the normals
        within duplicate_sigmas x sqrt(2) x R's normal sigma and the offsets within as many offset sigmas
        (:meth:`_duplicates`); None for features that are not planes."""
        if self._plane_limits is None:
            return None
        gap = self.feature.plane_gap(za, zb)
        return (gap[0] <= self._plane_limits[0]) & (gap[1] <= self._plane_limits[1])

    def _duplicates(self, lab: np.ndarray, cand: np.ndarray, exist: np.ndarray, zhat: np.ndarray, hph: np.ndarray) -> np.ndarray:
        """(P, A) the candidates cand (P, A) that an older candidate of their particle lies near: a possible second
        track of one landmark (``survival_duplicate``). Versions of one label are never each other's duplicates.

        Older: a smaller label (born at an earlier step, or at the same step from an earlier measurement), of
        existence (its label's, summed over its versions among the candidates; exist (P, A)) at least
        ``DUPLICATE_OF`` (0.99).

        Near, point features: one measurement cannot tell the two apart, the squared Mahalanobis distance of their
        predicted measurements zhat (P, A, dz) under H P H^T of both (hph (P, A, dz, dz)) plus the model's
        measurement noise R below ``duplicate_gate``. In measurement space, not in the map's: on real logs a track's
        covariance shrinks to centimetres where its duplicates lie a few times farther away, distinct by the tracks'
        covariances but not by any measurement. R is the model's: where measurements carry their own covariances
        (the laser's circle fits) it is the floor added to them, so the gate is stricter there than 'one
        measurement' says. While a new track's covariance is still large, a distinct landmark near a confirmed
        one can be inside the gate for its first steps, and takes survival_duplicate then.

        Near, planes (the plane metric, :meth:`slam_runtime.features.FeatureModel.plane_gap`): the normals of the
        predicted planes within ``duplicate_sigmas`` x sqrt(2) x sigma_n and their offsets within as many sigma_d,
        sigma_n and sigma_d the measurement noise R's (the larger of its azimuth and elevation sigmas, and its
        offset sigma; the profile's spread of true detections about their planes, floored). A plane seen in
        pieces gives each piece's track the bias of its own segment's fit (1-25 cm and up to a degree on the
        simulated streets: docs/calibration-payoff.md), while the tracks' own covariances shrink to millimetres: the Mahalanobis gate under H P H^T
        then separates two tracks that no segmentation could, so the plane test ignores the tracks' covariances
        and asks whether two detections of one plane could differ by that much (each within k sigma of the plane,
        so their difference within k sqrt(2) sigma)."""
        same = lab[:, :, None] == lab[:, None, :]  # (P, A, A)
        lab_ex = np.einsum("pij,pj->pi", (same & cand[:, None, :]).astype(np.float64), np.where(cand, exist, 0.0))
        older = cand[:, :, None] & cand[:, None, :] & (lab[:, None, :] < lab[:, :, None]) & (lab_ex >= DUPLICATE_OF)[:, None, :]
        i, j, k = np.nonzero(older)
        near = self._plane_near(zhat[i, j], zhat[i, k])
        if near is None:
            nu = self.feature.innovation(zhat[i, j], zhat[i, k])
            near = quad(inv(hph[i, j] + hph[i, k] + self.r), nu) < self.cfg.duplicate_gate
        out = np.zeros(cand.shape, dtype=bool)
        out[i[near], j[near]] = True
        return out

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
            mu[upd], cov[upd] = ekf_update(self.feature, sp[sp_[upd]], mu[upd], cov[upd], z[jj], rz[jj])
        return sp_, sk, mu, cov, label

    @staticmethod
    def _miss_pd(sl: _Slots, pd_model: np.ndarray, buf: np.ndarray) -> np.ndarray:
        """(P, S) the model's P_D that a miss of each slot weighs, for learning its factor: 0 in the buffer zone (thesis
        eq. 3.21: a miss there tells nothing, as in the costs) and for an empty slot."""
        return np.where(sl.valid & ~(buf & ~sl.birth), np.minimum(pd_model, 1.0 - 1e-9), 0.0)

    def _independent(self, sl: _Slots, sp: np.ndarray, z: np.ndarray, rz: np.ndarray, c: _Costs):
        """The exact Bernoulli update of the held candidates that are not idle births: (particle (K,), candidate
        (K,), existence (K,), mean (K, dx), covariance (K, dx, dx)), the candidates in the order of
        ``np.nonzero(c.held & ~c.idle)`` (slot ``c.act[particle, candidate]``): existence the share of its options in
        which it exists, density the moment match of its missed (prior) and detected (EKF-updated) versions."""
        hp, ha = np.nonzero(c.held & ~c.idle)
        hs = c.act[hp, ha]
        mu0, cov0, lh = sl.mu[hp, hs], sl.cov[hp, hs], c.l_held[hp, ha]
        q, j = np.nonzero(np.isfinite(c.l_det[hp, ha]))
        m_det, c_det = ekf_update(self.feature, sp[hp[q]], mu0[q], cov0[q], z[j], rz[j]) if q.size else (mu0[:0], cov0[:0])
        # the versions: detected by each gated measurement, then missed (the prior)
        r, mean, cov = moment_match(
            np.concatenate([q, np.arange(hp.size)]), np.exp(np.concatenate([c.l_det[hp[q], ha[q], j] - lh[q], c.l_miss[hp, ha] - lh])),
            np.concatenate([m_det, mu0]), np.concatenate([c_det, cov0]), hp.size,
        )
        return hp, ha, np.minimum(r, 1.0), mean, cov

    def _births(self, sp: np.ndarray, z: np.ndarray, rz: np.ndarray, explained: np.ndarray, piece: np.ndarray | None = None) -> Births:
        """Birth tracks for the next step from this step's measurements (eq. 28, adaptive birth); explained (P, M):
        inside some track's gate (birth_associated), piece (P, M): a piece of a confirmed plane (birth_piece)."""
        p, m = sp.shape[0], z.shape[0]
        d = self.feature.dim_x
        if m == 0:
            return Births.empty(p, d)
        pos, cov = birth_gaussians(self.feature, sp, z, rz, 1e-6)
        if self.transition is not None:  # the velocity's prior, which G R G^T of the position cannot give
            cov = cov + self.feature.birth_cov
        r = np.where(explained, self.cfg.birth_associated, self.cfg.birth_unassociated)
        if piece is not None:
            r = np.where(piece, np.minimum(r, self.cfg.birth_piece), r)
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
        if self.transition is not None and dt > 0:
            # every Gaussian the maps hold moves: the tracks, GLMB's free tracks, and the births of the next step
            # (born from this step's measurements, at this step's time)
            moved = {}
            for name in ("tracks", "free", "births"):
                part = getattr(maps, name, None)
                if part is not None and part.mu.shape[1]:
                    mu, cov = self.transition.predict(part.mu, part.cov, dt)
                    moved[name] = replace(part, mu=mu, cov=cov)
            maps = replace(maps, **moved)
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
            ident=self._label_identity(t.label) if meas.ident is not None else None,
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

    def _label_identity(self, label: np.ndarray) -> np.ndarray:
        """The identity each label's track reads (that of the measurement it was born from; -1 for an empty slot, a
        run without identities or a label born at a step without them), same shape as ``label``."""
        label = np.asarray(label, dtype=np.int64)
        out = np.full(label.shape, -1, np.int64)
        ok = label >= 0
        n = self._id_n
        if not n or not ok.any():
            return out
        step, m = label_parts(label[ok])
        steps, off = self._id_step[:n], self._id_off[: n + 1]
        at = np.minimum(np.searchsorted(steps, step), steps.size - 1)
        known = (steps[at] == step) & (m < off[at + 1] - off[at])
        got = np.full(step.shape, -1, np.int64)
        got[known] = self._id_flat[off[at[known]] + m[known]]
        out[ok] = got
        return out

    def _begin(self, poses: np.ndarray, meas: Measurements):
        self._frame_ident = meas.ident
        if meas.ident is not None:  # this step's births take these identities
            n = self._id_n
            if n and self._id_step[n - 1] == self.step:  # (the step begun again: its record replaced)
                n -= 1
            ident = np.asarray(meas.ident, np.int64)
            a = int(self._id_off[n])
            self._id_flat = _room(self._id_flat, a + ident.size)
            self._id_flat[a : a + ident.size] = ident
            self._id_step = _room(self._id_step, n + 1)
            self._id_off = _room(self._id_off, n + 2)
            self._id_step[n], self._id_off[n + 1], self._id_n = self.step, a + ident.size, n + 1
        z, rz = self.measurements(meas)
        sp = self.feature.sensor_pose(np.asarray(poses, dtype=np.float64))
        return z, rz, sp, self._log_kappa(z, meas)
