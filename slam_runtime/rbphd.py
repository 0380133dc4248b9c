"""RB-PHD-SLAM's map filter (Mullane et al.; Inostroza 2015, ch. 3): a Gaussian-mixture PHD per particle.

All particles are processed together (:mod:`slam_runtime.gm`):

* map prediction (eqs. 3.8, 3.15-3.16): the previous map (with an optional
  landmark process noise) plus a birth mixture made from the previous step's
  measurements through the inverse measurement model, each scaled by the share
  of its measurement the map left unexplained (adaptive birth, as in Reuter et
  al.'s LMB filter);
* map update (eqs. 3.17-3.18): for the features that can be seen (P_D > 0 or
  in the buffer zone) x measurements at once, EKF-updated components weighted by
  P_D w q / (kappa(z) + sum_l P_D w_l q_l) for the pairs inside the gate, plus
  the missed-detection copies (1 - P_D) w. P_D and the buffer zone come from
  the detection model; kappa(z) is the profile's clutter intensity, divided by
  the descriptor likelihood ratio when there is one (eq. 2.26 with eq. 5.6);
* the buffer zone (eq. 3.21): a feature in it may not lose weight when missed,
  up to one feature's worth (a component whose P_D is underestimated gathers
  weight 1 / P_D, which the thesis's rule would otherwise lock in); this step's
  birth hypotheses are exempt;
* ``update_rule: existence`` (off by default): under a low or misjudged P_D the
  PHD's weights are biased (a feature seen more often than P_D says climbs
  towards 1 / P_D, one seen less often loses (1 - P_D) of its weight per miss and
  leaves the map; thesis sec. 3.3: the PHD is forgetful and needs a high P_D).
  With it each component is read as a Bernoulli whose existence is its weight, at
  most ``existence_max``: the shares of eq. 3.18 give the probability rho that it
  made one of the measurements (at most 1), and the missed copy keeps
  (1 - rho) r (1 - P_D) / (1 - r P_D), the existence of a Bernoulli after a miss
  (the multi-Bernoulli update the thesis names as the alternative, sec. 3.4.1);
  merged duplicates are capped at ``existence_max`` again. A component's weight is
  then its existence and the map (weight >= map_threshold) the features likelier
  to exist than not;
* the particle's measurement likelihood (sec. 3.1.4, eq. 3.13): the
  single-cluster ``marginal`` likelihood by default (on rfs-sim and Victoria
  Park as accurate as the multi-feature strategy at a quarter of its cost:
  docs/results/slam.md), the multi-feature strategy (evaluated at every
  feature of weight >= map_threshold; p(Z | M, x) given those features
  approximated by a Poisson process of intensity kappa(z) + sum_m P_D(m) g(z | m)),
  empty-set and single-feature as options;
* Vo & Ma pruning and merging with a cap (reported when it binds).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from slam_runtime.features import FeatureModel, RangeBearing
from slam_runtime.gm import GMBatch, birth_gaussians, det, gaussian, inv, matmul, matvec, prune_merge, quad, transpose
from slam_runtime.mapfilter import MAP_FILTERS, MapFilter, Measurements
from slam_runtime.proposal import identity_match
from slam_runtime.rbphd_kernel import update_points


class RBPHDConfig(BaseModel):
    """Settings of the RB-PHD map filter (``filter: {kind: rbphd, ...}``)."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)
    kind: Literal["rbphd"] = "rbphd"
    noise_inflation: float = Field(default=1.0, ge=1.0, description="factor on the measurement noise covariance")
    birth_weight: float = Field(default=0.03, gt=0.0, le=1.0, description="weight of a birth component per unexplained measurement")
    adaptive_birth: bool = Field(default=True, description="scale each birth by the share of its measurement the map left unexplained")
    prune: float = Field(default=1e-3, gt=0.0, description="components of smaller weight are dropped")
    merge: float = Field(default=4.0, gt=0.0, description="squared Mahalanobis distance for merging")
    merge_rule: Literal["head", "mutual"] = Field(
        default="head", description="merge a component into the heaviest one when it lies in the head's gate (Vo & Ma), or in both gates"
    )
    merge_inflation: float = Field(default=1.0, ge=1.0, description="factor on the spread of the means of a merged group (not on the whole covariance: that compounds)")
    merge_scope: Literal["fresh", "all"] = Field(default="fresh", description="merge only pairs with a component updated or created this step (fresh), or every pair (all)")
    cap: int = Field(
        default=600, ge=1, description="components per particle at most (binds on large maps: 150 bound on Victoria Park)"
    )
    gate: float = Field(default=16.0, gt=0.0, description="squared Mahalanobis distance beyond which a measurement does not update a component")
    landmark_noise: float = Field(default=0.0, ge=0.0, description="landmark position variance added per second [m^2/s]")
    weighting: Literal["multi_feature", "marginal", "empty_set", "single_feature"] = Field(
        default="marginal", description="particle weight: marginal (single-cluster), multi_feature (sec. 3.1.4), empty_set, single_feature"
    )
    map_threshold: float = Field(default=0.5, gt=0.0, description="a component of this weight or more is a map feature")
    update_rule: Literal["phd", "existence"] = Field(
        default="phd",
        description="phd: eqs. 3.17-3.18; existence: a component's weight is its existence probability (low P_D: module docstring)",
    )
    existence_max: float = Field(default=0.99, gt=0.5, lt=1.0, description="update_rule existence: the largest weight of a component")


