"""The batch oracle of a simulated log: what the data allow, given the true associations.

A filter's error on one simulated run mixes two things: how far the data
themselves leave the truth (one noise draw of odometry and measurements), and
how far the filter is from the posterior those data give. The oracle separates
them. With every detection's true landmark known (the simulators label them)
and the simulator's own noise, the full-SLAM posterior over every pose and
landmark is (to first order) Gaussian; :func:`batch_oracle` finds its mode by
Gauss-Newton on the sparse least-squares problem (odometry factors between
consecutive poses, range-bearing factors between a pose and a landmark, the
first pose fixed at the truth as the filters start there) and its covariance
from the information matrix.

What to read off it (``benchmarks/bench_oracle.py`` prints these):

* the MAP's own error (final position, map OSPA): the floor an estimator
  that uses the posterior's mode would reach, the associations given;
* :func:`posterior_samples`: an RB particle filter's estimate is one particle's
  path, and its particles share one ancestor after a few hundred resamplings,
  so its poses behave like one *sample* of the posterior, not its mode; the
  samples' error is what such a filter can be expected to reach. Its map is
  not a sample but the map's conditional mean given that path, distributed
  (to first order) N(m_MAP, Sigma_mm - H_mm^-1), H_mm the landmark block of
  the information matrix (:func:`rb_map_samples`); :func:`map_distance` puts a
  filter's map on that scale;
* :func:`mahalanobis2`: the squared Mahalanobis distance of a filter's final
  position from the MAP under the posterior covariance; for an exact
  posterior sample it is chi-square with 2 degrees of freedom (mean 2), so a
  mean well above 2 over runs says the filter is further from the posterior
  than its own sampling explains.

Two odometry kinds are modelled, those of the simulators: ``increment`` (pose
increments in the vehicle frame, rfs-sim: per-axis sigma) and ``ackermann``
(speed and steering of a rear-axle bicycle, glmb-paper: the controls are
variables with their noise as prior, the poses follow them exactly).

:func:`log_oracle` is the same question for a recorded log whose detections carry identities (UTIAS's
barcodes): a pose at every frame the filters step through, the odometry between frames as the filter's own
vehicle model predicts it (mean and covariance, :meth:`~slam_runtime.vehicle.VehicleModel.predict_gaussian`),
the identities as the associations, a Huber loss on the measurements (a real camera's outliers), the first pose
at the truth as the filters start there. What it reaches with the associations given is the floor a filter
that must find them can be held to.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
from scipy.optimize import linear_sum_assignment
from scipy.sparse.linalg import splu

from detectors.geometry import compose, interpolate_poses
from detectors.sensor_log import SensorLog, wrap_angle
from profiles.errors import DataError, UsageError
from slam_runtime.oracle_factors import (
    Blocks,
    ackermann_factors,
    bicycle,
    increment_factors,
    range_bearing_factors,
    range_bearing_jacobian,
    relative_pose_factors,
)
from slam_runtime.refine import association_weights
from slam_runtime.sources import delayed



@dataclass
class OracleResult:
    stamps: np.ndarray  # (N,) the odometry stamps the poses are at [ns]
    poses: np.ndarray  # (N, 3) MAP vehicle poses, world frame
    landmark_ids: np.ndarray  # (L,)
    landmarks: np.ndarray  # (L, 2) MAP landmark positions, world frame (NaN: never detected)
    final_cov: np.ndarray  # (3, 3) posterior covariance of the last pose
    landmark_cov: np.ndarray  # (2L', 2L') posterior covariance of the detected landmarks (x, y interleaved)
    landmark_cov_given_path: np.ndarray  # (2L', 2L') their covariance given every pose (and control): H_mm^-1
    detected: np.ndarray  # (L,) bool: the landmarks some detection saw
    iterations: int
    converged: bool  # the last Gauss-Newton step moved nothing by more than 1e-10
    cost: float  # half the sum of squared whitened residuals at the last linearisation
    information: sp.csc_matrix  # (V, V) J^T J there: poses (3 N), then controls (2 per row, Ackermann), then landmarks

    def final_error(self, truth: np.ndarray) -> float:
        """Distance of the MAP's last position from the true one (2,) [m]."""
        return float(np.hypot(*(self.poses[-1, :2] - np.asarray(truth)[:2])))


@dataclass
class ClutterOracleResult(OracleResult):
    """The oracle of a log with false alarms, the associations not given (:func:`clutter_oracle`); its ``cost``
    is the odometry's part of the objective."""

    log_likelihood: float  # the objective at the mode: the measurements' mixture log-likelihood minus the odometry's cost
    own_weight: float  # mean responsibility a landmark's detection takes from its own landmark (1: no doubt)
    false_weight: float  # responsibility the false alarms take from the landmarks, per scan
    stray_weight: float  # responsibility landmark detections take from other landmarks than their own, per scan
    information_loss: float  # share of the measurements' Gauss-Newton information the association doubt removes (traces)


