"""The pose graph of the ground truth: keyframe poses from relative-pose edges, solved robustly.

Nodes are keyframe vehicle poses (x, y, theta), world frame; the first is held
by a tight prior. Edges are measured relative poses ``z_ij`` (pose j in the
frame of pose i) with a diagonal noise (sigma_x, sigma_y, sigma_theta):

- **sequential** edges from the front end (consecutive keyframes), trusted:
  plain Gaussian costs, and known inliers for GNC;
- **loop** edges from verified loop closures (:mod:`calib.loops`), which can
  still be wrong (a corridor that looks like another): robust costs.

Solvers (``GraphConfig.solver``):

- ``gtsam`` (default): GTSAM's ``BetweenFactorPose2`` factors, solved by
  graduated non-convexity with a truncated-least-squares loss (``robust: gnc``,
  Yang et al., "Graduated non-convexity for robust spatial perception", RA-L
  2020), which drives the weight of an inconsistent loop to zero, or by
  Levenberg-Marquardt with an M-estimator on the loops (``cauchy``, ``huber``);
- ``scipy``: ``scipy.optimize.least_squares`` on the same residuals with a
  sparse Jacobian, the robust cost on the loops by iteratively reweighted
  least squares (``cauchy``, ``huber``; ``gnc`` is GTSAM's only). Kept to
  compare (see the ground-truth results page).

After the solve every edge's whitened residual ``chi2 = e^T Sigma^-1 e``
(e = z_ij (-) (x_i (-) x_j)) is reported; a loop whose chi2 exceeds
``outlier_chi2`` (or whose GNC weight falls below 0.5) is counted as rejected
by the back end.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from detectors.geometry import relative
from profiles.errors import DataError


class GraphConfig(BaseModel):
    """Pose-graph noise models and solver (see the module docstring)."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)
    solver: Literal["gtsam", "scipy"] = "gtsam"
    robust: Literal["gnc", "cauchy", "huber", "none"] = Field(default="gnc", description="cost of loop edges")
    kernel: float = Field(default=3.0, gt=0.0, description="scale of the Cauchy / Huber cost, in whitened units (sigmas)")
    # defaults: about the residual rms of each kind of edge after the solve on the Intel log (a front-end edge is
    # good to millimetres, a loop to centimetres); looser sequential edges let a cluster of wrong loops bend the chain
    seq_sigma_xy: float = Field(default=0.005, gt=0.0, description="sequential edge, translation [m]")
    seq_sigma_theta: float = Field(default=0.001, gt=0.0, description="sequential edge, heading [rad]")
    seq_sigma_per_m: float = Field(default=0.005, ge=0.0, description="added to the sequential translation sigma per metre of the edge")
    loop_sigma_xy: float = Field(default=0.03, gt=0.0, description="loop edge, translation [m]")
    loop_sigma_theta: float = Field(default=0.005, gt=0.0, description="loop edge, heading [rad]")
    outlier_chi2: float = Field(default=16.27, gt=0.0, description="a loop's chi2 above this after the solve is an outlier (chi2, 3 dof, 99.9 %)")
    iterations: int = Field(default=100, ge=1)


@dataclass
class Edges:
    """Relative-pose edges, struct of arrays: E edges."""

    i: np.ndarray  # (E,) int, from node
    j: np.ndarray  # (E,) int, to node
    z: np.ndarray  # (E, 3) measured pose of j in the frame of i
    sigma: np.ndarray  # (E, 3) sigma_x, sigma_y [m], sigma_theta [rad]
    loop: np.ndarray  # (E,) bool: a loop edge (robust cost), else sequential

    @classmethod
    def empty(cls) -> Edges:
        return cls(np.zeros(0, int), np.zeros(0, int), np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(0, bool))

    def __len__(self) -> int:
        return int(self.i.size)

    def plus(self, i, j, z, sigma, loop: bool) -> Edges:
        i, j = np.atleast_1d(np.asarray(i, int)), np.atleast_1d(np.asarray(j, int))
        z, sigma = np.atleast_2d(np.asarray(z, float)), np.atleast_2d(np.asarray(sigma, float))
        return Edges(
            np.concatenate([self.i, i]), np.concatenate([self.j, j]), np.vstack([self.z, z]), np.vstack([self.sigma, np.broadcast_to(sigma, z.shape)]),
            np.concatenate([self.loop, np.full(i.size, loop)]),
        )  # fmt: skip


