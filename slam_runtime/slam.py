"""The Rao-Blackwellised particle loop shared by every map filter.

Particles carry the vehicle state (a :class:`slam_runtime.vehicle.VehicleModel`
samples it); each carries a map that a :class:`slam_runtime.mapfilter.MapFilter`
predicts and updates for all particles at once and that returns the
measurement log-likelihood per particle, which is added to the log-weights
(thesis eq. 3.13; delta-GLMB paper eq. 25). Resampling (a free function of
:mod:`slam_runtime.particles`) happens when the effective sample size falls
under ``resample_ess`` x P, at most every ``resample_every`` updates; the
history of states and parents is kept in a :class:`ParticleHistory`, so a
resampling step costs the same at step 8,000 as at step 1.

Islands (``islands`` K > 1; Verge, Dubarry, Del Moral & Moulines 2015): the P
particles are K independent filters of P / K particles, each normalising and
resampling its own weights (the map filter updates all particles at once as
before, told the islands by ``bind`` so that a sampling map filter draws each
island's Gibbs uniforms from its own step seed: the islands' draws are
independent, common random numbers hold within an island). After a few
hundred steps of resampling the particles of one filter share one history
for all but the last steps, so its heaviest particle's
trajectory and map are one draw from the smoothing posterior, with that
draw's error; K islands give K such draws, and the estimate averages them
with equal weights: the trajectory (:meth:`RBSlam.trajectory`, the heading's
circular mean; a vehicle state that is not a planar pose, ECT's, is the
reference island's) and, for a labelled map filter, each label of the reference
island's map estimate (the island of the largest evidence) at the mean of
its state in the islands' estimates that hold it (:func:`average_states`;
a label is one landmark in every particle of an island, but in every island
only if each bore the landmark from the same measurement: with
``island_match`` the features no label pairs are paired by position too,
:func:`match_labels`). RB-PHD's map has no labels: its
estimate is the reference island's heaviest particle's, as are the label
history's states (:mod:`slam_runtime.labels` follows :meth:`RBSlam.best`).
A step's ESS is the sum of the islands'; an island whose particles all have
zero weight stops the run, as one filter's would. The log evidence is
the log of the mean of the islands' (each an unbiased estimate of p(Z_1:k)).
``islands: 1`` is the single filter, the same bytes as before.

Example (a filter that only integrates odometry)::

    >>> import numpy as np
    >>> from slam_runtime.vehicle import OdometryIncrement
    >>> from slam_runtime.slam import RBSlam
    >>> class NoMap:  # the smallest map filter: no map, no information
    ...     timers = None
    ...     def empty(self, n): return None
    ...     def predict(self, maps, dt): return maps
    >>> slam = RBSlam(OdometryIncrement(), NoMap(), 4, np.zeros(3), np.random.default_rng(0))
    >>> slam.predict(np.array([[1.0, 0.0, 0.0]]), np.array([1.0]))
    >>> slam.mean_pose().round(1)
    array([1., 0., 0.])
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numba
import numpy as np
from scipy.optimize import linear_sum_assignment

from profiles.errors import UsageError
from slam_runtime.features import RangeBearing, lookup, mean_by_label
from slam_runtime.mapfilter import MapFilter, Measurements
from slam_runtime.particles import RESAMPLERS, ParticleHistory, ess, normalise_log
from slam_runtime.vehicle import VehicleModel


@dataclass
class StepInfo:
    n_measurements: int
    ess: float  # with islands: the sum of the islands' effective sample sizes
    resampled: bool
    components: float
    resample_ms: float  # time of the resampling decision and, when it happened, the resampling


class RBSlam:
    def __init__(
        self,
        vehicle: VehicleModel,
        mapfilter: MapFilter,
        n: int,
        start: np.ndarray,
        rng: np.random.Generator,
        *,
        resampler: str = "systematic",
        resample_ess: float = 0.5,
        resample_every: int = 1,
        proposal: str = "prior",
        islands: int = 1,
        island_match: float | None = None,
    ) -> None:
        if islands < 1 or n % islands:
            raise UsageError(f"islands: {islands} islands cannot share {n} particles equally (particles must be a multiple of islands)")
        self.vehicle = vehicle
        self.mf = mapfilter
        self.rng = rng
        self.resample = RESAMPLERS[resampler]
        self.resample_ess = resample_ess
        self.resample_every = resample_every
        self.x = vehicle.initial(np.asarray(start, dtype=np.float64), n)
        # islands (module docstring): particle k * m + j is particle j of island k; each island's weights are
        # normalised on their own, and each island resamples on its own
        self.islands, self._m = islands, n // islands
        self.island_match = island_match
        self._isl = [slice(k * self._m, (k + 1) * self._m) for k in range(islands)]
        self.logw = np.full(n, -np.log(self._m))
        # log p(Z_1:k) of each island up to the filter's constant (log of the clutter-only likelihood): the sum over
        # steps of the log normaliser of its weights (the sequential Monte Carlo estimate of the marginal likelihood)
        self._evidence = np.zeros(islands)
        mapfilter.bind(rng, islands)  # filters that sample draw from the run's generator, each island its own draws
        self.maps = mapfilter.empty(n)
        self.history = ParticleHistory(self.x)
        self._pending = np.arange(n, dtype=np.int32)  # parents of the next history row
        self._since = np.zeros(islands, np.int64)
        # per island, after a resampling: a copy of the particle that was heaviest before it (-1: none)
        self._heaviest = np.full(islands, -1, np.int64)
        self.time = {"predict": 0.0, "resample": 0.0}
        self.proposal = resolve_proposal(proposal, vehicle, mapfilter)
        if vehicle.adaptive and self.proposal != "optimal":
            raise UsageError(
                f"the {vehicle.label} model estimates its steering offset in every particle through the optimal proposal's pose "
                "update: set proposal: optimal (with a map filter that offers it), or leave the offset's standard deviation at 0"
            )
        self._prior: tuple[np.ndarray, ...] | None = None

    @property
    def n(self) -> int:
        return self.x.shape[0]

    @property
    def log_evidence(self) -> float:
        """log p(Z_1:k) up to the filter's constant: a criterion for settings that needs no ground truth. With
        islands, the log of the mean of the islands' estimates (each is an unbiased estimate of p(Z_1:k))."""
        if self.islands == 1:
            return float(self._evidence[0])
        m = float(np.max(self._evidence))
        return m + float(np.log(np.mean(np.exp(self._evidence - m))))

    def predict(self, controls: np.ndarray, dts: np.ndarray) -> None:
        """Move every particle through the control rows (R, k), each held for dts (R,) [s]."""
        t0 = time.perf_counter()
        if self.proposal == "optimal":  # sampled in update(), once the measurements are known
            if self.vehicle.adaptive:  # (states, pose covariance, the pose's covariance with the bias)
                self._prior = self.vehicle.predict_joint(self.x, controls, dts)
            else:
                self._prior = self.vehicle.predict_gaussian(self.x, controls, dts)
            self.x = self._prior[0]
        else:
            for u, dt in zip(controls, dts, strict=True):  # rows of one frame (a handful); each vectorised over particles
                self.x = self.vehicle.sample(self.x, u, float(dt), self.rng)
        self.maps = self.mf.predict(self.maps, float(np.sum(dts)))
        self.time["predict"] += time.perf_counter() - t0

    def place(self, pose: np.ndarray) -> None:
        """Every particle at ``pose`` (x, y, heading) for this step, in place of the motion's or the proposal's draw:
        mapping with the path given, to measure a map filter alone (called between :meth:`predict` and :meth:`update`).
        A vehicle that estimates a bias conditions it on the given pose (the one a proposal would have drawn)."""
        if self.vehicle.adaptive and self._prior is not None:
            xbar, q, cross = self._prior
            self.x = self.vehicle.condition(xbar, q, cross, np.broadcast_to(np.asarray(pose, dtype=np.float64)[:3], (self.n, 3)))
        else:
            self.x = self.vehicle.placed(self.x, pose)
        self._prior = None

    def update(self, meas: Measurements) -> StepInfo:
        """Record the states of this step, update the maps and weights with ``meas``, resample if needed.

        With the optimal proposal the pose is drawn here from the Gaussian the map filter makes of the
        motion prior and the measurements, and the weight is corrected by prior / proposal."""
        correction = 0.0
        if self._prior is not None:
            t0 = time.perf_counter()
            xbar, q = self._prior[0], self._prior[1]
            pose = self.vehicle.pose(xbar)
            mean, cov, _ = self.mf.pose_proposal(self.maps, pose, q, meas)
            chol = np.linalg.cholesky(cov + np.eye(3) * 1e-12)
            x = mean + (chol @ self.rng.standard_normal((self.n, 3, 1)))[..., 0]
            x[:, 2] = np.mod(x[:, 2] + np.pi, 2 * np.pi) - np.pi
            correction = _log_normal(x, pose, q) - _log_normal(x, mean, cov)
            if self.vehicle.adaptive:
                x = self.vehicle.condition(xbar, q, self._prior[2], x)
            self.x, self._prior = x, None
            self.time["proposal"] = self.time.get("proposal", 0.0) + time.perf_counter() - t0
        self.history.append(self.x, self._pending)
        self._pending = np.arange(self.n, dtype=np.int32)
        self.maps, loglik = self.mf.update(self.maps, self.vehicle.pose(self.x), meas)
        logw = self.logw + loglik + correction
        for k, sl in enumerate(self._isl):
            try:
                logw[sl], log_norm = normalise_log(logw[sl])
            except FloatingPointError:
                if self.islands == 1:
                    raise
                raise FloatingPointError(f"every particle of island {k} (of {self.islands}) has zero weight") from None
            self._evidence[k] += log_norm
        self.logw = logw
        self.mf.record(self.maps, self.logw)  # (the labelled filters' map estimate averages the particles' weighted states)
        t0 = time.perf_counter()
        e = np.array([ess(self.logw[sl]) for sl in self._isl])
        self._since += 1
        due = (e < self.resample_ess * self._m) & (self._since >= self.resample_every)
        if due.any():
            idx = np.arange(self.n)
            for k in np.flatnonzero(due):
                sl = self._isl[k]
                w = np.exp(self.logw[sl])
                local = self.resample(w / w.sum(), self.rng)
                # the weights are uniform after resampling: the estimate stays with the heaviest particle's first copy
                # (systematic, stratified and residual resampling keep every particle of weight >= 1/m, as the heaviest is;
                # a multinomial draw may lose it, and then the argmax of the uniform weights stands)
                copies = np.flatnonzero(local == int(np.argmax(w)))
                self._heaviest[k] = sl.start + int(copies[0]) if copies.size else -1
                idx[sl] = sl.start + local
                self.logw[sl] = -np.log(self._m)
                self._since[k] = 0
            self.x = self.x[idx]
            self.maps = self.maps.take(idx)
            self._pending = idx.astype(np.int32)
        dt = time.perf_counter() - t0
        self.time["resample"] += dt
        return StepInfo(len(meas), float(e.sum()), bool(due.any()), float(np.mean(self.mf.size(self.maps))), dt * 1e3)

    # ------------------------------------------------------------------ estimates
    def island_best(self, k: int) -> int:
        """Island k's heaviest particle; right after its resampling (uniform weights, where the argmax would be its first
        particle whatever it holds) a copy of the one that was heaviest."""
        if self._since[k] == 0 and self._heaviest[k] >= 0:
            return int(self._heaviest[k])
        sl = self._isl[k]
        return sl.start + int(np.argmax(self.logw[sl]))

    def best(self) -> int:
        """The particle whose map and trajectory are the estimate: the heaviest (of the island of the largest evidence;
        with islands the estimate then averages every island's heaviest: :meth:`trajectory`, :meth:`map_estimate`)."""
        return self.island_best(int(np.argmax(self._evidence)))

    def weights(self) -> np.ndarray:
        """(P,) the particles' normalised weights (islands weigh alike)."""
        if self.islands == 1:
            w = np.exp(self.logw - self.logw.max())
            return w / w.sum()
        return np.exp(self.logw) / self.islands

    def mean_pose(self) -> np.ndarray:
        """(3,) the particles' weighted mean planar pose (circular mean of the heading)."""
        return _mean_pose(self.vehicle.pose(self.x), self.weights())

    def trajectory(self, i: int | None = None) -> np.ndarray:
        """(T, dim) the states of particle ``i``'s ancestors at every recorded step (default: the best; with islands
        and a planar-pose vehicle, (T, 3) the mean pose of the islands' heaviest particles' histories)."""
        if i is None and self.islands > 1 and self.vehicle.planar:
            tr = np.stack([self.vehicle.pose(self.history.trajectory(int(self._pending[self.island_best(k)]))) for k in range(self.islands)])
            # once per call, at the end of a run: a loop over the steps (one batched product differs in the last bit)
            w = np.full(self.islands, 1.0 / self.islands)
            return np.stack([_mean_pose(tr[:, t], w) for t in range(tr.shape[1])])
        i = self.best() if i is None else i
        return self.history.trajectory(int(self._pending[i]))

    def map_estimate(self, i: int | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Particle i's map estimate (states, weights); default: the best particle's, and with islands and a labelled
        filter each of its labels at the mean of its state in the islands' heaviest particles' estimates that hold it."""
        if i is not None or self.islands == 1 or not self.mf.labelled:
            return self.mf.estimate(self.maps, self.best() if i is None else i)
        ref = self.best()
        lab, x, r = self.mf.labels(self.maps, ref)
        others = [self.mf.labels(self.maps, b)[:2] for b in map(self.island_best, range(self.islands)) if b != ref]
        if self.island_match is not None and isinstance(self.mf.feature, RangeBearing):
            others = [(match_labels(self.mf.feature, lab, x, ol, ox, self.island_match), ox) for ol, ox in others]
        return average_states(self.mf.feature, lab, x, others), r


def resolve_proposal(proposal: str, vehicle: VehicleModel, mapfilter: MapFilter) -> str:
    """The proposal a run draws its poses from: the optimal one needs a planar-pose vehicle and a map filter that offers
    it ("prior" otherwise); "auto" is the map filter's ``proposal_default`` for point (range-bearing) features, the
    prior for others."""
    if not (vehicle.planar and getattr(mapfilter, "proposes_poses", False)):
        return "prior"
    if proposal == "auto":
        return getattr(mapfilter, "proposal_default", "prior") if isinstance(getattr(mapfilter, "feature", None), RangeBearing) else "prior"
    return proposal


def _mean_pose(pose: np.ndarray, w: np.ndarray) -> np.ndarray:
    """(3,) the w-weighted mean of planar poses (P, 3), the heading's circular mean."""
    xy = w @ pose[:, :2]
    th = np.arctan2(w @ np.sin(pose[:, 2]), w @ np.cos(pose[:, 2]))
    return np.array([xy[0], xy[1], th])


def average_states(feature, label: np.ndarray, x: np.ndarray, others: list[tuple[np.ndarray, np.ndarray]]) -> np.ndarray:
    """x (K, dx) of the labels (K,), each averaged with the states of the same label in ``others`` (labels, states)
    that hold it, with equal weights (:func:`slam_runtime.features.mean_by_label`: angular components about x)."""
    uniq, mean = mean_by_label(
        np.concatenate([label, *(o[0] for o in others)]), np.concatenate([x, *(o[1] for o in others)]),
        np.ones(label.size + sum(o[0].size for o in others)), feature.state_angular,
    )
    return mean[lookup(uniq, label)[0]]


def match_labels(feature, label: np.ndarray, x: np.ndarray, other_label: np.ndarray, other_x: np.ndarray, gate: float) -> np.ndarray:
    """``other_label`` (J,) with each feature whose label is not among the reference's ``label`` (K,) given the label of
    the reference feature it pairs with: the features of either side that no label pairs are paired one to one by the
    assignment of least total cost, a pair costing the distance between the positions (``feature.position``) and a
    feature left unpaired ``gate`` [m] (OSPA's cut-off: pairs ``gate`` or more apart are not made; their labels stay).
    A label is one landmark in every particle of an island, but in every island only if each bore the landmark from
    the same measurement; under heavy clutter they often do not (docs/results/labelled-paper.md, islands)."""
    out = np.array(other_label, dtype=np.int64, copy=True)
    free_ref = np.flatnonzero(~np.isin(label, other_label))
    free_oth = np.flatnonzero(~np.isin(other_label, label))
    if free_ref.size == 0 or free_oth.size == 0:
        return out
    d = np.linalg.norm(feature.position(x[free_ref])[:, None, :] - feature.position(other_x[free_oth])[None, :, :], axis=2)
    i, j = linear_sum_assignment(np.minimum(d, gate))
    ok = d[i, j] < gate
    out[free_oth[j[ok]]] = label[free_ref[i[ok]]]
    return out


def _log_normal(x: np.ndarray, mean: np.ndarray, cov: np.ndarray) -> np.ndarray:
    """log N(x; mean, cov) of planar poses (P, 3) (heading difference wrapped), covariances (P, 3, 3)."""
    return _log_normal3(np.ascontiguousarray(x, dtype=np.float64), np.ascontiguousarray(mean, dtype=np.float64), np.ascontiguousarray(cov, dtype=np.float64))


@numba.njit(cache=True, nogil=True)
def _log_normal3(x, mean, cov):  # pragma: no cover - compiled
    """:func:`_log_normal` per particle: the Cholesky factor of cov + 1e-12 I, d^T C^-1 d by forward substitution,
    log det C = 2 sum log diag L."""
    p = x.shape[0]
    out = np.empty(p)
    ln2pi3 = 3.0 * np.log(2.0 * np.pi)
    lo = np.zeros((3, 3))
    d = np.empty(3)
    y = np.empty(3)
    for i in range(p):
        for a in range(3):
            d[a] = x[i, a] - mean[i, a]
        d[2] = np.mod(d[2] + np.pi, 2.0 * np.pi) - np.pi
        for a in range(3):
            for b in range(a + 1):
                acc = cov[i, a, b] + (1e-12 if a == b else 0.0)
                for k in range(b):
                    acc -= lo[a, k] * lo[b, k]
                if a == b:
                    lo[a, a] = np.sqrt(max(acc, 1e-300))
                else:
                    lo[a, b] = acc / lo[b, b]
        quad, logdet = 0.0, 0.0
        for a in range(3):
            acc = d[a]
            for k in range(a):
                acc -= lo[a, k] * y[k]
            y[a] = acc / lo[a, a]
            quad += y[a] * y[a]
            logdet += 2.0 * np.log(lo[a, a])
        out[i] = -0.5 * (quad + logdet + ln2pi3)
    return out
