"""MH-FastSLAM's map filter: the vector-based baseline the thesis compares RB-PHD-SLAM against (Inostroza 2015,
sec. 2.1 and ch. 7; Montemerlo et al. 2002; Nieto, Guivant, Nebot & Thrun 2003).

Each particle's map is a list of landmarks, each an EKF (mean, covariance; eq. 2.13: independent given the
trajectory) with the log-odds of its existence; a particle holds up to ``hypotheses`` such maps, one per data
association hypothesis it keeps (MH-FastSLAM: where several associations are plausible the particle keeps one
map for each, as the C++ RFS-SLAM library's ``FastSLAM`` splits the particle, and the weights sort them out
later). All particles' maps are held together, padded: landmarks (P, H, L), hypotheses (P, H).

One step (:meth:`MHFastSLAM.update`), for every hypothesis h of every particle at once:

* the landmarks the sensor can see: P_D > 0 or in the buffer zone, from the detection model
  (:meth:`detectors.model.DetectionModel.pd_features`; thesis eq. 3.21: a landmark in the buffer zone is not
  penalised when missed); their existence r = 1 / (1 + exp(-l)), l the log-odds;
* association scores (the maximum-likelihood association of FastSLAM with the profile's detection statistics in
  place of a fixed new-feature likelihood): landmark a taking measurement j against a missed and j clutter,

      s(a, j) = log(r_a P_D,a g(z_j | a) / kappa(z_j)) - log(1 - r_a P_D,a),

  g the EKF's predicted measurement density (innovation covariance H P H^T + R), kappa(z) the profile's clutter
  intensity (divided by the descriptor likelihood ratio where the source gives one, eq. 2.26 with 5.6); a pair is
  admissible inside the squared Mahalanobis ``gate`` and when s > 0 (the measurement is likelier the landmark's
  than clutter: the gate the profile's P_D and clutter set). A landmark in the buffer zone pays no miss
  (its 1 - r P_D is 1);
* the k best associations of each hypothesis (:mod:`slam_runtime.kbest`: Murty's method, k = ``hypotheses``,
  those within ``max_loglik_diff`` of the best; the C++ library's maxNDataAssocHypotheses = 3 and
  maxDataAssocLogLikelihoodDiff = 3); child c of hypothesis h has the log weight

      log w_h + sum_{a in view} log(1 - r_a P_D,a) + (the sum of its pairs' scores),

  the log of p(Z, association | map h, pose) over the all-clutter likelihood prod_j kappa(z_j), which every
  particle shares. The particle's measurement log-likelihood (what the particle loop adds to its log-weight) is
  the log of the sum over all children; the ``hypotheses`` heaviest children within ``max_loglik_diff`` of the
  heaviest are kept as the particle's new hypotheses, their weights normalised;
* each child's landmarks: an assigned landmark is EKF-updated (FastSLAM eq. 2.13's per-landmark EKF) and its
  log-odds raised by log(1 - P_D + P_D g(z) / kappa(z)) (the measurement was its detection or, the landmark
  missed, a false alarm; the C++ library's p_exist_given_Z with the profile's clutter in place of the scan's
  expected false-alarm share); a landmark in view and missed takes log(1 - P_D) (0 in the buffer zone, and
  none once its log-odds pass ``lock_logodds``: a landmark seen often enough is permanent, the library's
  landmarkLockWeight = 10); landmarks out of view are unchanged;
* map management: landmarks whose log-odds fall below ``prune_logodds`` are removed (the library's
  mapExistencePruneThreshold; -5 in its mhfastslam2dSim.xml); every measurement a child left unassigned starts
  a landmark by the inverse measurement model with the log-odds of ``existence_prior`` (the library's
  landmarkExistencePrior, 0.5: log-odds 0), unless it lies in the gate of a landmark in the buffer zone to which
  the detection model gives P_D 0 (just beyond a range table's edge: the measurement may be that landmark's, and
  a landmark started from it would duplicate it);
* hypotheses of a particle that hold the same landmarks, each within squared Mahalanobis distance ``merge`` of the
  other's, are one map and merge (weights summed). Without it, hypotheses that differ only in an association
  made long ago (two close landmarks' measurements swapped once) keep their slots, and the step's cost, for good.

The map estimate of particle i: its heaviest hypothesis's landmarks of existence above ``map_threshold`` (0.5:
likelier there than not; a newborn at the prior 0.5 is not yet). The pose proposal (``proposal: optimal``,
FastSLAM 2.0) takes each particle's heaviest hypothesis's landmarks.

Differences from the C++ library, each for the seam's sake: hypotheses live inside a particle (the particle
count stays fixed; the library grows it up to 3 P and resamples back) and a particle's weight sums its
children's; the association and the weight use the profile's P_D and clutter intensity (the library scores
associated pairs by their Gaussian log-likelihood floored at -10 and ignores misses and clutter in the weight);
no landmark-candidate list (the library's default count threshold of 1 makes every unassigned measurement a
landmark at once, as here).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numba
import numpy as np
from pydantic import BaseModel, ConfigDict, Field
from scipy.special import expit, logit

from profiles.errors import UsageError
from slam_runtime.features import FeatureModel
from slam_runtime.gm import birth_gaussians, ekf_update, inv, matmul, quad, transpose
from slam_runtime.kbest import kbest_batch
from slam_runtime.mapfilter import MAP_FILTERS, MapFilter, Measurements


class MHFastSLAMConfig(BaseModel):
    """Settings of the MH-FastSLAM map filter (``filter: {kind: mhfastslam, ...}``)."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)
    kind: Literal["mhfastslam"] = "mhfastslam"
    hypotheses: int = Field(
        default=3, ge=1, le=100, description="data-association hypotheses (maps) per particle at most (1: FastSLAM with the single best association)"
    )
    max_loglik_diff: float = Field(
        default=3.0, gt=0.0, description="a hypothesis more than this many nats below the particle's best is not kept"
    )
    gate: float = Field(default=16.0, gt=0.0, description="squared Mahalanobis distance beyond which a measurement cannot update a landmark")
    existence_prior: float = Field(default=0.5, gt=0.0, lt=1.0, description="existence probability of a landmark started from a measurement")
    prune_logodds: float = Field(default=-5.0, lt=0.0, description="landmarks whose existence log-odds fall below this are removed")
    lock_logodds: float = Field(default=10.0, gt=0.0, description="a landmark whose existence log-odds exceed this no longer loses any when missed")
    map_threshold: float = Field(default=0.5, gt=0.0, lt=1.0, description="a landmark of existence probability above this is in the map estimate")
    merge: float = Field(
        default=4.0, ge=0.0, description="hypotheses of a particle whose landmarks lie within this squared Mahalanobis distance merge (0: never)"
    )
    noise_inflation: float = Field(default=1.0, ge=1.0, description="factor on the measurement noise covariance")
    landmark_noise: float = Field(default=0.0, ge=0.0, description="landmark position variance added per second [m^2/s]")