@dataclass
class PHDMaps:
    """Map state of all particles: the mixtures (P, J) and the birth mixture for the next step."""

    gm: GMBatch
    birth: GMBatch
    #: (P, J) the components of gm that the last merge formed from several (None: all of them count as such)
    merged: np.ndarray | None = None

    def take(self, idx: np.ndarray) -> PHDMaps:
        return PHDMaps(self.gm.take(idx), self.birth.take(idx), None if self.merged is None else self.merged[idx])


class _Innovations:
    """z - zhat for every (particle, component, measurement): (P, J, M, dz), held per axis as contiguous
    (P, J, M) arrays for dz = 2 (the hot path: no interleaved (..., 2) temporaries)."""

    def __init__(self, fm: FeatureModel, z: np.ndarray, zhat: np.ndarray) -> None:
        self.fm = fm
        if z.shape[1] == 2:
            self.parts = [z[None, None, :, c] - zhat[:, :, None, c] for c in range(2)]
            for c in fm.angular:
                a = self.parts[c]
                a -= (2 * np.pi) * np.rint(a / (2 * np.pi))
            self.full = None
        else:
            self.full = fm.innovation(z[None, None], zhat[:, :, None])

    def quad(self, a: np.ndarray) -> np.ndarray:
        """nu^T A nu, A (..., dz, dz) broadcasting against (P, J, M)."""
        if self.full is not None:
            return quad(a, self.full)
        x, y = self.parts
        return a[..., 0, 0] * x * x + 2.0 * a[..., 0, 1] * x * y + a[..., 1, 1] * y * y

    def at(self, rows, jj, mm) -> np.ndarray:
        """(P, K, dz) innovations of the picked pairs."""
        if self.full is not None:
            return self.full[rows, jj, mm]
        return np.stack([c[rows, jj, mm] for c in self.parts], axis=-1)