@dataclass
class _Problem:
    """A log's full-SLAM problem: its odometry, the landmarks its labelled detections see, the first pose."""

    name: str
    stamps: np.ndarray
    ack: bool
    odo: np.ndarray
    ctrl: np.ndarray  # (N - 1, 2) initial controls (Ackermann) or (0, 2)
    dts: np.ndarray | None
    wb: float
    sig: np.ndarray
    start: np.ndarray
    ids: np.ndarray
    detected: np.ndarray
    k_of: np.ndarray  # labelled detections: odometry index,
    lj: np.ndarray  # index among the detected landmarks,
    zr: np.ndarray  # range,
    zb: np.ndarray  # bearing
    x0: np.ndarray  # initial poses (dead reckoning)
    lm0: np.ndarray  # initial landmarks (each from its first detection)

    @property
    def sizes(self) -> tuple[int, int, int]:
        n = self.stamps.size
        return 3 * n, 2 * self.ctrl.shape[0], 2 * int(self.detected.sum())


def _problem(log: SensorLog, odometry_sigma) -> _Problem:
    if log.odometry is None or log.detections is None or log.landmarks is None:
        raise DataError(f"{log.name}: the oracle needs odometry, detections and landmark truth")
    lab = log.detections.descriptors.get("landmark")
    if lab is None:
        raise DataError(f"{log.name}: the detections carry no 'landmark' label (only simulated logs have one)")
    ref = log.reference.get("ground_truth")
    if ref is None:
        raise DataError(f"{log.name}: no ground truth to fix the first pose")
    kind = log.odometry.kind
    if kind not in ("increment", "ackermann"):
        raise DataError(f"{log.name}: the oracle models increment and ackermann odometry, not {kind!r}")
    sig = np.asarray(odometry_sigma, dtype=np.float64)
    want = 2 if kind == "ackermann" else 3
    if sig.shape != (want,) or not np.all(np.isfinite(sig) & (sig > 0)):
        raise UsageError(
            f"oracle: odometry_sigma of {kind} odometry is {want} positive numbers "
            + ("(speed, steering)" if want == 2 else "(dx, dy, dtheta)")
            + f", not {odometry_sigma!r}"
        )
    stamps = np.asarray(log.odometry.stamp, dtype=np.int64)
    n = stamps.size
    det = log.detections
    lab = np.asarray(lab)
    ids = np.asarray(log.landmarks.ids)
    keep = lab > 0
    k_of = np.searchsorted(stamps, det.frame_stamp[det.frame[keep]])
    if np.any(k_of >= n) or np.any(stamps[np.minimum(k_of, n - 1)] != det.frame_stamp[det.frame[keep]]):
        raise DataError(f"{log.name}: the oracle needs a detection frame at an odometry stamp")
    li = np.minimum(np.searchsorted(ids, lab[keep]), ids.size - 1)
    if np.any(ids[li] != lab[keep]):
        raise DataError(
            f"{log.name}: detection label {int(lab[keep][ids[li] != lab[keep]][0])} is no landmark of the log's truth"
        )
    zr, zb = np.asarray(det.range)[keep], np.asarray(det.bearing)[keep]
    detected = np.zeros(ids.size, dtype=bool)
    detected[li] = True
    col = -np.ones(ids.size, dtype=np.int64)
    col[detected] = np.arange(int(detected.sum()))
    lj = col[li]  # index among the detected landmarks
    nl = int(detected.sum())
    mount = np.array([log.sensor.mount.x, log.sensor.mount.y, log.sensor.mount.theta]) if log.sensor is not None else np.zeros(3)
    if np.any(mount):
        raise DataError(f"{log.name}: the oracle models a sensor at the vehicle's reference point")
    if not ref.stamp[0] <= stamps[0] <= ref.stamp[-1]:
        raise DataError(f"{log.name}: the ground truth does not cover the first odometry stamp")
    start = interpolate_poses(ref.stamp, ref.poses, stamps[:1])[0]
    odo = np.asarray(log.odometry.values, dtype=np.float64)

    # initial guess: dead reckoning and each landmark from its first detection
    x = np.zeros((n, 3))
    x[0] = start
    ack = kind == "ackermann"
    dts, wb = None, 0.0
    if ack:
        if log.vehicle is None or log.vehicle.encoder_offset != 0.0:
            raise DataError(f"{log.name}: the oracle's Ackermann model is the rear-axle bicycle (encoder offset 0)")
        wb = float(log.vehicle.wheelbase)
        dts = np.diff(stamps) * 1e-9
        ctrl = odo[:-1].copy()  # row k drives pose k to pose k + 1 (the last row is held past the end)
        for k in range(n - 1):
            x[k + 1] = bicycle(x[k], ctrl[k], dts[k], wb)
    else:
        ctrl = np.zeros((0, 2))
        for k in range(1, n):
            x[k] = compose(x[k - 1], odo[k])
    first = np.unique(lj, return_index=True)[1]  # each landmark's first detection (lj lists them in frame order)
    lm = _sighted(x[k_of[first]], zr[first], zb[first])
    return _Problem(log.name, stamps, ack, odo, ctrl, dts, wb, sig, start, ids, detected, k_of, lj, zr, zb, x, lm)


