"""The Gaussian pose proposal every map filter shares (FastSLAM 2.0; the optimal proposal of PHD-SLAM 2.0/3.0).

Each particle's motion prior N(xbar, q) is updated by the frame's measurements
that its map explains, each by its likeliest feature when that feature takes
at least ``share`` of it (w P_D g(z) against kappa(z) + the sum over features,
g with the prior's pose uncertainty in its covariance: Montemerlo et al.
2003's data-association covariance R + H_m P H_m^T + H_x q H_x^T), with an
iterated EKF that re-linearises ``iterations`` times; the update itself uses
R + H_m P H_m^T. RB-PHD (features weighted w P_D) and the labelled filters
(tracks weighted r P_D) prepare the features and call :func:`pose_proposal`.

Two implementations give the same numbers (to rounding; ``tests/slam_runtime/
test_proposal.py`` checks them against each other):

* the hot path, range-bearing point landmarks with one measurement noise for
  the whole frame, is compiled (numba): the association is a loop over
  (feature, measurement) pairs of one particle, and numpy's version of it
  builds (P, J, M, 2, 2) covariances that differ only in their (J) part
  (the compiled pass's speed: ``benchmarks/bench_slam.py``, docs/results.md);
* every other feature model (planes) and per-measurement noise go through
  numpy, batched over particles, features and measurements.

A particle whose map explains no measurement keeps its motion prior exactly
(mean xbar, covariance q), so its weight correction prior / proposal is 0.

The update is in information form, so q is inverted after adding 1e-12 to its
diagonal: a rank-deficient prior (Ackermann odometry of one control row has no
sideways motion) then allows 1e-6 m of it, and the two implementations agree
to 1e-8 to 1e-7 m there instead of to rounding.
"""

from __future__ import annotations

import numba
import numpy as np

from profiles.errors import UsageError
from slam_runtime.features import FeatureModel, RangeBearing
from slam_runtime.gm import det, inv, matmul, quad, transpose
from slam_runtime.kernels import wrap_scalar

TWO_PI = 2.0 * np.pi


