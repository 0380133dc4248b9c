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

import numpy as np

from slam_runtime.mapfilter import MapFilter, Measurements
from slam_runtime.particles import RESAMPLERS, ParticleHistory, ess, normalise_log
from slam_runtime.vehicle import VehicleModel


@dataclass
class StepInfo:
    n_measurements: int
    ess: float
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
    ) -> None:
        self.vehicle = vehicle
        self.mf = mapfilter
        self.rng = rng
        self.resample = RESAMPLERS[resampler]
        self.resample_ess = resample_ess
        self.resample_every = resample_every
        self.x = vehicle.initial(np.asarray(start, dtype=np.float64), n)
        self.logw = np.full(n, -np.log(n))
        # log p(Z_1:k) up to the filter's constant (log of the clutter-only likelihood): the sum over steps of
        # the log normaliser of the weights (the sequential Monte Carlo estimate of the marginal likelihood);
        # a criterion for settings that needs no ground truth
        self.log_evidence = 0.0
        if hasattr(mapfilter, "bind"):
            mapfilter.bind(rng)  # filters that sample draw from the run's generator
        self.maps = mapfilter.empty(n)
        self.history = ParticleHistory(self.x)
        self._pending = np.arange(n, dtype=np.int32)  # parents of the next history row
        self._since = 0
        self._heaviest: int | None = None  # after a resampling: a copy of the particle that was heaviest before it
        self.time = {"predict": 0.0, "resample": 0.0}
        # the optimal proposal needs a planar-pose vehicle and a map filter that offers it
        self.proposal = proposal if (vehicle.dim == 3 and hasattr(mapfilter, "pose_proposal")) else "prior"
        self._prior: tuple[np.ndarray, np.ndarray] | None = None

    @property
    def n(self) -> int:
        return self.x.shape[0]

    def predict(self, controls: np.ndarray, dts: np.ndarray) -> None:
        """Move every particle through the control rows (R, k), each held for dts (R,) [s]."""
        t0 = time.perf_counter()
        if self.proposal == "optimal":  # sampled in update(), once the measurements are known
            self._prior = self.vehicle.predict_gaussian(self.x, controls, dts)
            self.x = self._prior[0]
        else:
            for u, dt in zip(controls, dts, strict=True):  # rows of one frame (a handful); each vectorised over particles
                self.x = self.vehicle.sample(self.x, u, float(dt), self.rng)
        self.maps = self.mf.predict(self.maps, float(np.sum(dts)))
        self.time["predict"] += time.perf_counter() - t0

    def update(self, meas: Measurements) -> StepInfo:
        """Record the states of this step, update the maps and weights with ``meas``, resample if needed.

        With the optimal proposal the pose is drawn here from the Gaussian the map filter makes of the
        motion prior and the measurements, and the weight is corrected by prior / proposal."""
        correction = 0.0
        if self._prior is not None:
            t0 = time.perf_counter()
            xbar, q = self._prior
            mean, cov, _ = self.mf.pose_proposal(self.maps, xbar, q, meas)
            chol = np.linalg.cholesky(cov + np.eye(3) * 1e-12)
            x = mean + (chol @ self.rng.standard_normal((self.n, 3, 1)))[..., 0]
            x[:, 2] = np.mod(x[:, 2] + np.pi, 2 * np.pi) - np.pi
            correction = _log_normal(x, xbar, q) - _log_normal(x, mean, cov)
            self.x, self._prior = x, None
            self.time["proposal"] = self.time.get("proposal", 0.0) + time.perf_counter() - t0
        self.history.append(self.x, self._pending)
        self._pending = np.arange(self.n, dtype=np.int32)
        self.maps, loglik = self.mf.update(self.maps, self.vehicle.pose(self.x), meas)
        self.logw, log_norm = normalise_log(self.logw + loglik + correction)
        self.log_evidence += log_norm
        if hasattr(self.mf, "record"):  # the labelled filters' map estimate averages the particles' weighted states
            self.mf.record(self.maps, self.logw)
        t0 = time.perf_counter()
        e = ess(self.logw)
        self._since += 1
        resampled = e < self.resample_ess * self.n and self._since >= self.resample_every
        if resampled:
            w = np.exp(self.logw)
            idx = self.resample(w / w.sum(), self.rng)
            # the weights are uniform after resampling: the estimate stays with the heaviest particle's first copy
            # (systematic, stratified and residual resampling keep every particle of weight >= 1/n, as the heaviest is;
            # a multinomial draw may lose it, and then the argmax of the uniform weights stands)
            copies = np.flatnonzero(idx == int(np.argmax(w)))
            self._heaviest = int(copies[0]) if copies.size else None
            self.x = self.x[idx]
            self.maps = self.maps.take(idx)
            self._pending = idx.astype(np.int32)
            self.logw = np.full(self.n, -np.log(self.n))
            self._since = 0
        dt = time.perf_counter() - t0
        self.time["resample"] += dt
        return StepInfo(len(meas), e, bool(resampled), float(np.mean(self.mf.size(self.maps))), dt * 1e3)

    # ------------------------------------------------------------------ estimates
    def best(self) -> int:
        """The particle whose map and trajectory are the estimate: the heaviest; right after a resampling (uniform
        weights, where the argmax would be particle 0 whatever it holds) a copy of the one that was heaviest."""
        if self._since == 0 and self._heaviest is not None:
            return self._heaviest
        return int(np.argmax(self.logw))

    def weights(self) -> np.ndarray:
        w = np.exp(self.logw - self.logw.max())
        return w / w.sum()

    def mean_pose(self) -> np.ndarray:
        """(3,) the particles' weighted mean planar pose (circular mean of the heading)."""
        w = self.weights()
        pose = self.vehicle.pose(self.x)
        xy = w @ pose[:, :2]
        th = np.arctan2(w @ np.sin(pose[:, 2]), w @ np.cos(pose[:, 2]))
        return np.array([xy[0], xy[1], th])

    def trajectory(self, i: int | None = None) -> np.ndarray:
        """(T, dim) the states of particle ``i``'s ancestors at every recorded step (default: the best)."""
        i = self.best() if i is None else i
        return self.history.trajectory(int(self._pending[i]))

    def map_estimate(self, i: int | None = None) -> tuple[np.ndarray, np.ndarray]:
        return self.mf.estimate(self.maps, self.best() if i is None else i)


def _log_normal(x: np.ndarray, mean: np.ndarray, cov: np.ndarray) -> np.ndarray:
    """log N(x; mean, cov) of planar poses (P, 3) (heading difference wrapped)."""
    d = x - mean
    d[:, 2] = np.mod(d[:, 2] + np.pi, 2 * np.pi) - np.pi
    c = cov + np.eye(3) * 1e-12
    sol = np.linalg.solve(c, d[..., None])[..., 0]
    _, logdet = np.linalg.slogdet(c)
    return -0.5 * (np.einsum("pi,pi->p", d, sol) + logdet + 3 * np.log(2 * np.pi))