def _sighted(poses: np.ndarray, rng: np.ndarray, brg: np.ndarray) -> np.ndarray:
    """(n, 2) the points at range and bearing (n,) from poses (n, 3): landmarks placed by a detection."""
    a = poses[:, 2] + brg
    return np.column_stack([poses[:, 0] + rng * np.cos(a), poses[:, 1] + rng * np.sin(a)])


def _motion_blocks(prob: _Problem, x: np.ndarray, ctrl: np.ndarray) -> Blocks:
    """The odometry's factors and the first pose's anchor."""
    blocks = Blocks()
    nx = 3 * prob.stamps.size
    if prob.ack:
        ackermann_factors(blocks, x, ctrl, prob.odo[:-1], prob.dts, prob.wb, prob.sig, nx)
    else:
        increment_factors(blocks, x, prob.odo, prob.sig)
    return blocks


def _anchor(blocks: Blocks, x: np.ndarray, start: np.ndarray) -> None:
    d0 = x[0] - start
    d0[2] = wrap_angle(d0[2])
    blocks.add(1e6 * d0, [(np.arange(3), np.full(3, 1e6))])  # the first pose is the true start


def _apply(prob: _Problem, step: np.ndarray, x: np.ndarray, ctrl: np.ndarray, lm: np.ndarray) -> None:
    nx, nc, _ = prob.sizes
    x += step[:nx].reshape(-1, 3)
    x[:, 2] = wrap_angle(x[:, 2])
    if prob.ack:
        ctrl += step[nx : nx + nc].reshape(-1, 2)
    lm += step[nx + nc :].reshape(-1, 2)


def _result(prob: _Problem, h: sp.csc_matrix, lu, x, lm, it: int, converged: bool, cost: float, cls=None, **extra):
    """Marginal covariances from the information matrix h (factorised as lu) at the mode."""
    nx, nc, nm = prob.sizes
    nl = nm // 2
    nv = nx + nc + nm
    e = np.zeros((nv, 3 + 2 * nl))
    e[nx - 3 + np.arange(3), np.arange(3)] = 1.0
    e[nx + nc + np.arange(2 * nl), 3 + np.arange(2 * nl)] = 1.0
    cols = lu.solve(e)
    final_cov = cols[nx - 3 : nx, :3]
    lcov = cols[nx + nc :, 3:]
    # given the path, the landmarks are independent: H_mm is block-diagonal, inverted 2x2 at a time
    hmm = h[nx + nc :, nx + nc :].toarray().reshape(nl, 2, nl, 2)
    given = np.zeros((nl, 2, nl, 2))
    k = np.arange(nl)
    given[k, :, k, :] = np.linalg.inv(hmm[k, :, k, :])  # (nl, 2, 2) diagonal blocks
    given = given.reshape(2 * nl, 2 * nl)
    out_lm = np.full((prob.ids.size, 2), np.nan)
    out_lm[prob.detected] = lm
    return (cls or OracleResult)(
        prob.stamps,
        x,
        prob.ids,
        out_lm,
        0.5 * (final_cov + final_cov.T),
        0.5 * (lcov + lcov.T),
        given,
        prob.detected,
        it,
        converged,
        cost,
        h,
        **extra,
    )


def _check_noise(range_sigma: float, bearing_sigma: float, iterations: int) -> None:
    if iterations < 1:
        raise UsageError(f"oracle: iterations must be at least 1, not {iterations}")
    for name, v in (("range_sigma", range_sigma), ("bearing_sigma", bearing_sigma)):
        if not (np.isfinite(v) and v > 0):
            raise UsageError(f"oracle: {name} must be a positive number, not {v!r}")


def batch_oracle(
    log: SensorLog,
    *,
    odometry_sigma: tuple[float, ...],
    range_sigma: float,
    bearing_sigma: float,
    iterations: int = 50,
) -> OracleResult:
    """The full-SLAM posterior's mode and covariance of a simulated log with labelled detections.

    odometry_sigma: per odometry row, (dx, dy, dtheta) [m, m, rad] for ``increment`` odometry, (speed [m/s],
    steering [rad]) for ``ackermann``; range_sigma [m], bearing_sigma [rad]: the measurement noise.
    """
    _check_noise(range_sigma, bearing_sigma, iterations)
    prob = _problem(log, odometry_sigma)
    x, _, lm, h, lu, it, converged, cost = _solve_labelled(prob, range_sigma, bearing_sigma, iterations)
    return _result(prob, h, lu, x, lm, it, converged, cost)


