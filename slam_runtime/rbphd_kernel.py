"""RB-PHD's map update for point features under one measurement noise, compiled: every particle in one call.

:meth:`slam_runtime.rbphd.RBPHD.update` runs this kernel in place of its numpy
batch when the features are range-bearing points and every measurement has
the filter's noise (no per-measurement covariance); the numbers are the
batch's (``tests/slam_runtime/test_rbphd_kernel.py`` compares them), the cost
at small particle counts is not: the batch makes some sixty numpy calls per
step whatever the particle count, which at 10 particles cost more than the
arithmetic. The equations (Inostroza 2015, eqs. 3.17-3.18 and 3.21) are the
batch's, see :mod:`slam_runtime.rbphd`.
"""

from __future__ import annotations

import math

import numba
import numpy as np

from slam_runtime.kernels import wrap_scalar

TWO_PI = 2.0 * math.pi


@numba.njit(cache=True, nogil=True)
def update_points(w, mu, cov, pd, buf, sp, z, r, kappa, gate, prune):  # pragma: no cover - compiled
    """The PHD update of every particle's mixture with one frame's range-bearing measurements.

    w (P, J), mu (P, J, 2) [m, world], cov (P, J, 2, 2): the predicted mixtures; pd (P, J) P_D, buf (P, J) the
    buffer-zone flags (False for this step's births); sp (P, 3) sensor poses; z (M, 2) (range [m], bearing [rad]);
    r (2, 2) the noise; kappa (M,) the clutter intensity; gate: squared Mahalanobis distance; prune: the weight
    under which an updated pair is not formed. Returns

    * missed (P, J): the missed-detection weights (eq. 3.17, with the buffer zone's floor, eq. 3.21);
    * w_kept (P, K), mu_kept (P, K, 2), cov_kept (P, K, 2, 2), j_kept (P, K): the detection-updated components of
      weight above ``prune`` (eq. 3.18), in the order of (component, measurement), zero weight past each particle's
      own count; j_kept the component each came from;
    * den (P, M): kappa(z) + sum_j P_D w_j q_j(z); wsum (P, M): the share of each measurement the map took.
    """
    p, j = w.shape
    m = z.shape[0]
    missed = w.copy()
    den = np.empty((p, m))
    wsum = np.zeros((p, m))
    # per (particle, component, measurement) scratch: the pair's weight and the component's innovation moments
    wdet = np.zeros((p, j, m))
    sinv = np.empty((p, j, 4))  # S^-1 (00, 01, 10, 11)
    ph = np.empty((p, j, 2, 2))  # P H^T
    zhat = np.empty((p, j, 2))
    count = np.zeros(p, np.int64)
    norm = TWO_PI**2  # the normal density's (2 pi)^dz
    for i in range(p):
        for mm in range(m):
            den[i, mm] = 0.0
        for k in range(j):
            if not (pd[i, k] > 0.0 and w[i, k] > 0.0):
                continue
            dx = mu[i, k, 0] - sp[i, 0]
            dy = mu[i, k, 1] - sp[i, 1]
            q = max(dx * dx + dy * dy, 1e-12)
            rr = math.sqrt(q)
            zhat[i, k, 0] = rr
            zhat[i, k, 1] = wrap_scalar(math.atan2(dy, dx) - sp[i, 2])
            h00, h01, h10, h11 = dx / rr, dy / rr, -dy / q, dx / q
            c = cov[i, k]
            # P H^T (2, 2), H P H^T + R
            p00 = c[0, 0] * h00 + c[0, 1] * h01
            p01 = c[0, 0] * h10 + c[0, 1] * h11
            p10 = c[1, 0] * h00 + c[1, 1] * h01
            p11 = c[1, 0] * h10 + c[1, 1] * h11
            ph[i, k, 0, 0], ph[i, k, 0, 1], ph[i, k, 1, 0], ph[i, k, 1, 1] = p00, p01, p10, p11
            s00 = h00 * p00 + h01 * p10 + r[0, 0]
            s01 = h00 * p01 + h01 * p11 + r[0, 1]
            s10 = h10 * p00 + h11 * p10 + r[1, 0]
            s11 = h10 * p01 + h11 * p11 + r[1, 1]
            dt = s00 * s11 - s01 * s10
            dd = dt if abs(dt) > 1e-300 else 1e-300
            i00, i01, i10, i11 = s11 / dd, -s01 / dd, -s10 / dd, s00 / dd
            sinv[i, k, 0], sinv[i, k, 1], sinv[i, k, 2], sinv[i, k, 3] = i00, i01, i10, i11
            g0 = math.sqrt(norm * max(dt, 1e-300))
            a = pd[i, k] * w[i, k]
            for mm in range(m):
                x = z[mm, 0] - zhat[i, k, 0]
                y = wrap_scalar(z[mm, 1] - zhat[i, k, 1])  # the numpy pairs' features.wrap
                m2 = i00 * x * x + 2.0 * i01 * x * y + i11 * y * y
                if m2 <= gate:
                    wdet[i, k, mm] = a * (math.exp(-0.5 * m2) / g0)
                    den[i, mm] += wdet[i, k, mm]
        for mm in range(m):
            den[i, mm] += kappa[mm]
        for k in range(j):
            if not (pd[i, k] > 0.0 and w[i, k] > 0.0):
                continue
            gained = 0.0
            for mm in range(m):
                dd = den[i, mm] if den[i, mm] > 0.0 else 1.0
                wdet[i, k, mm] /= dd
                gained += wdet[i, k, mm]
                wsum[i, mm] += wdet[i, k, mm]
                if wdet[i, k, mm] > prune:
                    count[i] += 1
            ms = (1.0 - pd[i, k]) * w[i, k]
            protect = min(w[i, k], 1.0)
            if buf[i, k] and gained + ms < protect:
                ms = protect - gained
            missed[i, k] = ms
    kmax = 0
    for i in range(p):
        kmax = max(kmax, count[i])
    w_kept = np.zeros((p, kmax))
    mu_kept = np.zeros((p, kmax, 2))
    cov_kept = np.zeros((p, kmax, 2, 2))
    j_kept = np.zeros((p, kmax), np.int64)
    for i in range(p):
        n = 0
        for k in range(j):
            if not (pd[i, k] > 0.0 and w[i, k] > 0.0):
                continue
            for mm in range(m):
                if not (wdet[i, k, mm] > prune):
                    continue
                x = z[mm, 0] - zhat[i, k, 0]
                y = wrap_scalar(z[mm, 1] - zhat[i, k, 1])  # the numpy pairs' features.wrap
                i00, i01, i10, i11 = sinv[i, k, 0], sinv[i, k, 1], sinv[i, k, 2], sinv[i, k, 3]
                p00, p01, p10, p11 = ph[i, k, 0, 0], ph[i, k, 0, 1], ph[i, k, 1, 0], ph[i, k, 1, 1]
                k00 = p00 * i00 + p01 * i10  # K = P H^T S^-1
                k01 = p00 * i01 + p01 * i11
                k10 = p10 * i00 + p11 * i10
                k11 = p10 * i01 + p11 * i11
                mu_kept[i, n, 0] = mu[i, k, 0] + (k00 * x + k01 * y)
                mu_kept[i, n, 1] = mu[i, k, 1] + (k10 * x + k11 * y)
                c = cov[i, k]
                c00 = c[0, 0] - (k00 * p00 + k01 * p01)  # P - K (P H^T)^T
                c01 = c[0, 1] - (k00 * p10 + k01 * p11)
                c10 = c[1, 0] - (k10 * p00 + k11 * p01)
                c11 = c[1, 1] - (k10 * p10 + k11 * p11)
                cov_kept[i, n, 0, 0] = 0.5 * (c00 + c00)
                cov_kept[i, n, 0, 1] = 0.5 * (c01 + c10)
                cov_kept[i, n, 1, 0] = 0.5 * (c10 + c01)
                cov_kept[i, n, 1, 1] = 0.5 * (c11 + c11)
                w_kept[i, n] = wdet[i, k, mm]
                j_kept[i, n] = k
                n += 1
    return missed, w_kept, mu_kept, cov_kept, j_kept, den, wsum
