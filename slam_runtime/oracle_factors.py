"""The factors of the batch oracle's least-squares problem (:mod:`slam_runtime.oracle`): residuals and Jacobians
of odometry between consecutive poses (pose increments; the rear-axle bicycle of Ackermann controls) and of
range-bearing measurements between a pose and a landmark, whitened by their noise, as dense blocks
(:class:`Blocks`) the solver assembles into the sparse information matrix.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from detectors.sensor_log import wrap_angle

#: the dynamics of Ackermann controls are constraints, kept to this residual scale [m, rad]
STIFF = 1e-5

class Blocks:
    """Rows of a sparse Jacobian and the whitened residuals, added a factor type at a time."""

    def __init__(self) -> None:
        self.rows: list[np.ndarray] = []
        self.cols: list[np.ndarray] = []
        self.vals: list[np.ndarray] = []
        self.res: list[np.ndarray] = []
        self.n = 0

    def add(self, r: np.ndarray, entries) -> None:
        ri = self.n + np.arange(r.size)
        for c, v in entries:
            self.rows.append(ri)
            self.cols.append(np.asarray(c))
            self.vals.append(np.broadcast_to(np.asarray(v, dtype=np.float64), (r.size,)))
        self.res.append(r)
        self.n += r.size

    def build(self, nv: int) -> tuple[sp.csr_matrix, np.ndarray]:
        jac = sp.csr_matrix(
            (np.concatenate(self.vals), (np.concatenate(self.rows), np.concatenate(self.cols))), shape=(self.n, nv)
        )
        return jac, np.concatenate(self.res)


def bicycle(x: np.ndarray, u: np.ndarray, dt: float, wb: float) -> np.ndarray:
    v, s = u
    return np.array([x[0] + dt * v * np.cos(x[2]), x[1] + dt * v * np.sin(x[2]), wrap_angle(x[2] + dt * v / wb * np.tan(s))])


def increment_factors(b: Blocks, x: np.ndarray, odo: np.ndarray, sig: np.ndarray) -> None:
    """relative(x_{k-1}, x_k) - odo_k, whitened by sig (3,), for k = 1..N-1."""
    a, c = x[:-1], x[1:]
    co, si = np.cos(a[:, 2]), np.sin(a[:, 2])
    dx, dy = c[:, 0] - a[:, 0], c[:, 1] - a[:, 1]
    u = odo[1:]
    ia = 3 * np.arange(x.shape[0] - 1)
    ib = ia + 3
    sx, sy, st = sig
    b.add(
        (co * dx + si * dy - u[:, 0]) / sx,
        [(ia, -co / sx), (ia + 1, -si / sx), (ia + 2, (-si * dx + co * dy) / sx), (ib, co / sx), (ib + 1, si / sx)],
    )
    b.add(
        (-si * dx + co * dy - u[:, 1]) / sy,
        [(ia, si / sy), (ia + 1, -co / sy), (ia + 2, (-co * dx - si * dy) / sy), (ib, -si / sy), (ib + 1, co / sy)],
    )
    b.add(wrap_angle(c[:, 2] - a[:, 2] - u[:, 2]) / st, [(ia + 2, -1.0 / st), (ib + 2, 1.0 / st)])


def ackermann_factors(b: Blocks, x, ctrl, odo, dts, wb, sig, off) -> None:
    """The controls' prior (logged reading - control, whitened by sig (2,)) and the bicycle dynamics as stiff
    constraints x_{k+1} = f(x_k, u_k)."""
    sv, ss = sig
    k = np.arange(ctrl.shape[0])
    ix, ic = 3 * k, off + 2 * k
    b.add((ctrl[:, 0] - odo[:, 0]) / sv, [(ic, 1.0 / sv)])
    b.add(wrap_angle(ctrl[:, 1] - odo[:, 1]) / ss, [(ic + 1, 1.0 / ss)])
    th, v, s = x[:-1, 2], ctrl[:, 0], ctrl[:, 1]
    co, si, t = np.cos(th), np.sin(th), np.tan(s)
    f = x[:-1] + np.column_stack([dts * v * co, dts * v * si, dts * v / wb * t])
    r = x[1:] - f
    r[:, 2] = wrap_angle(r[:, 2])
    e = STIFF
    b.add(r[:, 0] / e, [(ix + 3, 1 / e), (ix, -1 / e), (ix + 2, dts * v * si / e), (ic, -dts * co / e)])
    b.add(r[:, 1] / e, [(ix + 4, 1 / e), (ix + 1, -1 / e), (ix + 2, -dts * v * co / e), (ic, -dts * si / e)])
    b.add(r[:, 2] / e, [(ix + 5, 1 / e), (ix + 2, -1 / e), (ic, -dts / wb * t / e), (ic + 1, -dts * v / wb / np.cos(s) ** 2 / e)])


def range_bearing_factors(b: Blocks, x, lm, k_of, lj, zr, zb, sr, sb, off, w=None) -> None:
    """Range and bearing of landmark lj from pose k_of, whitened by (sr, sb); with w (per pair), each pair's
    rows scaled by sqrt(w) (its squared residual weighted by w)."""
    if w is not None:
        root = np.sqrt(w)
        sr, sb = sr / root, sb / root
    q = lm[lj] - x[k_of, :2]
    q2 = np.maximum((q**2).sum(axis=1), 1e-12)
    r = np.sqrt(q2)
    ip, il = 3 * k_of, off + 2 * lj
    b.add(
        (r - zr) / sr, [(ip, -q[:, 0] / r / sr), (ip + 1, -q[:, 1] / r / sr), (il, q[:, 0] / r / sr), (il + 1, q[:, 1] / r / sr)]
    )
    bb = wrap_angle(np.arctan2(q[:, 1], q[:, 0]) - x[k_of, 2] - zb)
    b.add(
        bb / sb,
        [
            (ip, q[:, 1] / q2 / sb),
            (ip + 1, -q[:, 0] / q2 / sb),
            (ip + 2, -1.0 / sb),
            (il, -q[:, 1] / q2 / sb),
            (il + 1, q[:, 0] / q2 / sb),
        ],
    )


def range_bearing_jacobian(x, lm, k_of, lj, zr, zb, sr, sb, off) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The same factors as dense blocks: whitened residuals (M, 2), Jacobians (M, 2, 5) and their variable
    indices (M, 5): the pose's x, y, heading, the landmark's x, y."""
    b = Blocks()
    range_bearing_factors(b, x, lm, k_of, lj, zr, zb, sr, sb, off)
    m = k_of.size
    jac = np.zeros((m, 2, 5))
    # the entries in range_bearing_factors' order: range (x, y, lx, ly), bearing (x, y, heading, lx, ly)
    v = b.vals
    jac[:, 0, [0, 1, 3, 4]] = np.column_stack(v[:4])
    jac[:, 1, :] = np.column_stack(v[4:])
    cols = np.column_stack([3 * k_of, 3 * k_of + 1, 3 * k_of + 2, off + 2 * lj, off + 2 * lj + 1])
    return np.column_stack(b.res), jac, cols