def _solve_labelled(prob: _Problem, range_sigma: float, bearing_sigma: float, iterations: int):
    """Gauss-Newton on the labelled problem from dead reckoning: (poses, controls, landmarks, information,
    its factorisation, iterations, converged, cost)."""
    x, ctrl, lm = prob.x0.copy(), prob.ctrl.copy(), prob.lm0.copy()
    nx, nc, nm = prob.sizes
    nv = nx + nc + nm
    lu = h = None
    cost = np.inf
    it = 0
    converged = False
    for it in range(1, iterations + 1):
        blocks = _motion_blocks(prob, x, ctrl)
        range_bearing_factors(blocks, x, lm, prob.k_of, prob.lj, prob.zr, prob.zb, range_sigma, bearing_sigma, nx + nc)
        _anchor(blocks, x, prob.start)
        jac, res = blocks.build(nv)
        h = (jac.T @ jac).tocsc()
        lu = splu(h)
        step = lu.solve(-(jac.T @ res))
        cost = 0.5 * float(res @ res)
        _apply(prob, step, x, ctrl, lm)
        if np.abs(step).max() < 1e-10:
            converged = True
            break
    return x, ctrl, lm, h, lu, it, converged, cost


def clutter_oracle(
    log: SensorLog,
    *,
    odometry_sigma: tuple[float, ...],
    range_sigma: float,
    bearing_sigma: float,
    pd: float,
    clutter_density: float,
    range_max: float,
    range_min: float = 0.0,
    gate: float = 36.0,
    iterations: int = 300,
    tolerance: float = 1e-8,
) -> ClutterOracleResult:
    """The full-SLAM posterior's mode and covariance when the associations are *not* given: what the data of a
    log with false alarms allow an exact filter.

    Each landmark in view at a scan (its estimated range in [range_min, range_max]) contributes the exact
    single-feature likelihood of the scan, (1 - pd) + pd sum_j N(z_j; h(x, m), R) / kappa, kappa =
    ``clutter_density`` per (m rad) (Bar-Shalom's probabilistic data association; the multi-object
    likelihood when no two landmarks compete for one measurement; the landmarks are those the labelled
    detections saw, the labels used for nothing else). The mode is found by EM from the labelled oracle's
    mode (:func:`batch_oracle`): each iteration weighs every (landmark, measurement) pair within ``gate``
    (squared Mahalanobis distance) by its responsibility and takes one Gauss-Newton step of the weighted
    problem. The information at the mode is the weighted Gauss-Newton information less the missing
    information of the associations (Louis 1982): for each landmark and scan, the responsibility-weighted
    covariance of the pairs' scores. A local mode: the one the true associations lead to.
    """
    _check_noise(range_sigma, bearing_sigma, iterations)
    if not (0.0 < pd < 1.0):
        raise UsageError(f"clutter oracle: pd must be in (0, 1), not {pd!r}")
    if not (np.isfinite(clutter_density) and clutter_density > 0.0):
        raise UsageError(f"clutter oracle: clutter_density must be a positive number, not {clutter_density!r}")
    if not (0.0 <= range_min < range_max):
        raise UsageError(f"clutter oracle: need 0 <= range_min < range_max, not {range_min!r}, {range_max!r}")
    if not (np.isfinite(gate) and gate > 0.0):
        raise UsageError(f"clutter oracle: gate must be a positive number, not {gate!r}")
    prob = _problem(log, odometry_sigma)
    x, ctrl, lm = _solve_labelled(prob, range_sigma, bearing_sigma, 50)[:3]  # the labelled mode: the start
    nx, nc, nm = prob.sizes
    nv = nx + nc + nm
    mix = _Mixture(log, prob, x, lm, pd, clutter_density, range_min, range_max, range_sigma, bearing_sigma, gate)
    k_all, zr_all, zb_all = mix.k_all, mix.zr, mix.zb

    def weighted(dj, lj, w):
        blocks = _motion_blocks(prob, x, ctrl)
        range_bearing_factors(blocks, x, lm, k_all[dj], lj, zr_all[dj], zb_all[dj], range_sigma, bearing_sigma, nx + nc, w)
        _anchor(blocks, x, prob.start)
        return blocks.build(nv)

    it = 0
    converged = False
    for it in range(1, iterations + 1):
        dj, lj, w, _, _ = mix.pairs(x, lm)  # E-step: the responsibilities at the current estimate
        jac, res = weighted(dj, lj, w)  # M-step: one Gauss-Newton step of the weighted problem
        step = splu((jac.T @ jac).tocsc()).solve(-(jac.T @ res))
        _apply(prob, step, x, ctrl, lm)
        if np.abs(step).max() < tolerance:
            converged = True
            break
    dj, lj, w, grp, ll = mix.pairs(x, lm)
    motion = _motion_blocks(prob, x, ctrl)
    _anchor(motion, x, prob.start)
    mjac, mres = motion.build(nv)
    cost = 0.5 * float(mres @ mres)  # the odometry's (and the anchor's) part of the objective
    # the measurements' Gauss-Newton information, sum_j w_j J_j^T J_j, from the pairs' dense blocks (whitened)
    r, jb, cols = range_bearing_jacobian(x, lm, k_all[dj], lj, zr_all[dj], zb_all[dj], range_sigma, bearing_sigma, nx + nc)
    h_meas = _sparse_blocks(w[:, None, None] * np.einsum("mki,mkj->mij", jb, jb), cols, nv)
    h_gn = ((mjac.T @ mjac) + h_meas).tocsc()
    # Louis's missing information: per (scan, landmark) group, sum_j w_j s_j s_j^T - s_bar s_bar^T over the
    # group's pairs' scores s_j = -J_j^T r_j (whitened; the missed-detection term has none)
    s = -np.einsum("mij,mi->mj", jb, r)  # (M, 5)
    ug, gi = np.unique(grp, return_inverse=True)
    sbar = np.zeros((ug.size, 5))
    np.add.at(sbar, gi, w[:, None] * s)
    gcols = np.zeros((ug.size, 5), dtype=np.int64)
    gcols[gi] = cols
    outer = w[:, None, None] * s[:, :, None] * s[:, None, :]
    miss = np.zeros((ug.size, 5, 5))
    np.add.at(miss, gi, outer)
    miss -= sbar[:, :, None] * sbar[:, None, :]
    h_miss = _sparse_blocks(miss, gcols, nv)
    h = (h_gn - h_miss).tocsc()
    lu = splu(h)
    meas_info = float(h_meas.diagonal().sum())
    loss = float(h_miss.diagonal().sum()) / meas_info if meas_info > 0 else 0.0
    own, own_j, n_frames = mix.own, mix.own_j, mix.n_frames
    true_pair = own_j[dj] == lj
    n_true = int(np.sum(own_j >= 0))
    return _result(
        prob,
        h,
        lu,
        x,
        lm,
        it,
        converged,
        cost,
        cls=ClutterOracleResult,
        log_likelihood=ll - cost,
        own_weight=float(w[true_pair].sum() / max(n_true, 1)),
        false_weight=float(w[own[dj] == 0].sum() / max(n_frames, 1)),
        stray_weight=float(w[(own_j[dj] >= 0) & ~true_pair].sum() / max(n_frames, 1)),
        information_loss=loss,
    )


