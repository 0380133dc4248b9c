"""The map-filter seam: what every Rao-Blackwellised map filter (RB-PHD, LMB, delta-GLMB) offers.

A map filter holds no particles of its own: it maps the map state of all P
particles (an object with ``take(idx)``), their vehicle poses and one frame's
measurements to the updated map state and the log-likelihood of the
measurements per particle, which the particle loop adds to the log-weights::

    maps = mf.empty(P)
    maps = mf.predict(maps, dt)
    maps, loglik = mf.update(maps, poses, measurements)   # poses (P, 3), loglik (P,)
    maps = maps.take(parent_indices)                     # resampling
    xs, ws = mf.estimate(maps, i)                        # particle i's map estimate

The filter uses a feature model (:mod:`slam_runtime.features`: predict z and H,
inverse for birth, innovation) and the detection model
(:class:`detectors.model.DetectionModel`: P_D, buffer zone, clutter kappa(z),
descriptor likelihoods); it never reads a profile or a file.

Every filter is found through :data:`MAP_FILTERS` (its settings' ``filter.kind``
-> its class): a new filter is a module with a :class:`MapFilter` subclass, its
settings model (``Config``, a pydantic model whose ``kind`` is a one-value
Literal) and one registration line; the settings' union, the command line's
``--filter`` choices and the docs' list follow the table. What a filter can do
beyond the seam is declared on its class (``labelled``, ``proposes_poses``,
``occlusion_default``), never guessed from its kind's name.
"""

from __future__ import annotations

import time
from abc import ABC, abstractmethod
from collections import defaultdict
from contextlib import contextmanager
from typing import Protocol

import numpy as np

from detectors.kinds import Measurements
from profiles.errors import UsageError
from profiles.registry import Registry
from slam_runtime.features import FeatureModel
from slam_runtime.gibbs import detection_costs
from slam_runtime.gm import det, inv, quad
from slam_runtime.proposal import pose_proposal


class MapState(Protocol):
    def take(self, idx: np.ndarray) -> MapState: ...


class Timers:
    """Wall time per stage, accumulated (seconds)."""

    def __init__(self) -> None:
        self.total: dict[str, float] = defaultdict(float)

    @contextmanager
    def __call__(self, stage: str):
        t0 = time.perf_counter()
        try:
            yield
        finally:
            self.total[stage] += time.perf_counter() - t0