@dataclass
class FastSLAMMaps:
    """The maps of P particles, H hypotheses each, L landmark slots each (padded): mean mu (P, H, L, dx) and
    covariance cov (P, H, L, dx, dx) world frame, existence log-odds lo (P, H, L) (-inf: an empty slot), and the
    hypotheses' normalised log weights logw (P, H) (-inf: an empty hypothesis)."""

    mu: np.ndarray
    cov: np.ndarray
    lo: np.ndarray
    logw: np.ndarray

    def take(self, idx: np.ndarray) -> FastSLAMMaps:
        return FastSLAMMaps(self.mu[idx], self.cov[idx], self.lo[idx], self.logw[idx])

    @property
    def valid(self) -> np.ndarray:
        return np.isfinite(self.lo)

    def best(self) -> np.ndarray:
        """(P,) each particle's heaviest hypothesis."""
        return np.argmax(self.logw, axis=1)


def _logsumexp(x: np.ndarray, axis: int) -> np.ndarray:
    """log sum exp along ``axis``; -inf where every entry is -inf."""
    mx = np.max(x, axis=axis, keepdims=True)
    safe = np.where(np.isfinite(mx), mx, 0.0)
    with np.errstate(divide="ignore"):
        return np.squeeze(safe, axis) + np.log(np.sum(np.exp(x - safe), axis=axis))