def _sparse_blocks(blocks: np.ndarray, cols: np.ndarray, nv: int) -> sp.csc_matrix:
    """(nv, nv) the sum of dense blocks (M, k, k), block m at the rows and columns cols[m] (M, k) (repeats add)."""
    rows = np.broadcast_to(cols[:, :, None], blocks.shape).ravel()
    cols_ = np.broadcast_to(cols[:, None, :], blocks.shape).ravel()
    return sp.csc_matrix((blocks.ravel(), (rows, cols_)), shape=(nv, nv))


class _Mixture:
    """The measurements' term of :func:`clutter_oracle`'s objective: for each scan and landmark in view, the
    exact single-feature likelihood (1 - pd) + pd sum_j N(z_j; h(x, m), R) / kappa over the scan's measurements
    within the gate. Which landmarks are in view at a scan is decided once, at (x0, lm0)."""

    def __init__(self, log: SensorLog, prob: _Problem, x0, lm0, pd, kappa, range_min, range_max, sr, sb, gate) -> None:
        det = log.detections
        stamps = prob.stamps
        self.k_all = np.searchsorted(stamps, det.frame_stamp[det.frame])
        at = stamps[np.minimum(self.k_all, stamps.size - 1)]
        if np.any(self.k_all >= stamps.size) or np.any(at != det.frame_stamp[det.frame]):
            raise DataError(f"{log.name}: the oracle needs a detection frame at an odometry stamp")
        self.frame = np.asarray(det.frame)
        self.zr, self.zb = np.asarray(det.range, np.float64), np.asarray(det.bearing, np.float64)
        self.nl = lm0.shape[0]
        self.own = np.asarray(det.descriptors["landmark"])
        col = -np.ones(prob.ids.size, dtype=np.int64)
        col[prob.detected] = np.arange(self.nl)
        idx = np.minimum(np.searchsorted(prob.ids, np.maximum(self.own, 0)), prob.ids.size - 1)
        self.own_j = np.where(self.own > 0, col[idx], -1)  # each measurement's landmark among the detected (-1: none)
        self.n_frames = np.unique(self.frame).size
        self.sr, self.sb, self.gate = sr, sb, gate
        self.norm = pd / (kappa * 2.0 * np.pi * sr * sb)
        # the candidate pairs: each measurement with each landmark in view at its scan (from x0, lm0), fixed
        rng0 = np.hypot(*(lm0[None, :, :] - x0[self.k_all, None, :2]).transpose(2, 0, 1))
        self.cand_d, self.cand_j = np.nonzero((rng0 >= range_min) & (rng0 <= range_max))
        groups, self.g_inv = np.unique(self.frame[self.cand_d] * self.nl + self.cand_j, return_inverse=True)
        self.miss = np.full(groups.size, 1.0 - pd)  # the (scan, landmark) groups in view (scans with a measurement)

    def pairs(self, x, lm):
        """Every gated (measurement, landmark in view) pair: its measurement and landmark, its responsibility and
        its (scan, landmark) group; and the log-likelihood, summed over the groups in view (up to a constant)."""
        d, j = self.cand_d, self.cand_j
        q = lm[j] - x[self.k_all[d], :2]
        bear = np.arctan2(q[:, 1], q[:, 0]) - x[self.k_all[d], 2]
        d2 = ((np.hypot(q[:, 0], q[:, 1]) - self.zr[d]) / self.sr) ** 2 + (wrap_angle(bear - self.zb[d]) / self.sb) ** 2
        gated = d2 < self.gate
        w, denom = association_weights(np.where(gated, self.norm * np.exp(-0.5 * d2), 0.0), self.g_inv, self.miss)
        return d[gated], j[gated], w[gated], self.g_inv[gated], float(np.log(denom).sum())