class MapFilter(ABC):
    """Base of the map filters; ``timers`` splits their time by stage (P_D, update, weight, merge)."""

    #: the filter's name in results ("RB-PHD")
    name: str = "map filter"
    #: its settings: a pydantic model refusing unknown keys, whose ``kind`` is a one-value Literal (the registry name)
    Config: type
    #: its tracks carry labels: it offers ``labels(maps, i)`` and ``hypotheses(maps)``, and a run records the label history
    labelled: bool = False
    #: it offers ``pose_proposal`` (the optimal proposal draws poses from it)
    proposes_poses: bool = False
    #: it takes the identities a detector reads (``Measurements.ident``, ``detection.identities``)
    takes_identities: bool = False
    #: the proposal of ``proposal: auto`` for point features ("optimal" where it was measured the better, else "prior")
    proposal_default: str = "prior"
    #: ``detection.occlusion_sigmas`` when the settings give none: "profile" (the profile's k_sigma) or a number of
    #: range sigmas (inf: no return occludes a map feature)
    occlusion_default: float | str = "profile"

    def __init__(self, feature: FeatureModel, detection) -> None:
        self.feature = feature
        self.detection = detection
        self.timers = Timers()
        #: detection.frame_clutter: the filters scale the frame's clutter by :meth:`frame_clutter_scale`, which keeps
        #: the remembered false-alarm counts and frames in _clutter_sums
        self.frame_clutter = bool(getattr(detection, "frame_clutter", False))
        self._clutter_sums = (0.0, 0.0)
        #: steps at which a component cap bound (reported by the runner)
        self.capped_steps = 0

    @abstractmethod
    def empty(self, n: int) -> MapState: ...

    #: (dz, dz) the filter's measurement noise floor (the feature model's, times any inflation); subclasses set it
    r: np.ndarray

    def measurements(self, meas: Measurements) -> tuple[np.ndarray, np.ndarray]:
        """The frame's measurements z (M, dz), sensor frame, and their noise rz (M, dz, dz): the floor ``r``, plus
        each measurement's own covariance when the source gives one."""
        dz = self.feature.dim_z
        z = np.asarray(meas.z, dtype=np.float64).reshape(-1, dz)
        m = z.shape[0]
        rz = np.broadcast_to(self.r, (m, dz, dz)) if meas.cov is None else np.asarray(meas.cov, dtype=np.float64).reshape(m, dz, dz) + self.r
        if meas.ident is not None and np.shape(meas.ident) != (m,):
            raise UsageError(f"measurements: {np.size(meas.ident)} identities for {m} measurements (one each)")
        return z, rz

    def clutter(self, z: np.ndarray, meas: Measurements) -> np.ndarray:
        """(M,) kappa(z) of each measurement: the profile's clutter intensity, divided by the descriptor likelihood
        ratio when the source gives one (eq. 2.26 with eq. 5.6)."""
        if z.shape[0] == 0:
            return np.zeros(0)
        kappa = np.asarray(self.detection.clutter_intensity(z), dtype=np.float64)
        if meas.ratio is not None:
            kappa = kappa / np.maximum(np.asarray(meas.ratio, dtype=np.float64), 1e-300)
        return kappa

    def frame_clutter_scale(self, m: int, expected: float) -> float:
        """lambda_k / lambda: this frame's clutter rate over the profile's mean when ``detection.frame_clutter`` is on
        and the profile's clutter counts are negative binomial, else 1.

        The negative binomial of the profile (mean ``rate``, variance rate + rate^2 / ``size``) is a Poisson count
        whose rate is gamma(shape size, rate size / lambda) from frame to frame. Given c false alarms in the frame, the
        rate's posterior mean is (size + c) / (size / lambda + 1); c is taken as the frame's m measurements less the
        map's expected detections ``expected`` (sum of P_D times existence or weight, averaged over particles), at
        least 0. The filter then scores the frame's measurements against kappa(z) lambda_k / lambda: a frame with
        many unexplained measurements takes more of them for clutter, one with few fewer.

        With ``detection.clutter_memory`` T > 0 the counts of earlier frames count too, each frame's with the weight
        (1 - 1/T) per frame since (the rate drifting from place to place): (size + sum w c) / (size / lambda + sum w),
        the run's own clutter rate where the place changes slowly. Called once per frame (it keeps the sums). The
        scale is the particles' plain mean, and the log evidence of a run leaves out the clutter's per-frame
        constant: compare runs by evidence only with the same setting. RB-PHD, LMB and delta-GLMB take it
        (MH-FastSLAM refuses it)."""
        cl = self.detection.clutter
        if not self.frame_clutter or cl.count_model != "negative_binomial" or not cl.size or cl.rate <= 0.0:
            return 1.0
        c = max(float(m) - float(expected), 0.0)
        keep = 1.0 - 1.0 / max(float(self.detection.clutter_memory), 1.0)  # 0: this frame only
        a, b = self._clutter_sums
        a, b = keep * a + c, keep * b + 1.0
        self._clutter_sums = (a, b)
        return (cl.size + a) / (cl.size / cl.rate + b) / cl.rate

    @staticmethod
    def expected_detections(pd: np.ndarray, weight: np.ndarray, valid: np.ndarray | None = None) -> float:
        """The map's expected detections in this frame, the :meth:`frame_clutter_scale` argument: the sum of P_D times
        existence (or PHD weight) over the (valid) features of each particle (P, J), averaged over particles."""
        if pd.shape[0] == 0:
            return 0.0
        e = pd * weight
        return float(np.mean(np.sum(e if valid is None else np.where(valid, e, 0.0), axis=1)))

    def _det_costs(self, zhat, hph, z, rz, own_cov: bool, l_base, log_kappa, in_a, pd_pos, compiled: bool = True):
        """log eta of the detections (P, A, M) (-inf outside the gate or where P_D = 0) and the gate (P, A, M) of the
        active candidates: predicted measurements zhat (P, A, dz), H P H^T (P, A, dz, dz), measurements z (M, dz),
        their own covariances rz (M, dz, dz) when own_cov (else the model's R), l_base (P, A) log(r P_S P_D).

        The labelled filters' and MH-FastSLAM's association scores. Point landmarks (dz = 2) take :func:`slam_runtime.gibbs.detection_costs`, the same arithmetic fused in one
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

    def _proposal(
        self, xbar: np.ndarray, q: np.ndarray, meas: Measurements, mu: np.ndarray, cov: np.ndarray, ex: np.ndarray,
        valid: np.ndarray | None, *, gate: float, share: float, iterations: int, pd_factor: np.ndarray | None = None,
        ident: np.ndarray | None = None,
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """What the filters' ``pose_proposal`` share: the features mu (P, J, dx), cov (P, J, dx, dx) of weight or
        existence ex (P, J) (valid (P, J): the slots that hold one; None: every slot) weighted by their P_D from the
        motion prior's poses (times pd_factor (P, J) where given: a track's learned factor on P_D), and the frame's
        measurements, noise and kappa, handed to :func:`slam_runtime.proposal.pose_proposal`; ident (P, J) the
        features' identities when the run takes them (``meas.ident``; None: features without, which any measurement
        may have made)."""
        z, rz = self.measurements(meas)
        if z.shape[0] == 0 or mu.shape[1] == 0:
            return xbar, q, np.zeros(xbar.shape[0], dtype=np.int64)
        pd, _ = self.detection.pd_features(self.feature.sensor_pose(xbar), mu, cov, meas, ex)
        if pd_factor is not None:
            pd = pd * pd_factor
        seen = pd > 0 if valid is None else (pd > 0) & valid
        return pose_proposal(
            self.feature, xbar, q, z, rz, self.r if meas.cov is None else None, mu, cov, np.where(seen, ex * np.minimum(pd, 1.0), 0.0),
            self.clutter(z, meas), gate=gate, share=share, iterations=iterations,
            ident=ident if meas.ident is not None else None, ident_z=meas.ident,
        )

    def bind(self, rng: np.random.Generator, groups: int = 1) -> None:
        """Receive the run's generator (the particle loop calls this); filters that sample (the Gibbs
        sampler of the labelled filters) draw from it, the others ignore it. ``groups``: the particles come in
        this many equal contiguous islands, independent filters whose draws must not be shared."""

    def predict(self, maps: MapState, dt: float) -> MapState:
        return maps

    def record(self, maps: MapState, logw: np.ndarray) -> None:
        """Receive the particles' log-weights after every update (the particle loop calls this); the labelled
        filters' map estimate averages the particles' weighted states, the others ignore it."""

    @abstractmethod
    def update(self, maps: MapState, poses: np.ndarray, meas: Measurements) -> tuple[MapState, np.ndarray]: ...

    @abstractmethod
    def estimate(self, maps: MapState, i: int) -> tuple[np.ndarray, np.ndarray]:
        """Particle i's map: feature states (K, dx) and their weights or existence probabilities (K,)."""

    def components(self, maps: MapState, i: int) -> tuple[np.ndarray, np.ndarray]:
        """Particle i's whole map: every component's state (K, dx) and weight (K,), however light."""
        return self.estimate(maps, i)

    @abstractmethod
    def size(self, maps: MapState) -> np.ndarray:
        """(P,) components (or tracks) per particle."""


#: The map filters by their settings' ``filter.kind``, in the order the settings' union lists them.
MAP_FILTERS: Registry[type[MapFilter]] = Registry("map filter", builtins=("slam_runtime.rbphd", "slam_runtime.lmb", "slam_runtime.glmb", "slam_runtime.fastslam"))