class RBPHD(MapFilter):
    name = "RB-PHD"
    Config = RBPHDConfig
    proposes_poses = True
    takes_identities = True
    proposal_default = "optimal"  # (proposal: auto) rfs-sim and Victoria Park chose it: docs/results/slam.md
    #: point features under one noise take the compiled update (:mod:`slam_runtime.rbphd_kernel`, the same numbers)
    compiled = True

    def __init__(self, feature: FeatureModel, detection, cfg: RBPHDConfig) -> None:
        super().__init__(feature, detection)
        self.cfg = cfg
        self.r = feature.r * cfg.noise_inflation

    def empty(self, n: int) -> PHDMaps:
        d = self.feature.dim_x
        return PHDMaps(GMBatch.empty(n, 0, d), GMBatch.empty(n, 0, d))

    def predict(self, maps: PHDMaps, dt: float) -> PHDMaps:
        q = self.cfg.landmark_noise * max(dt, 0.0)
        if q > 0 and maps.gm.shape[1]:
            d = self.feature.dim_x
            maps = PHDMaps(GMBatch(maps.gm.w, maps.gm.mu, maps.gm.cov + q * np.eye(d), maps.gm.ident), maps.birth)  # every gate grew
        return maps

    def size(self, maps: PHDMaps) -> np.ndarray:
        return maps.gm.count()

    def components(self, maps: PHDMaps, i: int) -> tuple[np.ndarray, np.ndarray]:
        keep = maps.gm.w[i] > 0
        return maps.gm.mu[i][keep], maps.gm.w[i][keep]

    def estimate(self, maps: PHDMaps, i: int) -> tuple[np.ndarray, np.ndarray]:
        keep = maps.gm.w[i] >= self.cfg.map_threshold
        return maps.gm.mu[i][keep], maps.gm.w[i][keep]

    # ------------------------------------------------------------------ update
    def update(self, maps: PHDMaps, poses: np.ndarray, meas: Measurements) -> tuple[PHDMaps, np.ndarray]:
        cfg, fm, tm = self.cfg, self.feature, self.timers
        z, rz = self.measurements(meas)
        m = z.shape[0]
        sp = fm.sensor_pose(poses)
        n_map = maps.gm.shape[1]
        prior = maps.gm.concat(maps.birth)  # eq. 3.16: previous map + birth from the previous measurements
        w, mu, cov = prior.w, prior.mu, prior.cov
        p = w.shape[0]
        with tm("pd"):
            pd, buf = self.detection.pd_features(sp, mu, cov, meas, w)
            buf[:, n_map:] = False  # the rule protects map features, not this step's birth hypotheses
        kappa = self.clutter(z, meas)
        if self.frame_clutter:
            kappa = kappa * self.frame_clutter_scale(m, self.expected_detections(pd, w))
        with tm("update"):
            # point features under the filter's one noise: every particle in one compiled call
            # (:func:`slam_runtime.rbphd_kernel.update_points`, the numpy pairs' numbers), which holds the PHD's
            # update (eqs. 3.17-3.18) only; the existence rule and every other feature model take the numpy pairs
            if self.compiled and meas.cov is None and meas.ident is None and type(fm) is RangeBearing and cfg.update_rule == "phd":
                missed, w_kept, mu_det, cov_det, j_kept, den, wsum = update_points(
                    w, np.ascontiguousarray(mu), np.ascontiguousarray(cov), np.ascontiguousarray(pd, dtype=np.float64), np.ascontiguousarray(buf),
                    np.ascontiguousarray(sp), z, np.ascontiguousarray(self.r), kappa, float(cfg.gate), float(cfg.prune),
                )
                seen, pd_kept, id_kept = (pd > 0) & (w > 0), np.take_along_axis(pd, j_kept, axis=1), None
            else:
                missed, w_kept, mu_det, cov_det, pd_kept, den, wsum, seen, id_kept = self._pairs(w, mu, cov, pd, buf, sp, z, rz, kappa, meas, None if meas.ident is None else prior.identities())
            upd = GMBatch(missed, mu, cov, prior.ident).concat(GMBatch(w_kept, mu_det, cov_det, id_kept))
            # what this step touched: the map features in view, the ones the last merge formed (their moments
            # changed), this step's births and every detection update; the rest was tested at the last merge
            fresh = None
            if cfg.merge_scope == "fresh" and maps.merged is not None:
                fresh = np.ones(upd.shape, dtype=np.bool_)
                fresh[:, :n_map] = seen[:, :n_map] | maps.merged
        with tm("weight"):
            if cfg.weighting == "marginal":
                # p(Z | x, Z_1:k-1) when the predicted map is Poisson with intensity v^- (the
                # single-cluster PHD weight): prod_z (kappa + sum_j P_D w_j q_j(z)) / kappa(z) * exp(-sum_j P_D w_j)
                lw = np.log(np.where(kappa > 0, den / np.maximum(kappa, 1e-300), 1.0)).sum(axis=1) if m else np.zeros(p)
                loglik = lw - (pd * w).sum(axis=1)
            else:
                loglik = self._log_weight(prior, upd, np.concatenate([pd, pd_kept], axis=1), sp, z, kappa, rz, meas.ident)
        with tm("merge"):
            gm, capped, merged = prune_merge(
                upd, prune=cfg.prune, merge=cfg.merge, cap=cfg.cap, inflate=cfg.merge_inflation, mutual=cfg.merge_rule == "mutual", fresh=fresh, groups=True
            )
            self.capped_steps += int(capped)
            if cfg.update_rule == "existence":  # duplicates of one feature merged: still one feature
                gm = GMBatch(np.minimum(gm.w, cfg.existence_max), gm.mu, gm.cov, gm.ident)
        # adaptive birth: a measurement the map already explains gives birth to little
        unexplained = 1.0 - np.clip(wsum, 0.0, 1.0) if cfg.adaptive_birth else None
        if meas.ident is not None and m and prior.shape[1]:
            # an identity names one landmark: the predicted map's mass of a measurement's identity is the share of
            # its landmark mapped before this measurement, which a birth of the same identity would duplicate (a
            # mapped landmark the measurement misses, the pose lost, is clutter to the map, not a second landmark)
            known = meas.ident >= 0
            same = (prior.identities()[:, :, None] == meas.ident[None, None, :]) & known[None, None, :]
            mass = np.einsum("pj,pjm->pm", prior.w, same)
            left = 1.0 - np.clip(mass, 0.0, 1.0)
            unexplained = left if unexplained is None else np.minimum(unexplained, left)
        birth = self._birth(sp, z, rz, unexplained, meas.ident)
        return PHDMaps(gm, birth, merged), loglik

    def _pairs(self, w, mu, cov, pd, buf, sp, z, rz, kappa, meas, ident=None):
        """The numpy update of the prior mixtures w (P, J), mu (P, J, dx), cov (P, J, dx, dx) (identities ident
        (P, J), given with ``meas.ident``) by the measurements z (M, dz): (missed-detection weights (P, J) with the
        buffer zone's floor (eqs. 3.17, 3.21), the kept detection-updated components' weights (P, K), means and
        covariances (eq. 3.18), their P_D (P, K), kappa + sum_j P_D w_j q_j (P, M), the share of each measurement the
        map took (P, M), the components in view (P, J), the kept components' identities (P, K) or None). With
        ``meas.ident`` a component takes part only in the measurements of its identity
        (:func:`slam_runtime.proposal.identity_match`)."""
        cfg, fm = self.cfg, self.feature
        dz = fm.dim_z
        m = z.shape[0]
        p, j = w.shape
        # only the features that can be seen take part: the others keep their weight (P_D = 0)
        seen = (pd > 0) & (w > 0)
        js = int(seen.sum(axis=1).max()) if j else 0
        sel = np.argsort(~seen, axis=1, kind="stable")[:, :js]  # (P, Js) seen ones first
        rows = np.arange(p)[:, None]
        in_s = seen[rows, sel]
        w_s, mu_s, cov_s, pd_s = np.where(in_s, w[rows, sel], 0.0), mu[rows, sel], cov[rows, sel], np.where(in_s, pd[rows, sel], 0.0)
        zhat, h = fm.predict_sensor(sp[:, None, :], mu_s)  # (P, Js, dz), (P, Js, dz, dx)
        ph = matmul(cov_s, transpose(h))  # P H^T (P, Js, dx, dz)
        hph = matmul(h, ph)
        nu = _Innovations(fm, z, zhat)
        if meas.cov is None:  # one noise for every measurement: S and its inverse per component, not per pair
            s_c = hph + self.r
            sinv_c, det_c = inv(s_c), det(s_c)
            m2 = nu.quad(sinv_c[:, :, None])  # (P, Js, M)
            det_pair = np.broadcast_to(det_c[:, :, None], m2.shape)
        else:  # each measurement its own noise: S per (component, measurement) pair
            s_pair = hph[:, :, None] + rz[None, None]
            sinv_pair, det_pair = inv(s_pair), det(s_pair)
            m2 = nu.quad(sinv_pair)
        gated = m2 <= cfg.gate
        id_s = None
        if meas.ident is not None:
            id_s = ident[rows, sel]
            gated &= identity_match(id_s, meas.ident)
        q = np.zeros(m2.shape)
        q[gated] = gaussian(m2[gated], det_pair[gated], dz)
        existence = cfg.update_rule == "existence"
        if existence:  # each component a Bernoulli of existence r: the weight, capped
            w_s = np.minimum(w_s, cfg.existence_max)
        num = (pd_s * w_s)[..., None] * q  # (P, Js, M)
        den = kappa[None, :] + num.sum(axis=1)  # (P, M)
        w_det = num / np.where(den > 0, den, 1.0)[:, None, :]
        missed = w.copy()
        if existence:
            # the probability rho that the component made one of the measurements (its shares, eq. 3.18, at most 1 in
            # all); otherwise it was missed, and a Bernoulli's existence after a miss is r (1 - P_D) / (1 - r P_D)
            rho = w_det.sum(axis=2)
            w_det = w_det / np.maximum(rho, 1.0)[..., None]
            rho = np.minimum(rho, 1.0)
            missed_s = (1.0 - rho) * w_s * (1.0 - pd_s) / np.maximum(1.0 - w_s * pd_s, 1e-12)
        else:
            missed_s = (1.0 - pd_s) * w_s
        buf_s = buf[rows, sel] & in_s
        gained = w_det.sum(axis=2)
        protect = np.minimum(w_s, 1.0)
        short = buf_s & (gained + missed_s < protect)
        missed_s = np.where(short, protect - gained, missed_s)
        missed[rows, sel] = np.where(in_s, missed_s, missed[rows, sel])
        # EKF-updated components (eqs. 3.17-3.18) only for the pairs whose weight survives pruning
        keep = (w_det > cfg.prune).reshape(p, js * m)
        k = int(keep.sum(axis=1).max()) if js * m else 0
        pick = np.argsort(~keep, axis=1, kind="stable")[:, :k]  # (P, K) flat (j, m) indices, kept ones first
        jj, mm = np.divmod(pick, max(m, 1))
        sinv = sinv_c[rows, jj] if meas.cov is None else sinv_pair[rows, jj, mm]
        gain = matmul(ph[rows, jj], sinv)  # (P, K, dx, dz)
        mu_det = mu_s[rows, jj] + matvec(gain, nu.at(rows, jj, mm))
        cov_det = cov_s[rows, jj] - matmul(gain, transpose(ph[rows, jj]))
        cov_det = 0.5 * (cov_det + transpose(cov_det))
        w_kept = np.where(np.take_along_axis(keep, pick, axis=1), w_det[rows, jj, mm], 0.0)
        id_kept = None if id_s is None else id_s[rows, jj]
        return missed, w_kept, mu_det, cov_det, pd_s[rows, jj], den, w_det.sum(axis=1), seen, id_kept

    def pose_proposal(
        self, maps: PHDMaps, xbar: np.ndarray, q: np.ndarray, meas: Measurements, *, share: float = 0.5, iterations: int = 3
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """A Gaussian approximation of the optimal importance density of each particle's pose (FastSLAM
        2.0; the optimal proposal of PHD-SLAM 2.0/3.0): the motion prior N(xbar, q) (P, 3), (P, 3, 3)
        updated by the frame's measurements that the particle's map explains, each by its likeliest
        feature when that feature takes at least ``share`` of it (the share of the PHD update,
        P_D w q / (kappa + sum)), with an iterated EKF (re-linearised ``iterations`` times).
        The association (gate and shares) uses the innovation covariance with the motion prior's
        uncertainty in it, R + H_m P H_m^T + H_x q H_x^T (FastSLAM 2.0, Montemerlo et al. 2003:
        the data-association covariance); the update itself uses R + H_m P H_m^T.
        Returns the mean (P, 3), covariance (P, 3, 3) and the number of measurements used (P,)."""
        gm = maps.gm
        return self._proposal(xbar, q, meas, gm.mu, gm.cov, gm.w, None, gate=self.cfg.gate, share=share, iterations=iterations, ident=gm.ident)

    def _birth(self, sp: np.ndarray, z: np.ndarray, rz: np.ndarray, unexplained: np.ndarray | None, ident: np.ndarray | None = None) -> GMBatch:
        """Birth mixture for the next step from this step's measurements (eq. 3.15).

        unexplained (P, M): the share of each measurement the updated map did not
        take, 1 - sum_j w_det, and with identities at most the share of the
        landmark its identity names that the predicted map does not hold; it
        scales the birth weight, so features seen every step are not re-born and
        merged into themselves, and a mapped landmark is not born twice. ident
        (M,): the measurements' identities, which their births take (None: no
        identities).
        """
        p, m = sp.shape[0], z.shape[0]
        if m == 0:
            return GMBatch.empty(p, 0, self.feature.dim_x, ident=ident is not None)
        pos, cov = birth_gaussians(self.feature, sp, z, rz, 1e-4)
        w = np.full((p, m), self.cfg.birth_weight)
        if unexplained is not None:
            w = w * unexplained
        return GMBatch(w, pos, cov, None if ident is None else np.broadcast_to(np.asarray(ident, np.int64), (p, m)).copy())

    def _log_weight(self, prior: GMBatch, upd: GMBatch, pd_upd: np.ndarray, sp, z, kappa, rz, ident_z: np.ndarray | None = None) -> np.ndarray:
        """log of eq. 3.13 under the chosen strategy (particle-independent factors dropped); ident_z (M,) the
        measurements' identities (a feature's likelihood counts only for its own identity's)."""
        cfg = self.cfg
        base = upd.total() - prior.total()
        if cfg.weighting == "empty_set" or upd.shape[1] == 0:
            return base
        p = upd.shape[0]
        rows = np.arange(p)[:, None]
        if cfg.weighting == "single_feature":
            pick = np.argmax(upd.w, axis=1)[:, None]
            chosen = np.ones((p, 1), dtype=bool)
        else:
            k = max(1, int((upd.w >= cfg.map_threshold).sum(axis=1).max()))
            pick = np.argsort(-upd.w, axis=1, kind="stable")[:, :k]
            chosen = np.take_along_axis(upd.w, pick, axis=1) >= cfg.map_threshold
        pts = upd.mu[rows, pick]  # (P, K, 2)
        pd_m = np.where(chosen, pd_upd[rows, pick], 0.0)
        v_minus = prior.density(pts) if prior.shape[1] else np.zeros(pts.shape[:2])
        v_plus = upd.density(pts)
        ratio = np.where(chosen, np.log(np.maximum(v_minus, 1e-300)) - np.log(np.maximum(v_plus, 1e-300)), 0.0).sum(axis=1)
        # log p(Z | M, x) ~ a Poisson process of intensity kappa + sum_m P_D g(z | m), relative to clutter alone.
        # Measured against taking each chosen feature as detected at most once (a Bernoulli per feature): on the
        # cluttered park the Poisson form is more forgiving of a P_D that is wrong for one feature (a bush
        # ray-traced as visible), and the calibrated profile's map OSPA and path were clearly better with it
        lik = -pd_m.sum(axis=1)
        if z.shape[0]:
            zh, _ = self.feature.predict_sensor(sp[:, None, :], pts)
            nu = self.feature.innovation(z[None, None, :, :], zh[:, :, None, :])
            m2 = quad(inv(rz)[None, None], nu)
            ok = m2 <= cfg.gate
            if ident_z is not None:
                ok &= identity_match(upd.identities()[rows, pick], ident_z)
            g = np.where(ok, gaussian(m2, det(rz)[None, None], self.feature.dim_z), 0.0)
            lam = (pd_m[..., None] * g).sum(axis=1)  # (P, M)
            lik += np.log1p(lam / np.maximum(kappa[None, :], 1e-300)).sum(axis=1)
        return base + ratio + lik


MAP_FILTERS.add("rbphd", RBPHD)