def posterior_samples(res: OracleResult, rng: np.random.Generator, n: int) -> tuple[np.ndarray, np.ndarray]:
    """n draws of (final position (n, 2), detected landmarks (n, L', 2)) from the Gaussian posterior's
    marginals (each drawn on its own: the final pose and the map are not jointly drawn)."""
    fin = rng.multivariate_normal(res.poses[-1, :2], res.final_cov[:2, :2], size=n)
    mean = res.landmarks[res.detected].ravel()
    ch = np.linalg.cholesky(res.landmark_cov + np.eye(mean.size) * 1e-15)
    lms = mean + rng.standard_normal((n, mean.size)) @ ch.T
    return fin, lms.reshape(n, -1, 2)


def rb_map_samples(res: OracleResult, rng: np.random.Generator, n: int) -> np.ndarray:
    """n maps (n, L', 2) as an ideal Rao-Blackwellised particle holds them: the conditional mean of the detected
    landmarks given a path drawn from the posterior, N(m_MAP, Sigma_mm - H_mm^-1) to first order."""
    mean = res.landmarks[res.detected].ravel()
    c = res.landmark_cov - res.landmark_cov_given_path
    val, vec = np.linalg.eigh(0.5 * (c + c.T))
    root = vec * np.sqrt(np.clip(val, 0.0, None))
    return (mean + rng.standard_normal((n, mean.size)) @ root.T).reshape(n, -1, 2)


def map_distance(res: OracleResult, map_xy: np.ndarray, cutoff: float = 0.5) -> tuple[float, int]:
    """How far a map (K, 2) lies from the oracle's mode: each detected landmark paired with at most one feature
    within ``cutoff`` [m] (optimal assignment), then (m - m_MAP)^T Sigma^-1 (m - m_MAP) / dof over the paired
    landmarks, Sigma their posterior covariance. Returns (that ratio, landmarks paired). An exact posterior
    sample gives 1 on average; an ideal RB particle's map less (:func:`rb_map_samples`)."""
    mode = res.landmarks[res.detected]
    map_xy = np.asarray(map_xy, dtype=np.float64).reshape(-1, 2)
    if map_xy.shape[0] == 0:
        return float("nan"), 0
    d = np.linalg.norm(map_xy[:, None, :] - mode[None, :, :], axis=2)
    r, k = linear_sum_assignment(d)
    ok = d[r, k] < cutoff
    r, k = r[ok], k[ok]
    if k.size == 0:
        return float("nan"), 0
    sel = np.column_stack([2 * k, 2 * k + 1]).ravel()
    e = (map_xy[r] - mode[k]).ravel()
    return float(e @ np.linalg.solve(res.landmark_cov[np.ix_(sel, sel)], e) / e.size), int(k.size)


def mahalanobis2(res: OracleResult, position: np.ndarray) -> float:
    """Squared Mahalanobis distance of an estimated last position (2,) from the MAP's, under the posterior
    covariance: chi-square(2) for an exact posterior sample."""
    d = np.asarray(position, dtype=np.float64)[:2] - res.poses[-1, :2]
    return float(d @ np.linalg.solve(res.final_cov[:2, :2], d))


def clutter_information_ratio(pd: float, density: float, rng: np.random.Generator, n: int = 100_000, window: float = 8.0) -> float:
    """How much of a detection's information false alarms leave: the Fisher information about a feature's
    position carried by one scan of a detector of probability ``pd`` with Poisson false alarms of ``density``
    per unit of *whitened* measurement area (the clutter intensity kappa times |S|^(1/2), S the innovation
    covariance), over the information the same detector gives without false alarms (pd per axis), by Monte
    Carlo (n scans). The association is not given: the scan's likelihood is (1 - pd) + pd sum_j N(z_j; x, I) /
    density, the exact single-feature likelihood (Bar-Shalom's information reduction factor of probabilistic
    data association, for a 2-D measurement and an unbounded gate; false alarms drawn over a square of half-
    width ``window`` whitened units, far beyond where they matter). 1 without false alarms; it falls as they
    crowd the innovation volume. The oracle has no false alarms; an ideal filter's errors under clutter are
    its errors over sqrt(this ratio) (for errors well below the OSPA cut-off)."""
    if not (0.0 < pd <= 1.0):
        raise UsageError(f"clutter information ratio: pd must be in (0, 1], not {pd!r}")
    if not (np.isfinite(density) and density >= 0.0):
        raise UsageError(f"clutter information ratio: density must be a non-negative number, not {density!r}")
    if density == 0.0:
        return 1.0
    detected = rng.random(n) < pd
    z0 = rng.standard_normal((n, 2))
    count = rng.poisson(density * (2.0 * window) ** 2, size=n)
    k = int(count.max()) + 1
    z = rng.uniform(-window, window, size=(n, k, 2))
    valid = np.arange(k)[None, :] < count[:, None]
    z[:, -1] = z0  # the last column holds the detection, where there is one
    valid[:, -1] = detected
    g = np.where(valid, np.exp(-0.5 * np.einsum("nki,nki->nk", z, z)) / (2.0 * np.pi), 0.0)
    # d/dx of the scan's log-likelihood at the true position x = 0, first axis
    score = (pd / density) * np.einsum("nk,nk->n", g, z[..., 0]) / ((1.0 - pd) + (pd / density) * g.sum(axis=1))
    return float(np.mean(score**2) / pd)