@numba.njit(cache=True, nogil=True)
def _assemble(mu, cov, lo, crow, cp, cs, h_new, upd, u_mu, u_cov, b_mu, b_cov, born, lo_birth, p):  # pragma: no cover - compiled
    """The kept children's maps (P, h_new, L', ...), left-packed: child c (particle cp[c], hypothesis cs[c]) holds
    its parent row crow[c]'s landmarks of finite new log-odds lo (C, L) in slot order, each its EKF update
    (u_mu, u_cov at row upd[c, l]) where it was detected, then the births of its particle b_mu (P, M, dx),
    b_cov (P, M, dx, dx) of the measurements born (C, M) marks, at log-odds lo_birth. Empty slots: mean 0,
    identity covariance, log-odds -inf. One pass writing only the output (the numpy form copied every map
    several times per step)."""
    nc, l_slots = lo.shape
    d = mu.shape[2]
    m = born.shape[1]
    cnt = np.zeros(nc, np.int64)
    for c in range(nc):
        for l in range(l_slots):
            if np.isfinite(lo[c, l]):
                cnt[c] += 1
        for j in range(m):
            if born[c, j]:
                cnt[c] += 1
    l_new = 0
    for c in range(nc):
        l_new = max(l_new, cnt[c])
    out_mu = np.zeros((p, h_new, l_new, d))
    out_cov = np.zeros((p, h_new, l_new, d, d))
    out_lo = np.full((p, h_new, l_new), -np.inf)
    for a in range(p):
        for h in range(h_new):
            for q in range(l_new):
                for r in range(d):
                    out_cov[a, h, q, r, r] = 1.0
    for c in range(nc):
        a, h, src = cp[c], cs[c], crow[c]
        q = 0
        for l in range(l_slots):
            if not np.isfinite(lo[c, l]):
                continue
            u = upd[c, l]
            for r in range(d):
                out_mu[a, h, q, r] = u_mu[u, r] if u >= 0 else mu[src, l, r]
                for s in range(d):
                    out_cov[a, h, q, r, s] = u_cov[u, r, s] if u >= 0 else cov[src, l, r, s]
            out_lo[a, h, q] = lo[c, l]
            q += 1
        for j in range(m):
            if born[c, j]:
                for r in range(d):
                    out_mu[a, h, q, r] = b_mu[a, j, r]
                    for s in range(d):
                        out_cov[a, h, q, r, s] = b_cov[a, j, r, s]
                out_lo[a, h, q] = lo_birth
                q += 1
    return out_mu, out_cov, out_lo


def _merge_hypotheses(mu, cov, lo, logw, gate: float):
    """Hypotheses of one particle that hold the same landmarks (the same slots filled) each within squared
    Mahalanobis distance ``gate`` of the other's (under the sum of both covariances) are one map: the lighter is
    merged into the heavier, whose weight takes the sum (chains resolved to the heaviest). Returns the maps with the
    merged hypotheses removed and the rest in order of weight. mu (P, H, L, dx), cov (P, H, L, dx, dx), lo
    (P, H, L), logw (P, H) heaviest first."""
    p, h, _ = lo.shape
    v = np.isfinite(lo)
    live = np.isfinite(logw)
    # candidate pairs (lighter i, heavier j) of live hypotheses with the same slots filled; their landmarks compared
    below = np.tril(np.ones((h, h), dtype=bool), -1)[None]
    pp, ii, jj = np.nonzero(live[:, :, None] & live[:, None, :] & below & (v[:, :, None] == v[:, None, :]).all(axis=-1))
    d2 = quad(inv(cov[pp, ii] + cov[pp, jj]), mu[pp, ii] - mu[pp, jj])  # (K, L)
    close = ((d2 <= gate) | ~v[pp, ii]).all(axis=-1)
    dup = np.zeros((p, h, h), dtype=bool)
    dup[pp[close], ii[close], jj[close]] = True
    target = np.where(dup.any(axis=2), np.argmax(dup, axis=2), np.arange(h)[None, :])  # the first heavier duplicate
    for _ in range(h):  # chains: a hypothesis merged into one that is merged itself goes to that one's target
        target = np.take_along_axis(target, target, axis=1)
    rows = np.repeat(np.arange(p), h)
    w = np.exp(np.where(live, logw, -np.inf))
    tot = np.bincount(rows * h + target.ravel(), weights=w.ravel(), minlength=p * h).reshape(p, h)
    root = live & (target == np.arange(h)[None, :])
    with np.errstate(divide="ignore"):
        new_lw = np.where(root, np.log(tot), -np.inf)
    keep = int(root.sum(axis=1).max())
    order = np.argsort(-new_lw, axis=1, kind="stable")[:, :keep]
    pr = np.arange(p)[:, None]
    return mu[pr, order], cov[pr, order], lo[pr, order], new_lw[pr, order]