@dataclass
class Solution:
    """Optimised node poses (K, 3) and, per edge (E,), the whitened residual chi2 and the robust weight (1 = inlier)."""

    poses: np.ndarray
    chi2: np.ndarray
    weight: np.ndarray
    iterations: int


def sequential_sigma(z: np.ndarray, cfg: GraphConfig) -> np.ndarray:
    """(E, 3) sigmas of sequential edges with relative poses ``z`` (E, 3): a floor plus a share of the length."""
    d = np.hypot(z[:, 0], z[:, 1])
    s = cfg.seq_sigma_xy + cfg.seq_sigma_per_m * d
    return np.column_stack([s, s, np.full(d.size, cfg.seq_sigma_theta)])


def residuals(poses: np.ndarray, edges: Edges) -> np.ndarray:
    """(E, 3) edge errors z_ij (-) (x_i (-) x_j), heading wrapped; divide by sigma to whiten."""
    return relative(edges.z, relative(poses[edges.i], poses[edges.j]))


def solve(x0: np.ndarray, edges: Edges, cfg: GraphConfig) -> Solution:
    """Optimise node poses from the start ``x0`` (K, 3); node 0 is held at ``x0[0]``."""
    if len(edges) == 0:
        return Solution(x0.copy(), np.zeros(0), np.ones(0), 0)
    if edges.i.min() < 0 or max(edges.i.max(), edges.j.max()) >= x0.shape[0]:
        raise DataError("pose graph: an edge names a node that does not exist")
    if cfg.solver == "scipy":
        return _solve_scipy(x0, edges, cfg)
    return _solve_gtsam(x0, edges, cfg)


def _chi2(poses: np.ndarray, edges: Edges) -> np.ndarray:
    e = residuals(poses, edges) / edges.sigma
    return np.sum(e**2, axis=1)


def _solve_gtsam(x0: np.ndarray, edges: Edges, cfg: GraphConfig) -> Solution:
    import gtsam

    graph = gtsam.NonlinearFactorGraph()
    graph.add(gtsam.PriorFactorPose2(0, gtsam.Pose2(*x0[0]), gtsam.noiseModel.Diagonal.Sigmas(np.array([1e-4, 1e-4, 1e-5]))))
    robust = cfg.robust if cfg.robust != "gnc" else "none"
    for i, j, z, s, lp in zip(edges.i, edges.j, edges.z, edges.sigma, edges.loop, strict=True):
        noise = gtsam.noiseModel.Diagonal.Sigmas(np.asarray(s, dtype=float))
        if lp and robust != "none":
            est = gtsam.noiseModel.mEstimator.Cauchy.Create(cfg.kernel) if robust == "cauchy" else gtsam.noiseModel.mEstimator.Huber.Create(cfg.kernel)
            noise = gtsam.noiseModel.Robust.Create(est, noise)
        graph.add(gtsam.BetweenFactorPose2(int(i), int(j), gtsam.Pose2(*z), noise))
    init = gtsam.Values()
    for k, p in enumerate(x0):
        init.insert(k, gtsam.Pose2(*p))
    lm = gtsam.LevenbergMarquardtParams()
    lm.setMaxIterations(cfg.iterations)
    weight = np.ones(len(edges))
    if cfg.robust == "gnc" and edges.loop.any():
        params = gtsam.GncLMParams(lm)
        params.setLossType(gtsam.GncLossType.TLS)
        # the prior (factor 0) and the sequential edges are trusted; only loops may be turned off
        params.setKnownInliers([0, *[int(k) + 1 for k in np.flatnonzero(~edges.loop)]])
        opt = gtsam.GncLMOptimizer(graph, init, params)
        # TLS threshold on the factor's cost 0.5 * chi2: loops beyond outlier_chi2 get weight 0
        opt.setInlierCostThresholds(0.5 * cfg.outlier_chi2)
        result = opt.optimize()
        weight = np.asarray(opt.getWeights())[1:]
        iters = -1
    else:
        opt = gtsam.LevenbergMarquardtOptimizer(graph, init, lm)
        result = opt.optimize()
        iters = int(opt.iterations())
    poses = np.array([[result.atPose2(k).x(), result.atPose2(k).y(), result.atPose2(k).theta()] for k in range(x0.shape[0])])
    chi2 = _chi2(poses, edges)
    if cfg.robust != "gnc":
        weight = np.where(edges.loop & (chi2 > cfg.outlier_chi2), 0.0, 1.0)
    return Solution(poses, chi2, weight, iters)