def pose_proposal(
    fm: FeatureModel,
    xbar: np.ndarray,
    q: np.ndarray,
    z: np.ndarray,
    rz: np.ndarray,
    r_const: np.ndarray | None,
    mu: np.ndarray,
    cov: np.ndarray,
    weight: np.ndarray,
    kappa: np.ndarray,
    *,
    gate: float,
    share: float = 0.5,
    iterations: int = 3,
    ident: np.ndarray | None = None,
    ident_z: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Mean (P, 3), covariance (P, 3, 3) and number of measurements used (P,) of each particle's pose proposal.

    xbar (P, 3), q (P, 3, 3): the motion prior (vehicle poses, world frame); z (M, dz) the frame's
    measurements (sensor frame), rz (M, dz, dz) their noise; r_const (dz, dz) that noise when it is the same
    for every measurement (else None); mu (P, J, dx), cov (P, J, dx, dx): each particle's map features, world
    frame; weight (P, J): their weight (or existence) times P_D, 0 for a feature the sensor cannot see or an
    empty slot; kappa (M,) the clutter intensity of each measurement (divided by its descriptor ratio, if any).
    Only the features of positive weight take part (gathered first, in their order). ident (P, J) and ident_z (M,):
    the features' and the measurements' identities (:func:`identity_match`), or None; with them, the numpy path.
    """
    if iterations < 1:
        raise UsageError(f"pose proposal: iterations must be at least 1, not {iterations}")
    p, m = xbar.shape[0], z.shape[0]
    seen = weight > 0
    js = int(seen.sum(axis=1).max()) if weight.shape[1] else 0
    if m == 0 or js == 0:
        return xbar, q, np.zeros(p, dtype=np.int64)
    rows = np.arange(p)[:, None]
    sel = np.argsort(~seen, axis=1, kind="stable")[:, :js]  # (P, Js) the seen features first
    mu_s, cov_s, w_s = mu[rows, sel], cov[rows, sel], np.where(seen[rows, sel], weight[rows, sel], 0.0)
    if ident is not None and ident_z is not None:
        return pose_proposal_numpy(fm, xbar, q, z, rz, mu_s, cov_s, w_s, kappa, gate=gate, share=share, iterations=iterations, match=identity_match(ident[rows, sel], ident_z))
    if type(fm) is RangeBearing and r_const is not None:  # exactly this model: a subclass may measure otherwise
        return _compiled(
            np.ascontiguousarray(xbar, dtype=np.float64),
            np.ascontiguousarray(q, dtype=np.float64),
            np.ascontiguousarray(z, dtype=np.float64),
            np.ascontiguousarray(r_const, dtype=np.float64),
            np.ascontiguousarray(fm.mount, dtype=np.float64),
            np.ascontiguousarray(mu_s, dtype=np.float64),
            np.ascontiguousarray(cov_s, dtype=np.float64),
            np.ascontiguousarray(w_s, dtype=np.float64),
            np.ascontiguousarray(kappa, dtype=np.float64),
            float(gate),
            float(share),
            int(iterations),
        )
    return pose_proposal_numpy(fm, xbar, q, z, rz, mu_s, cov_s, w_s, kappa, gate=gate, share=share, iterations=iterations)


def identity_match(ident: np.ndarray, ident_z: np.ndarray) -> np.ndarray:
    """(P, J, M) bool: which features (identities ident (P, J)) may have made which measurements (identities ident_z
    (M,)): the same identity, or either reads none (-1). A detection is explained by a feature born of its own
    identity or by clutter; a misread barcode is clutter, as the calibration's labels count it."""
    return (ident[:, :, None] == ident_z[None, None, :]) | (ident[:, :, None] < 0) | (ident_z[None, None, :] < 0)


def pose_proposal_numpy(fm, xbar, q, z, rz, mu_s, cov_s, w_s, kappa, *, gate: float, share: float = 0.5, iterations: int = 3, match=None):
    """:func:`pose_proposal` for any feature model, batched in numpy (the reference of the compiled path); match
    (P, Js, M) bool: the pairs the identities allow (None: every pair)."""
    p, m = xbar.shape[0], z.shape[0]
    dz = fm.dim_z
    sp = fm.sensor_pose(xbar)
    zhat, hl = fm.predict_sensor(sp[:, None, :], mu_s)
    s_pair = matmul(hl, matmul(cov_s, transpose(hl)))[:, :, None] + rz[None, None]  # (P, Js, M, dz, dz)
    hx0 = fm.pose_jacobian(xbar[:, None, :], mu_s)  # (P, Js, dz, 3)
    s_assoc = s_pair + matmul(hx0, matmul(q[:, None], transpose(hx0)))[:, :, None]
    nu = fm.innovation(z[None, None], zhat[:, :, None])
    m2 = quad(inv(s_assoc), nu)
    lik = (
        np.where(m2 <= gate, np.exp(-0.5 * m2) / np.sqrt((2 * np.pi) ** dz * np.maximum(det(s_assoc), 1e-300)), 0.0)
        * w_s[..., None]
    )
    if match is not None:
        lik = np.where(match, lik, 0.0)
    best = np.argmax(lik, axis=1)  # (P, M) the likeliest feature of each measurement
    lb = np.take_along_axis(lik, best[:, None, :], axis=1)[:, 0]
    use = lb > share * (kappa[None, :] + lik.sum(axis=1))  # (P, M)
    n_used = use.sum(axis=1)
    if not use.any():
        return xbar, q, n_used
    rm = np.arange(p)[:, None]
    mu_b = mu_s[rm, best]  # (P, M, dx)
    s_inv = np.where(use[..., None, None], inv(s_pair[rm, best, np.arange(m)[None, :]]), 0.0)
    q_inv = np.linalg.inv(q + np.eye(3) * 1e-12)
    x, cov = xbar.copy(), q
    for _ in range(iterations):
        zh, _ = fm.predict(x[:, None, :], mu_b)
        hx = fm.pose_jacobian(x[:, None, :], mu_b)  # (P, M, dz, 3)
        r = fm.innovation(np.broadcast_to(z, zh.shape).copy(), zh)
        dx = x - xbar
        dx[:, 2] = np.mod(dx[:, 2] + np.pi, TWO_PI) - np.pi
        r = r + (hx @ dx[:, None, :, None])[..., 0]  # iterated EKF: linearise at x, expand about xbar
        hts = transpose(hx) @ s_inv  # (P, M, 3, dz)
        cov = np.linalg.inv(q_inv + (hts @ hx).sum(axis=1))
        x = xbar + (cov @ (hts @ r[..., None]).sum(axis=1))[..., 0]
        x[:, 2] = np.mod(x[:, 2] + np.pi, TWO_PI) - np.pi
    cov = 0.5 * (cov + transpose(cov))
    none = n_used == 0  # no measurement explained: the motion prior itself
    x[none], cov[none] = xbar[none], q[none]
    return x, cov, n_used


@numba.njit(cache=True, nogil=True)
def _mod_wrap(a):
    b = a + np.pi
    return b - TWO_PI * np.floor(b / TWO_PI) - np.pi


@numba.njit(cache=True, nogil=True)
def _inv3(a, out):
    c00 = a[1, 1] * a[2, 2] - a[1, 2] * a[2, 1]
    c01 = a[1, 2] * a[2, 0] - a[1, 0] * a[2, 2]
    c02 = a[1, 0] * a[2, 1] - a[1, 1] * a[2, 0]
    d = a[0, 0] * c00 + a[0, 1] * c01 + a[0, 2] * c02
    out[0, 0] = c00 / d
    out[1, 0] = c01 / d
    out[2, 0] = c02 / d
    out[0, 1] = (a[0, 2] * a[2, 1] - a[0, 1] * a[2, 2]) / d
    out[1, 1] = (a[0, 0] * a[2, 2] - a[0, 2] * a[2, 0]) / d
    out[2, 1] = (a[0, 1] * a[2, 0] - a[0, 0] * a[2, 1]) / d
    out[0, 2] = (a[0, 1] * a[1, 2] - a[0, 2] * a[1, 1]) / d
    out[1, 2] = (a[0, 2] * a[1, 0] - a[0, 0] * a[1, 2]) / d
    out[2, 2] = (a[0, 0] * a[1, 1] - a[0, 1] * a[1, 0]) / d


@numba.njit(cache=True, nogil=True)
def _observe(x, mount, lx, ly, hx):
    """Predicted (range, bearing) of landmark (lx, ly) from vehicle pose x, and d z / d pose into hx (2, 3)."""
    c, s = np.cos(x[2]), np.sin(x[2])
    spx = x[0] + c * mount[0] - s * mount[1]
    spy = x[1] + s * mount[0] + c * mount[1]
    dx, dy = lx - spx, ly - spy
    qq = max(dx * dx + dy * dy, 1e-12)
    rr = np.sqrt(qq)
    h00, h01, h10, h11 = dx / rr, dy / rr, -dy / qq, dx / qq
    dsx = -s * mount[0] - c * mount[1]
    dsy = c * mount[0] - s * mount[1]
    hx[0, 0], hx[0, 1], hx[0, 2] = -h00, -h01, -(h00 * dsx + h01 * dsy)
    hx[1, 0], hx[1, 1], hx[1, 2] = -h10, -h11, -(h10 * dsx + h11 * dsy) - 1.0
    return rr, wrap_scalar(np.arctan2(dy, dx) - (x[2] + mount[2])), h00, h01, h10, h11


@numba.njit(cache=True, nogil=True)
def _compiled(xbar, q, z, r, mount, mu, cov, w, kappa, gate, share, iterations):
    """:func:`pose_proposal` for range-bearing point landmarks and one noise r (2, 2) for the frame, a loop per
    particle: xbar (P, 3), q (P, 3, 3), z (M, 2), mount (3,), mu (P, J, 2), cov (P, J, 2, 2) (symmetric: the
    [1, 0] entries are not read), w (P, J) weight x P_D (0: padding), kappa (M,); iterations >= 1."""
    p, js = w.shape
    m = z.shape[0]
    x_out = xbar.copy()
    cov_out = q.copy()
    n_used = np.zeros(p, np.int64)
    norm = 1.0 / (2.0 * np.pi)
    zr = np.empty(js)
    zb = np.empty(js)
    si = np.empty((js, 3))  # S^-1, S = R + H_m P H_m^T (the update's): i00, i01, i11
    sa = np.empty((js, 4))  # (S + H_x q H_x^T)^-1 (association): i00, i01, i11, and the density's factor
    hx = np.empty((2, 3))
    best_j = np.empty(m, np.int64)
    qinv = np.empty((3, 3))
    info = np.empty((3, 3))
    cv = np.empty((3, 3))
    b = np.empty(3)
    for i in range(p):
        for j in range(js):
            if w[i, j] <= 0.0:
                continue
            rr, bb, h00, h01, h10, h11 = _observe(xbar[i], mount, mu[i, j, 0], mu[i, j, 1], hx)
            zr[j], zb[j] = rr, bb
            c00, c01, c11 = cov[i, j, 0, 0], cov[i, j, 0, 1], cov[i, j, 1, 1]
            a00 = h00 * c00 + h01 * c01
            a01 = h00 * c01 + h01 * c11
            a10 = h10 * c00 + h11 * c01
            a11 = h10 * c01 + h11 * c11
            s00 = a00 * h00 + a01 * h01 + r[0, 0]
            s01 = a00 * h10 + a01 * h11 + r[0, 1]
            s11 = a10 * h10 + a11 * h11 + r[1, 1]
            dd = s00 * s11 - s01 * s01
            dd = dd if abs(dd) > 1e-300 else 1e-300
            si[j, 0], si[j, 1], si[j, 2] = s11 / dd, -s01 / dd, s00 / dd
            # + H_x q H_x^T
            t00 = t01 = t11 = 0.0
            for u in range(3):
                g0 = hx[0, 0] * q[i, 0, u] + hx[0, 1] * q[i, 1, u] + hx[0, 2] * q[i, 2, u]
                g1 = hx[1, 0] * q[i, 0, u] + hx[1, 1] * q[i, 1, u] + hx[1, 2] * q[i, 2, u]
                t00 += g0 * hx[0, u]
                t01 += g0 * hx[1, u]
                t11 += g1 * hx[1, u]
            e00, e01, e11 = s00 + t00, s01 + t01, s11 + t11
            d = e00 * e11 - e01 * e01
            dd = d if abs(d) > 1e-300 else 1e-300
            sa[j, 0], sa[j, 1], sa[j, 2] = e11 / dd, -e01 / dd, e00 / dd
            sa[j, 3] = norm / np.sqrt(max(d, 1e-300))
        used = 0
        for k in range(m):
            top, top_j, tot = 0.0, 0, 0.0
            for j in range(js):
                if w[i, j] <= 0.0:
                    continue
                n0 = z[k, 0] - zr[j]
                n1 = wrap_scalar(z[k, 1] - zb[j])
                m2 = sa[j, 0] * n0 * n0 + 2.0 * sa[j, 1] * n0 * n1 + sa[j, 2] * n1 * n1
                if m2 <= gate:
                    lik = np.exp(-0.5 * m2) * sa[j, 3] * w[i, j]
                    tot += lik
                    if lik > top:
                        top, top_j = lik, j
            if top > share * (kappa[k] + tot):
                best_j[used] = top_j + js * k  # the measurement and its feature in one index
                used += 1
        n_used[i] = used
        if used == 0:
            continue
        qreg = q[i].copy()
        for u in range(3):
            qreg[u, u] += 1e-12
        _inv3(qreg, qinv)
        x = xbar[i].copy()
        for _ in range(iterations):
            info[:, :] = qinv
            b[:] = 0.0
            d0, d1, d2 = x[0] - xbar[i, 0], x[1] - xbar[i, 1], _mod_wrap(x[2] - xbar[i, 2])
            for u in range(used):
                k, j = divmod(best_j[u], js)
                rr, bb, _, _, _, _ = _observe(x, mount, mu[i, j, 0], mu[i, j, 1], hx)
                i00, i01, i11 = si[j, 0], si[j, 1], si[j, 2]
                r0 = z[k, 0] - rr + hx[0, 0] * d0 + hx[0, 1] * d1 + hx[0, 2] * d2
                r1 = wrap_scalar(z[k, 1] - bb) + hx[1, 0] * d0 + hx[1, 1] * d1 + hx[1, 2] * d2
                for a in range(3):
                    ga0 = hx[0, a] * i00 + hx[1, a] * i01  # (H_x^T S^-1)[a, :]
                    ga1 = hx[0, a] * i01 + hx[1, a] * i11
                    b[a] += ga0 * r0 + ga1 * r1
                    for c in range(3):
                        info[a, c] += ga0 * hx[0, c] + ga1 * hx[1, c]
            _inv3(info, cv)
            for a in range(3):
                x[a] = xbar[i, a] + cv[a, 0] * b[0] + cv[a, 1] * b[1] + cv[a, 2] * b[2]
            x[2] = _mod_wrap(x[2])
        x_out[i] = x
        for a in range(3):
            for c in range(3):
                cov_out[i, a, c] = 0.5 * (cv[a, c] + cv[c, a])
    return x_out, cov_out, n_used