class MHFastSLAM(MapFilter):
    """MH-FastSLAM map per particle (module docstring)."""

    name = "MH-FastSLAM"
    Config = MHFastSLAMConfig
    proposes_poses = True
    # as the labelled filters: every object the detector fires on is kept as a landmark, so no return occludes one
    occlusion_default = float("inf")

    def __init__(self, feature: FeatureModel, detection, cfg: MHFastSLAMConfig) -> None:
        super().__init__(feature, detection)
        if self.frame_clutter:
            raise UsageError("detection.frame_clutter: MH-FastSLAM scores clutter with the profile's rate; RB-PHD, LMB and delta-GLMB take it")
        self.cfg = cfg
        self.r = feature.r * cfg.noise_inflation

    def empty(self, n: int) -> FastSLAMMaps:
        d = self.feature.dim_x
        return FastSLAMMaps(np.zeros((n, 1, 0, d)), np.zeros((n, 1, 0, d, d)), np.zeros((n, 1, 0)), np.zeros((n, 1)))

    def predict(self, maps: FastSLAMMaps, dt: float) -> FastSLAMMaps:
        q = self.cfg.landmark_noise * max(dt, 0.0)
        if q > 0 and maps.lo.shape[2]:
            maps = FastSLAMMaps(maps.mu, maps.cov + q * np.eye(self.feature.dim_x), maps.lo, maps.logw)
        return maps

    def size(self, maps: FastSLAMMaps) -> np.ndarray:
        """(P,) landmarks per particle, over all its hypotheses."""
        return maps.valid.sum(axis=(1, 2))

    def hypotheses(self, maps: FastSLAMMaps) -> np.ndarray:
        """(P,) hypotheses per particle."""
        return np.isfinite(maps.logw).sum(axis=1)

    def components(self, maps: FastSLAMMaps, i: int) -> tuple[np.ndarray, np.ndarray]:
        """Particle i's heaviest hypothesis: every landmark (K, dx) and its existence probability (K,)."""
        h = int(np.argmax(maps.logw[i]))
        keep = maps.valid[i, h]
        return maps.mu[i, h][keep], expit(maps.lo[i, h][keep])

    def estimate(self, maps: FastSLAMMaps, i: int) -> tuple[np.ndarray, np.ndarray]:
        x, r = self.components(maps, i)
        keep = r > self.cfg.map_threshold
        return x[keep], r[keep]

    def pose_proposal(
        self, maps: FastSLAMMaps, xbar: np.ndarray, q: np.ndarray, meas: Measurements, *, share: float = 0.5, iterations: int = 3
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The optimal importance density's Gaussian approximation (FastSLAM 2.0; :meth:`MapFilter._proposal`) from
        each particle's heaviest hypothesis's landmarks, weighted by their existence."""
        rows = np.arange(maps.logw.shape[0])
        b = maps.best()
        lo = maps.lo[rows, b]
        valid = np.isfinite(lo)
        ex = np.where(valid, expit(np.where(valid, lo, 0.0)), 0.0)
        return self._proposal(xbar, q, meas, maps.mu[rows, b], maps.cov[rows, b], ex, valid, gate=self.cfg.gate, share=share, iterations=iterations)

    # ------------------------------------------------------------------ update
    def _pd(self, sp, mu, cov, meas, r, valid) -> tuple[np.ndarray, np.ndarray]:
        """P_D and buffer flags (N, L) of the landmarks mu (N, L, dx) seen from sensor poses sp (N, 3), from the
        detection model; point landmarks farther than the range limit plus the widest buffer band (the
        detection model's buffer_sigmas times sqrt(sigma_r^2 + trace(cov)), more than its band along the line of
        sight) are not handed to it: they can be neither in view nor in the buffer zone, and a map holds many
        (every landmark ever started, tentative ones too), so the model's cost follows the landmarks near the
        sensor, not the map."""
        det = self.detection
        s = getattr(det, "sensor", None)
        rmax = getattr(s, "range_max", None)
        if self.feature.dim_x != 2 or rmax is None or not mu.shape[1]:
            return det.pd_features(sp, mu, cov, meas, r)
        sr = det.noise_sigmas[0] if hasattr(det, "noise_sigmas") else 0.0
        k = getattr(det, "buffer_sigmas", 0.0) if getattr(det, "buffer", False) else 0.0
        dist = np.hypot(mu[..., 0] - sp[:, None, 0], mu[..., 1] - sp[:, None, 1])
        band = k * np.sqrt(sr * sr + np.maximum(cov[..., 0, 0] + cov[..., 1, 1], 0.0))
        near = valid & (dist - band <= rmax)
        j = int(near.sum(axis=1).max())
        n = mu.shape[0]
        pd, buf = np.zeros(near.shape), np.zeros(near.shape, dtype=bool)
        if j == 0:
            return pd, buf
        sel = np.argsort(~near, axis=1, kind="stable")[:, :j]
        rows = np.arange(n)[:, None]
        pd_s, buf_s = det.pd_features(sp, mu[rows, sel], cov[rows, sel], meas, np.where(near[rows, sel], r[rows, sel], 0.0))
        ok = near[rows, sel]
        pd[rows, sel] = np.where(ok, pd_s, 0.0)
        buf[rows, sel] = buf_s & ok
        return pd, buf

    def _scores(self, sp, mu_a, cov_a, z, rz, own_cov: bool, l_base, log_kappa, in_a, pd_pos):
        """log(r P_D g(z | a) / kappa(z)) of every (row, active landmark, measurement) (-inf outside the gate or
        where P_D = 0), and the gate (in it, active): :meth:`MapFilter._det_costs` of the landmarks' predicted
        measurements."""
        zhat, h = self.feature.predict_sensor(sp[:, None, :], mu_a)
        hph = matmul(h, matmul(cov_a, transpose(h)))
        return self._det_costs(zhat, hph, z, rz, own_cov, l_base, log_kappa, in_a, pd_pos)

    def update(self, maps: FastSLAMMaps, poses: np.ndarray, meas: Measurements) -> tuple[FastSLAMMaps, np.ndarray]:
        cfg, fm, tm = self.cfg, self.feature, self.timers
        z, rz = self.measurements(meas)
        m = z.shape[0]
        log_kappa = np.log(np.maximum(self.clutter(z, meas), 1e-300))
        sp = fm.sensor_pose(np.asarray(poses, dtype=np.float64))
        p, hmax, l_slots = maps.lo.shape
        d = fm.dim_x
        # the live hypotheses, one row each
        rp, rh = np.nonzero(np.isfinite(maps.logw))
        n = rp.size
        if n == p * hmax:  # every hypothesis live: views, not copies
            mu, cov, lo = (a.reshape((n,) + a.shape[2:]) for a in (maps.mu, maps.cov, maps.lo))
        else:
            mu, cov, lo = maps.mu[rp, rh], maps.cov[rp, rh], maps.lo[rp, rh]
        valid = np.isfinite(lo)
        r = np.where(valid, expit(np.where(valid, lo, 0.0)), 0.0)
        spr = sp[rp]
        with tm("pd"):
            pd, buf = self._pd(spr, mu, cov, meas, r, valid)
        with tm("association"):
            view = valid & ((pd > 0) | buf)
            nact = view.sum(axis=1)
            a = int(nact.max()) if n and l_slots else 0
            act = np.argsort(~view, axis=1, kind="stable")[:, :a]
            rows = np.arange(n)[:, None]
            in_a = np.arange(a)[None, :] < nact[:, None]
            pd_a = np.where(in_a, np.minimum(pd[rows, act], 1.0 - 1e-9), 0.0)  # a miss always stays possible
            buf_a = buf[rows, act] & in_a
            r_a = np.where(in_a, r[rows, act], 0.0)
            pd_miss = np.where(buf_a, 0.0, pd_a)
            l_miss = np.log1p(-r_a * pd_miss)  # (n, A): 0 for padding and the buffer zone
            with np.errstate(divide="ignore"):
                l_base = np.log(r_a * pd_a)
            if a and m:
                l_det, gated = self._scores(spr, mu[rows, act], cov[rows, act], z, rz, meas.cov is not None, l_base, log_kappa, in_a, pd_a > 0)
            else:
                l_det, gated = np.full((n, a, m), -np.inf), np.zeros((n, a, m), dtype=bool)
            # a measurement in the gate of a landmark in the buffer zone whose P_D the model puts at 0 (beyond the edge
            # of a range table) may be that landmark's: it starts no landmark (which would duplicate it)
            shadow = (gated & (buf_a & (pd_a == 0.0))[..., None]).any(axis=1)
            score = l_det - l_miss[..., None]
            score = np.where(score > 0.0, score, -np.inf)
            assign, total, _ = kbest_batch(np.ascontiguousarray(score), nact.astype(np.int64), int(cfg.hypotheses), float(cfg.max_loglik_diff))
            # children: (p, parent h, k); their log weights, the particles' likelihoods, the kept children
            k = assign.shape[1]
            child = np.full((p, hmax, k), -np.inf)
            child[rp, rh] = maps.logw[rp, rh][:, None] + l_miss.sum(axis=1)[:, None] + total
            flat = child.reshape(p, hmax * k)
            loglik = _logsumexp(flat, axis=1)
            order = np.argsort(-flat, axis=1, kind="stable")[:, : cfg.hypotheses]
            top = np.take_along_axis(flat, order, axis=1)
            kept = np.isfinite(top) & (top >= top[:, :1] - cfg.max_loglik_diff)
            h_new = int(kept.sum(axis=1).max()) if p else 1
            order, top, kept = order[:, :h_new], top[:, :h_new], kept[:, :h_new]
            norm = _logsumexp(np.where(kept, top, -np.inf), axis=1)
            logw = np.where(kept, top - norm[:, None], -np.inf)
            cp, cs = np.nonzero(kept)
            ph, ck = np.divmod(order[cp, cs], k)
            row_of = np.full((p, hmax), -1, np.int64)
            row_of[rp, rh] = np.arange(n)
            crow = row_of[cp, ph]  # each kept child's parent row
        with tm("update"):
            nc = cp.size
            slot_meas = np.full((nc, l_slots), -1, np.int64)
            ci, ai = np.nonzero(in_a[crow])
            slot_meas[ci, act[crow[ci], ai]] = assign[crow[ci], ck[ci], ai]
            c_lo = lo[crow]
            # detected: EKF update and the existence evidence log(1 - P_D + P_D g / kappa)
            di, dl = np.nonzero(slot_meas >= 0)
            dj = slot_meas[di, dl]
            upd = np.full((nc, l_slots), -1, np.int64)  # each child slot's row in the EKF results (-1: not detected)
            upd[di, dl] = np.arange(di.size)
            u_mu, u_cov = mu[crow[di], dl], cov[crow[di], dl]
            if di.size:
                u_mu, u_cov = ekf_update(fm, spr[crow[di]], u_mu, u_cov, z[dj], rz[dj])
                # (the slot's active index, to read its P_D and score)
                a_of = np.full((n, l_slots), -1, np.int64)
                vr, va = np.nonzero(in_a)
                a_of[vr, act[vr, va]] = va
                da = a_of[crow[di], dl]
                pdd = pd_a[crow[di], da]
                lgk = l_det[crow[di], da, dj] - l_base[crow[di], da]  # log g / kappa
                c_lo[di, dl] += np.logaddexp(np.log1p(-pdd), np.log(pdd) + lgk)
            # missed in view: log(1 - P_D) (0 in the buffer zone), none once locked
            mi, ma = np.nonzero(in_a[crow] & (assign[crow, ck] < 0))
            ms = act[crow[mi], ma]
            miss = np.log1p(-pd_miss[crow[mi], ma])
            c_lo[mi, ms] += np.where(c_lo[mi, ms] > cfg.lock_logodds, 0.0, miss)
            c_lo[c_lo < cfg.prune_logodds] = -np.inf
            # births from the measurements each child left unassigned
            born = np.ones((nc, m), dtype=bool)
            born[di, dj] = False
            born &= ~shadow[crow]
            if m:
                b_mu, b_cov = birth_gaussians(fm, sp, z, rz, 1e-6)
            else:
                b_mu, b_cov = np.zeros((p, 0, d)), np.zeros((p, 0, d, d))
        with tm("merge"):
            out_mu, out_cov, out_lo = _assemble(
                np.ascontiguousarray(mu), np.ascontiguousarray(cov), c_lo, crow, cp, cs, h_new, upd, np.ascontiguousarray(u_mu),
                np.ascontiguousarray(u_cov), np.ascontiguousarray(b_mu), np.ascontiguousarray(b_cov), born, float(logit(cfg.existence_prior)), p,
            )  # fmt: skip
            if cfg.merge > 0 and h_new > 1:
                out_mu, out_cov, out_lo, logw = _merge_hypotheses(out_mu, out_cov, out_lo, logw, cfg.merge)
        return FastSLAMMaps(out_mu, out_cov, out_lo, logw), loglik


MAP_FILTERS.add("mhfastslam", MHFastSLAM)