def _solve_scipy(x0: np.ndarray, edges: Edges, cfg: GraphConfig) -> Solution:
    """Sparse least squares (``scipy.optimize.least_squares``, trust region) with the robust cost on the loop
    edges by iteratively reweighted least squares: Cauchy w = 1 / (1 + chi2 / k^2), Huber w = min(1, k / sqrt(chi2))."""
    from scipy.optimize import least_squares
    from scipy.sparse import coo_matrix

    if cfg.robust == "gnc":
        raise DataError("pose graph: robust 'gnc' needs solver 'gtsam'")
    k = x0.shape[0]
    inv = 1.0 / edges.sigma
    # the Jacobian's pattern: each edge's 3 rows meet the 3 columns of each of its free nodes
    r = (3 * np.arange(len(edges)))[:, None, None] + np.arange(3)[None, :, None]
    rr, cc = [], []
    for node in (edges.i, edges.j):
        rows, cols = np.broadcast_arrays(r, (3 * (node - 1))[:, None, None] + np.arange(3)[None, None, :])
        free = node > 0
        rr.append(rows[free].ravel())
        cc.append(cols[free].ravel())
    rr, cc = np.concatenate(rr), np.concatenate(cc)
    sparsity = coo_matrix((np.ones(rr.size, dtype=np.int8), (rr, cc)), shape=(3 * len(edges), 3 * (k - 1))).tocsr()
    sparsity.data[:] = 1
    weight = np.ones(len(edges))
    flat = x0[1:].ravel()
    nfev = 0
    for _ in range(1 if cfg.robust == "none" else 10):
        sw = np.sqrt(weight)[:, None]

        def resid(f, sw=sw):
            x = np.vstack([x0[:1], f.reshape(-1, 3)])
            return (residuals(x, edges) * inv * sw).ravel()

        sol = least_squares(resid, flat, jac_sparsity=sparsity, method="trf", x_scale="jac", max_nfev=cfg.iterations)
        nfev += int(sol.nfev)
        flat = sol.x
        chi2 = _chi2(np.vstack([x0[:1], flat.reshape(-1, 3)]), edges)
        kk = cfg.kernel**2
        new = np.where(edges.loop, 1.0 / (1.0 + chi2 / kk) if cfg.robust == "cauchy" else np.minimum(1.0, cfg.kernel / np.sqrt(np.maximum(chi2, 1e-12))), 1.0)
        if cfg.robust == "none" or np.abs(new - weight).max() < 1e-3:
            break
        weight = new
    poses = np.vstack([x0[:1], flat.reshape(-1, 3)])
    poses[:, 2] = np.mod(poses[:, 2] + np.pi, 2 * np.pi) - np.pi
    chi2 = _chi2(poses, edges)
    weight = np.where(edges.loop & (chi2 > cfg.outlier_chi2), 0.0, 1.0)
    return Solution(poses, chi2, weight, nfev)
