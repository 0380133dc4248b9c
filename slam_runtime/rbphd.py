"""RB-PHD-SLAM (Mullane et al.; Inostroza 2015, ch. 3) with a detector profile's statistics.

Particles carry the trajectory; each carries a Gaussian-mixture PHD of the map
(:mod:`slam_runtime.gm`), all particles processed together:

* map prediction (eqs. 3.8, 3.15-3.16): the previous map plus a birth mixture
  made from the previous step's measurements through the inverse measurement
  model (weight ``birth_weight``);
* map update (eqs. 3.17-3.18): for every particle x component x measurement at
  once, EKF-updated components weighted by
  P_D w q / (kappa(z) + sum_l P_D w_l q_l), plus the missed-detection copies
  (1 - P_D) w. P_D comes from the detection model: through n_p ray-traced
  against the current scan for a laser profile, through the range for a
  detection-level profile, or a constant inside the field of view
  (``pd_mode="constant"``, for comparison). kappa(z) is the profile's clutter
  intensity;
* the buffer zone (eq. 3.21, sec. 6.1): a component whose P_D is uncertain
  (samples across its position give zero and non-zero P_D, or 0 < P_D < 0.5)
  may not lose weight in the update; its missed-detection copy makes up the
  difference;
* particle weights (sec. 3.1.4, eq. 3.13): the multi-feature strategy by
  default, with the empty-set and single-feature strategies as options; the
  measurement likelihood given the chosen features is approximated by a
  Poisson process of intensity kappa(z) + sum_m P_D(m) g(z | m);
* merging and pruning (Vo & Ma), low-variance resampling when the effective
  sample size drops under ``resample_ess`` x particles.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from detectors.model import DetectionModel
from detectors.raytrace import buffer_zone, count_unoccluded, expected_pd, expected_unoccluded
from slam_runtime.gm import GMBatch, _det2, _inv2, _quad, prune_merge
from slam_runtime.measurement import innovation, inverse, predict, sensor_pose


class RBPHDConfig(BaseModel):
    model_config = ConfigDict(extra="forbid")
    particles: int = Field(default=20, ge=1)
    sigma_range: float | None = Field(
        default=None, gt=0.0, description="measurement noise of a landmark's range [m]; default: the profile's measured noise, else 0.1"
    )
    sigma_bearing: float | None = Field(default=None, gt=0.0, description="... and of its bearing [rad]; default: the profile's, else 0.01")
    birth_weight: float = Field(default=0.03, gt=0.0, le=1.0, description="weight of a birth component per unexplained measurement")
    adaptive_birth: bool = Field(default=True, description="scale each birth by the share of its measurement the map left unexplained")
    prune: float = Field(default=1e-3, gt=0.0)
    merge: float = Field(default=4.0, gt=0.0, description="squared Mahalanobis distance for merging")
    cap: int = Field(default=150, ge=1, description="components per particle at most")
    weighting: Literal["multi_feature", "empty_set", "single_feature", "marginal"] = "multi_feature"
    map_threshold: float = Field(default=0.5, gt=0.0, description="a component of this weight or more is a map feature")
    resample_ess: float = Field(default=0.5, gt=0.0, le=1.0)
    pd_mode: Literal["profile", "constant"] = "profile"
    constant_pd: float = Field(default=0.9, gt=0.0, le=1.0, description="P_D inside the field of view in constant mode")
    buffer_zone: bool = True
    descriptor_likelihood: bool = Field(
        default=True, description="weigh each detection by g_x(d) / g_FA(d) of its descriptors (eqs. 2.26, 5.6) when the profile has a Hotelling model"
    )
    buffer_sigmas: float = Field(default=2.0, gt=0.0, description="lateral spread of the buffer-zone samples, in position std")
    landmark_radius: float | None = Field(
        default=None, gt=0.0, description="radius the n_p ray tracer gives map features [m]; default: the profile's typical true radius, else 0.2"
    )
    phase_average: bool = Field(
        default=True, description="P_D from n_p averaged over where the beams fall (detectors.raytrace.expected_unoccluded), not the integer count"
    )


def _spread(sp: np.ndarray, mu: np.ndarray, cov: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Range (P, J) of each component from its particle's sensor, and its position std across
    and along the line of sight (P, J) each."""
    los = mu - sp[:, None, :2]
    rr = np.maximum(np.hypot(los[..., 0], los[..., 1]), 1e-9)
    u = los / rr[..., None]
    perp = np.stack([-u[..., 1], u[..., 0]], axis=-1)
    s_lat = np.sqrt(np.maximum(np.einsum("pji,pjik,pjk->pj", perp, cov, perp), 0.0))
    s_rad = np.sqrt(np.maximum(np.einsum("pji,pjik,pjk->pj", u, cov, u), 0.0))
    return rr, s_lat, s_rad