@dataclass
class LogOracleResult:
    """:func:`log_oracle`'s mode."""

    stamps: np.ndarray  # (T,) the log's frame stamps [ns]: the steps of a filter run on it
    poses: np.ndarray  # (T, 3) MAP vehicle poses, world frame
    landmark_ids: np.ndarray  # (L,)
    landmarks: np.ndarray  # (L, 2) MAP landmark positions (NaN: never detected)
    detected: np.ndarray  # (L,) bool
    iterations: int  # of the last solve
    converged: bool  # the last solve's step moved nothing by more than ``tolerance``
    downweighted: float  # share of the labelled detections whose residual the Huber loss downweighted at the mode
    forward_stamps: np.ndarray  # (W,) the last frame of each window [ns]
    forward_poses: np.ndarray  # (W, 3) the pose there given the data up to it: what a filter (forward only) could know


def log_oracle(
    log: SensorLog,
    vehicle,
    labels: np.ndarray,
    *,
    range_sigma: float,
    bearing_sigma: float,
    huber: float = 3.0,
    window: float = 30.0,
    iterations: int = 50,
    tolerance: float = 1e-6,
) -> LogOracleResult:
    """The full-SLAM mode of a recorded log, its detections' associations given.

    vehicle: the filter's vehicle model (planar pose state); labels (detections,): the landmark id of each
    detection, or -1 for one that is no landmark (clutter, another robot); range_sigma [m], bearing_sigma [rad]: the
    measurement noise; huber: the whitened residual norm beyond which a detection is downweighted (IRLS). The run
    grows ``window`` seconds at a time (each solve starts from the last, the new frames dead-reckoned on, each new
    landmark from its first detection): a whole log from dead reckoning metres off would fall into a wrong basin.
    The last pose of each window's solve is the mode given the data up to it (``forward_poses``): the floor of a
    filter's estimate at that time, where the final ``poses`` also use what came after (a smoother's).
    """
    _check_noise(range_sigma, bearing_sigma, iterations)
    if not huber > 0 or not window > 0:
        raise UsageError(f"log_oracle: huber and window must be positive, not {huber!r} and {window!r}")
    det, ref = log.detections, log.reference.get("ground_truth")
    if log.odometry is None or det is None or log.landmarks is None or ref is None:
        raise DataError(f"{log.name}: the oracle needs odometry, detections, landmark truth and ground truth")
    labels = np.asarray(labels)
    if labels.shape != (det.range.size,):
        raise UsageError(f"log_oracle: one label per detection ({det.range.size}), not an array of shape {labels.shape}")
    if vehicle.dim != 3:
        raise UsageError(f"log_oracle: a vehicle model whose state is the planar pose, not {type(vehicle).__name__} of {vehicle.dim}")
    mount = log.sensor.mount if log.sensor is not None else None
    if mount is not None and (mount.x, mount.y, mount.theta) != (0.0, 0.0, 0.0):
        raise DataError(f"{log.name}: the oracle models a sensor at the vehicle's reference point")
    log = delayed(log, vehicle.delay)
    frames = list(log.frames())
    stamps = np.array([f.stamp for f in frames], dtype=np.int64)
    if not ref.stamp[0] <= stamps[0] <= ref.stamp[-1]:
        raise DataError(f"{log.name}: the ground truth does not cover the first frame")
    n = stamps.size
    inc, whiten = frame_odometry(log, vehicle, frames)
    ids = np.asarray(log.landmarks.ids)
    keep = labels >= 0
    li = np.minimum(np.searchsorted(ids, labels[keep]), ids.size - 1)
    if np.any(ids[li] != labels[keep]):
        raise DataError(f"{log.name}: label {int(labels[keep][ids[li] != labels[keep]][0])} is no landmark of the log's truth")
    k_of, zr, zb = det.frame[keep], np.asarray(det.range)[keep], np.asarray(det.bearing)[keep]
    start = interpolate_poses(ref.stamp, ref.poses, stamps[:1])[0]

    x = np.zeros((n, 3))
    x[0] = start
    lm = np.full((ids.size, 2), np.nan)
    ends = np.searchsorted(stamps, stamps[0] + np.arange(1, int((stamps[-1] - stamps[0]) / (window * 1e9)) + 1) * int(window * 1e9))
    ends = np.unique(np.concatenate([ends[(ends > 1) & (ends < n)], [n]]))
    done, it, converged, w = 1, 0, False, np.ones(0)
    forward = np.zeros((ends.size, 3))
    for i, end in enumerate(ends):
        for k in range(done - 1, end - 1):  # dead reckoning onto the new frames
            x[k + 1] = compose(x[k], inc[k])
        sel = k_of < end
        new = sel & np.isnan(lm[li, 0])
        first = np.unique(li[new], return_index=True)[1]
        f = np.flatnonzero(new)[first]
        lm[li[f]] = _sighted(x[k_of[f]], zr[f], zb[f])
        last = end == n  # the windows before only place the start of the next: a few iterations, a coarse tolerance
        it, converged, w = _solve_log(x[:end], lm, inc[: end - 1], whiten[: end - 1], start, k_of[sel], li[sel], zr[sel], zb[sel],
                                      range_sigma, bearing_sigma, huber, iterations if last else min(iterations, 10),
                                      tolerance if last else max(tolerance, 1e-4))  # fmt: skip
        forward[i] = x[end - 1]
        done = end
    return LogOracleResult(
        stamps, x, ids, lm, ~np.isnan(lm[:, 0]), it, converged, float(np.mean(w < 1.0)) if w.size else 0.0, stamps[ends - 1], forward
    )