def relative_pose_factors(b: Blocks, x: np.ndarray, inc: np.ndarray, whiten: np.ndarray) -> None:
    """relative(x_{k-1}, x_k) - inc_k for k = 1..N-1, whitened by whiten_k (N-1, 3, 3) (the inverse Cholesky factor
    of the increment's covariance, which may couple the axes): the odometry between the frames of a log."""
    a, c = x[:-1], x[1:]
    co, si = np.cos(a[:, 2]), np.sin(a[:, 2])
    dx, dy = c[:, 0] - a[:, 0], c[:, 1] - a[:, 1]
    r = np.column_stack([co * dx + si * dy - inc[:, 0], -si * dx + co * dy - inc[:, 1], wrap_angle(c[:, 2] - a[:, 2] - inc[:, 2])])
    zero = np.zeros_like(co)
    jac = np.stack(
        [
            np.column_stack([-co, -si, -si * dx + co * dy, co, si, zero]),
            np.column_stack([si, -co, -co * dx - si * dy, -si, co, zero]),
            np.column_stack([zero, zero, zero - 1.0, zero, zero, zero + 1.0]),
        ],
        axis=1,
    )  # (N-1, 3, 6): d(r)/d(x_{k-1}, x_k)
    rw = np.einsum("kij,kj->ki", whiten, r)
    jw = np.einsum("kij,kjl->kil", whiten, jac)
    ia = 3 * np.arange(x.shape[0] - 1)
    cols = ia[:, None] + np.arange(6)[None, :]
    for i in range(3):
        b.add(rw[:, i], [(cols[:, q], jw[:, i, q]) for q in range(6)])