@dataclass
class StepInfo:
    n_measurements: int
    ess: float
    resampled: bool
    components: float


class RBPHDSlam:
    """The filter. ``predict`` with a motion function, ``update`` with a frame's measurements."""

    def __init__(self, model: DetectionModel, mount: np.ndarray, cfg: RBPHDConfig, rng: np.random.Generator, start: np.ndarray):
        self.model = model
        self.mount = np.asarray(mount, dtype=np.float64)
        self.cfg = cfg
        self.rng = rng
        p = cfg.particles
        self.poses = np.tile(np.asarray(start, dtype=np.float64), (p, 1))
        self.logw = np.full(p, -np.log(p))
        self.map = GMBatch.empty(p, 0)
        self.birth = GMBatch.empty(p, 0)
        # measurement noise: the settings, else what the calibration measured, else a floor for laser
        # circle fits, whose own covariance is added per detection
        noise = model.noise
        sr = cfg.sigma_range if cfg.sigma_range is not None else (noise.range_sigma if noise is not None else 0.1)
        sb = cfg.sigma_bearing if cfg.sigma_bearing is not None else (noise.bearing_sigma if noise is not None else 0.01)
        self.r = np.diag([sr**2, sb**2])
        self.radius = cfg.landmark_radius if cfg.landmark_radius is not None else model.typical_radius()
        self.occlusion_radius = max(self.radius, model.large_radius()) if cfg.phase_average else None
        self.history: list[np.ndarray] = [self.poses.copy()]

    # ------------------------------------------------------------------ motion
    def predict(self, move) -> None:
        """``move(poses (P, 3), rng) -> poses (P, 3)``: one motion-model step for every particle."""
        self.poses = move(self.poses, self.rng)

    # ------------------------------------------------------------------ P_D
    def _pd(self, sp: np.ndarray, mu: np.ndarray, cov: np.ndarray, scan: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
        """P_D (P, J) of every component and whether it is in the buffer zone (P, J)."""
        p, j = mu.shape[:2]
        z, _ = predict(sp[:, None, :], mu)
        inside = self.model.in_fov(z)
        if self.cfg.pd_mode == "constant":
            return np.where(inside, self.cfg.constant_pd, 0.0), np.zeros((p, j), dtype=bool)
        table = self.model.pd_table
        if table.covariate == "range":
            full = table.lookup(z[..., 0])
            pd = np.where(inside, full, 0.0)
            if not self.cfg.buffer_zone:
                return pd, np.zeros((p, j), dtype=bool)
            # the buffer zone of a range-covariate detector is the edge of its field of view: the
            # component's +-buffer_sigmas spread across and along the line of sight is partly in, partly out
            # (a low P_D inside the field of view is real here, so the n_p rule "0 < P_D < 0.5" does not apply)
            rr, s_lat, s_rad = _spread(sp, mu, cov)
            k = self.cfg.buffer_sigmas
            ins = [inside] + [
                self.model.in_fov(np.stack([z[..., 0] + dr * s_rad, z[..., 1] + dl * s_lat / rr], axis=-1))
                for dl, dr in ((-k, 0.0), (k, 0.0), (0.0, -k), (0.0, k))
            ]
            ins = np.stack(ins, axis=-1)
            mixed = ins.any(axis=-1) & ~ins.all(axis=-1)
            return np.where(mixed, full, pd), mixed
        if scan is None:
            raise ValueError("an n_p profile needs the current scan")
        pd_full = np.zeros((p, j))
        buf_full = np.zeros((p, j), dtype=bool)
        jf = int(inside.sum(axis=1).max()) if j else 0
        if jf == 0:
            return pd_full, buf_full
        # ray-trace only what can be seen: each particle's in-view components, moved to the front
        sel = np.argsort(~inside, axis=1, kind="stable")[:, :jf]
        rows = np.arange(p)[:, None]
        mu_v, cov_v, in_v = mu[rows, sel], cov[rows, sel], inside[rows, sel]
        sensor = self.model.sensor
        common = {"range_sigma": float(sensor.range_sigma), "k_sigma": self.model.k_sigma, "range_max": sensor.range_max}
        ang = sensor.angles()
        if self.cfg.buffer_zone:
            # sec. 6.1: samples across the line of sight, spread by the position std
            lat = self.cfg.buffer_sigmas * _spread(sp, mu_v, cov_v)[1]
            pd_v, buf_v = buffer_zone(
                sp, ang, scan, mu_v, self.radius, lat, table.lookup, samples=self.model.buffer_samples,
                phase_average=self.cfg.phase_average, occlusion_radius=self.occlusion_radius, **common,
            )
        elif self.cfg.phase_average:
            n_bar = expected_unoccluded(sp, ang, scan, mu_v, self.radius, occlusion_radius=self.occlusion_radius, **common)
            pd_v, buf_v = expected_pd(n_bar, table.lookup), np.zeros((p, jf), dtype=bool)
        else:
            n_p, _ = count_unoccluded(sp, ang, scan, mu_v, self.radius, **common)
            pd_v, buf_v = table.lookup(n_p), np.zeros((p, jf), dtype=bool)
        pd_full[rows, sel] = np.where(in_v, pd_v, 0.0)
        buf_full[rows, sel] = buf_v & in_v
        return pd_full, buf_full

    # ------------------------------------------------------------------ update
    def update(
        self, z: np.ndarray, scan: np.ndarray | None = None, zcov: np.ndarray | None = None, ratio: np.ndarray | None = None
    ) -> StepInfo:
        """One map update + reweighting with measurements z (M, 2) (range, bearing; sensor frame).

        zcov (M, 2, 2): each measurement's own covariance (the circle fit's), added to
        the floor diag(sigma_range^2, sigma_bearing^2).
        ratio (M,): descriptor likelihood ratio g_x(d) / g_FA(d) of each measurement
        (eq. 5.6); eq. 2.26 then reads as the plain update with clutter kappa(z) / ratio.
        """
        cfg = self.cfg
        z = np.asarray(z, dtype=np.float64).reshape(-1, 2)
        rz = np.broadcast_to(self.r, (z.shape[0], 2, 2)) if zcov is None else np.asarray(zcov).reshape(-1, 2, 2) + self.r
        sp = sensor_pose(self.poses, self.mount)
        prior = self.map.concat(self.birth)  # eq. 3.16: previous map + birth from the previous measurements
        w, mu, cov = prior.w, prior.mu, prior.cov
        p, j = w.shape
        m = z.shape[0]
        pd, buf = self._pd(sp, mu, cov, scan)
        kappa = self.model.clutter_intensity(z) if m else np.zeros(0)
        if ratio is not None and m:
            kappa = kappa / np.maximum(np.asarray(ratio, dtype=np.float64), 1e-300)
        zhat, h = predict(sp[:, None, :], mu)  # (P, J, 2), (P, J, 2, 2)
        hph = h @ cov @ np.swapaxes(h, -1, -2)  # (P, J, 2, 2)
        s = hph[:, :, None] + rz[None, None]  # (P, J, M, 2, 2): each measurement its own noise
        sinv = _inv2(s)
        pht = cov @ np.swapaxes(h, -1, -2)  # (P, J, 2, 2)
        nu = innovation(z[None, None, :, :], zhat[:, :, None, :]) if m else np.zeros((p, j, 0, 2))
        m2 = _quad(sinv, nu[..., 0], nu[..., 1])
        q = np.exp(-0.5 * m2) / (2 * np.pi * np.sqrt(np.maximum(_det2(s), 1e-300)))
        num = (pd * w)[..., None] * q  # (P, J, M)
        den = kappa[None, :] + num.sum(axis=1)  # (P, M)
        w_det = num / np.where(den > 0, den, 1.0)[:, None, :]
        missed = (1.0 - pd) * w
        if cfg.buffer_zone:
            buf[:, self.map.shape[1]:] = False  # the rule protects map features, not this step's birth hypotheses
            gained = w_det.sum(axis=2)
            # eq. 3.21: no weight lost in the buffer zone -- up to one feature's worth: a component
            # whose P_D is underestimated gathers weight 1 / P_D, which the rule would otherwise lock in
            protect = np.minimum(w, 1.0)
            short = buf & (gained + missed < protect)
            missed = np.where(short, protect - gained, missed)
        # EKF-updated components (eqs. 3.17-3.18) only for the (component, measurement) pairs whose
        # weight survives pruning: the rest would be dropped by prune_merge anyway
        keep = (w_det > cfg.prune).reshape(p, j * m)
        k = int(keep.sum(axis=1).max()) if j * m else 0
        pick = np.argsort(~keep, axis=1, kind="stable")[:, :k]  # (P, K) flat (j, m) indices, kept ones first
        jj, mm = np.divmod(pick, max(m, 1))
        rows = np.arange(p)[:, None]
        gain = pht[rows, jj] @ sinv[rows, jj, mm]  # (P, K, 2, 2)
        mu_det = mu[rows, jj] + (gain @ nu[rows, jj, mm][..., None])[..., 0]
        cov_det = cov[rows, jj] - gain @ (h @ cov)[rows, jj]
        w_kept = np.where(np.take_along_axis(keep, pick, axis=1), w_det[rows, jj, mm], 0.0)
        upd = GMBatch(missed, mu, cov).concat(GMBatch(w_kept, mu_det, cov_det))
        pd_upd = np.concatenate([pd, pd[rows, jj]], axis=1)
        if cfg.weighting == "marginal":
            # p(Z | x, Z_1:k-1) when the predicted map is Poisson with intensity v^- (the
            # single-cluster PHD weight): prod_z (kappa + sum_j P_D w_j q_j(z)) / kappa(z) * exp(-sum_j P_D w_j)
            lw = np.log(np.where(kappa > 0, den / np.maximum(kappa, 1e-300), 1.0)).sum(axis=1) if m else np.zeros(p)
            self.logw += lw - (pd * w).sum(axis=1)
        else:
            self.logw += self._log_weight(prior, upd, pd_upd, sp, z, kappa, rz)
        self.map = prune_merge(upd, prune=cfg.prune, merge=cfg.merge, cap=cfg.cap)
        # adaptive birth: a measurement the map already explains gives birth to little
        self.birth = self._birth(sp, z, rz, 1.0 - np.clip(w_det.sum(axis=1), 0.0, 1.0) if cfg.adaptive_birth else None)
        return self._resample(m)

    def _birth(self, sp: np.ndarray, z: np.ndarray, rz: np.ndarray, unexplained: np.ndarray | None = None) -> GMBatch:
        """Birth mixture for the next step from this step's measurements (eq. 3.15).

        unexplained (P, M): the share of each measurement the updated map did not
        take, 1 - sum_j w_det; it scales the birth weight (adaptive birth, as in
        Reuter et al.'s LMB filter), so features seen every step are not re-born
        and merged into themselves.
        """
        p, m = sp.shape[0], z.shape[0]
        if m == 0:
            return GMBatch.empty(p, 0)
        pos, g = inverse(sp[:, None, :], z[None, :, :])  # (P, M, 2), (P, M, 2, 2)
        cov = g @ rz[None] @ np.swapaxes(g, -1, -2) + np.eye(2) * 1e-4
        w = np.full((p, m), self.cfg.birth_weight)
        if unexplained is not None:
            w = w * unexplained
        return GMBatch(w, pos, cov)

    def _log_weight(self, prior: GMBatch, upd: GMBatch, pd_upd: np.ndarray, sp, z, kappa, rz) -> np.ndarray:
        """log of eq. 3.13 under the chosen strategy (particle-independent factors dropped)."""
        cfg = self.cfg
        base = upd.total() - prior.total()
        if cfg.weighting == "empty_set" or upd.shape[1] == 0:
            return base
        if cfg.weighting == "single_feature":
            pick = np.argmax(upd.w, axis=1)[:, None]
        else:
            k = max(1, int((upd.w >= cfg.map_threshold).sum(axis=1).max()))
            pick = np.argsort(-upd.w, axis=1, kind="stable")[:, :k]
        rows = np.arange(upd.shape[0])[:, None]
        chosen = np.take_along_axis(upd.w, pick, axis=1) >= (cfg.map_threshold if cfg.weighting == "multi_feature" else 0.0)
        pts = upd.mu[rows, pick]  # (P, K, 2)
        pd_m = np.where(chosen, pd_upd[rows, pick], 0.0)
        v_minus = prior.density(pts) if prior.shape[1] else np.zeros(pts.shape[:2])
        v_plus = upd.density(pts)
        ratio = np.where(chosen, np.log(np.maximum(v_minus, 1e-300)) - np.log(np.maximum(v_plus, 1e-300)), 0.0).sum(axis=1)
        # log p(Z | M, x) ~ Poisson process of intensity kappa + sum_m P_D g(z | m), relative to clutter alone
        lik = -pd_m.sum(axis=1)
        if z.shape[0]:
            zh, _ = predict(sp[:, None, :], pts)
            nu = innovation(z[None, None, :, :], zh[:, :, None, :])
            rinv = _inv2(rz)  # (M, 2, 2)
            g = np.exp(-0.5 * _quad(rinv[None, None], nu[..., 0], nu[..., 1])) / (2 * np.pi * np.sqrt(_det2(rz)))[None, None]
            lam = (pd_m[..., None] * g).sum(axis=1)  # (P, M)
            lik += np.log1p(lam / np.maximum(kappa[None, :], 1e-300)).sum(axis=1)
        return base + ratio + lik

    def _resample(self, m: int) -> StepInfo:
        lw = self.logw - self.logw.max()
        w = np.exp(lw)
        w /= w.sum()
        self.logw = np.log(np.maximum(w, 1e-300))
        ess = 1.0 / float(np.sum(w * w))
        p = w.size
        resampled = ess < self.cfg.resample_ess * p
        self.history.append(self.poses.copy())
        if resampled:  # low-variance (systematic) resampling
            u = (self.rng.uniform() + np.arange(p)) / p
            idx = np.minimum(np.searchsorted(np.cumsum(w), u), p - 1)
            self.poses = self.poses[idx]
            self.map = self.map.take(idx)
            self.birth = self.birth.take(idx)
            self.history = [hh[idx] for hh in self.history]
            self.logw = np.full(p, -np.log(p))
        return StepInfo(m, ess, bool(resampled), float((self.map.w > 0).sum(axis=1).mean()) if self.map.shape[1] else 0.0)

    # ------------------------------------------------------------------ estimates
    def best(self) -> int:
        return int(np.argmax(self.logw))

    def mean_pose(self) -> np.ndarray:
        """(3,) the particles' weighted mean pose (circular mean of the heading)."""
        w = np.exp(self.logw - self.logw.max())
        w /= w.sum()
        xy = w @ self.poses[:, :2]
        th = np.arctan2(w @ np.sin(self.poses[:, 2]), w @ np.cos(self.poses[:, 2]))
        return np.array([xy[0], xy[1], th])

    def trajectory(self) -> np.ndarray:
        """(T, 3) trajectory of the currently best particle."""
        b = self.best()
        return np.stack([hh[b] for hh in self.history])

    def map_estimate(self) -> tuple[np.ndarray, np.ndarray]:
        """Means (K, 2) and weights (K,) of the best particle's components of weight >= map_threshold."""
        b = self.best()
        keep = self.map.w[b] >= self.cfg.map_threshold
        return self.map.mu[b][keep], self.map.w[b][keep]