def frame_odometry(log: SensorLog, vehicle, frames: list | None = None) -> tuple[np.ndarray, np.ndarray]:
    """The odometry between consecutive frames as the vehicle model predicts it: the mean increment (T-1, 3) in the
    earlier frame's pose, and the whitening (T-1, 3, 3), W = L^-1 for the increment's covariance L L^T, so that
    W (relative pose - increment) has unit covariance. Frames with no odometry row between them hold the pose
    (0.1 mm, 1e-5 rad)."""
    from slam_runtime.sources import control_rows

    frames = list(log.frames()) if frames is None else frames
    n = len(frames)
    inc, cov = np.zeros((n - 1, 3)), np.zeros((n - 1, 3, 3))
    x0 = vehicle.initial(np.zeros(3), 1)
    for k, fr in enumerate(frames[1:]):
        u, dt = control_rows(log, fr.odometry)
        if u.shape[0]:
            m, c = vehicle.predict_gaussian(x0, u, dt)
            inc[k], cov[k] = vehicle.pose(m)[0], c[0, :3, :3]
    return inc, np.linalg.inv(np.linalg.cholesky(cov + np.diag([1e-8, 1e-8, 1e-10])))


def _solve_log(x, lm, inc, whiten, start, k_of, li, zr, zb, sr, sb, huber, iterations, tolerance):
    """Gauss-Newton with Huber weights re-set at each iteration (IRLS), x (m, 3) and the seen landmarks of lm in
    place: (iterations, converged, the final weights)."""
    seen = np.flatnonzero(~np.isnan(lm[:, 0]))
    col = -np.ones(lm.shape[0], dtype=np.int64)
    col[seen] = np.arange(seen.size)
    lj = col[li]
    nx = 3 * x.shape[0]
    nv = nx + 2 * seen.size
    sub = lm[seen].copy()
    w = np.ones(k_of.size)
    converged, it = False, 0
    for it in range(1, iterations + 1):
        b = Blocks()
        relative_pose_factors(b, x, inc, whiten)
        range_bearing_factors(b, x, sub, k_of, lj, zr, zb, sr, sb, nx, w=w)
        _anchor(b, x, start)
        jac, res = b.build(nv)
        step = splu((jac.T @ jac).tocsc()).solve(-(jac.T @ res))
        x += step[:nx].reshape(-1, 3)
        x[:, 2] = wrap_angle(x[:, 2])
        sub += step[nx:].reshape(-1, 2)
        q = sub[lj] - x[k_of, :2]
        e = np.hypot((np.hypot(q[:, 0], q[:, 1]) - zr) / sr, wrap_angle(np.arctan2(q[:, 1], q[:, 0]) - x[k_of, 2] - zb) / sb)
        w = huber / np.maximum(e, huber)  # 1 within the threshold, huber / e beyond
        if np.abs(step).max() < tolerance:
            converged = True
            break
    lm[seen] = sub
    return it, converged, w


def as_slam_result(res: LogOracleResult):
    """The oracle's mode in the shape of a filter run's result (no timings, every landmark it placed as the map), so
    that :func:`slam_runtime.run.evaluate` scores it with the filters' own metrics."""
    from slam_runtime.run import SlamResult

    t = res.stamps.size
    return SlamResult(
        "oracle", res.stamps, res.poses, res.poses, res.landmarks[res.detected], np.ones(int(res.detected.sum())),
        np.zeros(t), np.zeros(t, dtype=np.int64), np.ones(t), np.zeros(t, dtype=bool), np.ones(t), res.poses[0].copy(),
    )  # fmt: skip
