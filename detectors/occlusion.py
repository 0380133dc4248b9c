"""Compiled occlusion test between the point features of detection-level maps.

Used by :meth:`detectors.model.DetectionModel.pd_features` when the profile
gives the occluders a radius (the n_p idea on a detection-level log): a
feature whose centre lies behind a nearer confirmed feature, within that
trunk's angular half-width, is hidden; one within the half-width widened by a
margin is in the buffer zone. Also the line-of-sight geometry of point features
that P_D starts from (:func:`line_of_sight`). Kept apart from
:mod:`detectors.model` so that calibration, which never needs it, does not
import numba.
"""

from __future__ import annotations

import numba
import numpy as np


@numba.njit(cache=True, nogil=True)
def occlusion_flags(r, b, occluder, in_view, half, margin, radius):  # pragma: no cover - compiled
    """hidden, near (P, J) of features at ranges r and bearings b (P, J) [world frame].

    occluder (P, J): the features that can hide others; in_view (P, J): the ones
    tested; half (P, J): each occluder's angular half-width; margin (P, J): each
    feature's angular buffer margin. Feature k hides feature i when k is nearer
    by more than 2 radius and their bearings differ by less than k's half-width
    (the same test as the vectorised form in the tests, one pair at a time,
    stopping at the first occluder that hides)."""
    p, j = r.shape
    hidden = np.zeros((p, j), dtype=np.bool_)
    near = np.zeros((p, j), dtype=np.bool_)
    two_pi = 2.0 * np.pi
    for a in range(p):
        for i in range(j):
            if not in_view[a, i]:
                continue
            hid = False
            nr = False
            limit = r[a, i] - 2.0 * radius
            for k in range(j):
                if not occluder[a, k] or not r[a, k] < limit:
                    continue
                d = b[a, i] - b[a, k]
                if d > np.pi:
                    d -= two_pi
                elif d <= -np.pi:
                    d += two_pi
                d = abs(d)
                if d < half[a, k]:
                    hid = True
                    break
                if d < half[a, k] + margin[a, i]:
                    nr = True
            hidden[a, i] = hid
            near[a, i] = nr and not hid
    return hidden, near


@numba.njit(cache=True, nogil=True)
def line_of_sight(sp, mu, cov):  # pragma: no cover - compiled
    """Of point features mu (P, J, 2) with covariances cov (P, J, 2, 2) seen from sensor poses sp (P, 3): range and
    bearing z (P, J, 2) (range floored at 1e-9 m, bearing wrapped to (-pi, pi]), and the position's standard
    deviation along (s_rad) and across (s_lat) the line of sight (P, J)."""
    p, j = mu.shape[0], mu.shape[1]
    z = np.empty((p, j, 2))
    s_rad = np.empty((p, j))
    s_lat = np.empty((p, j))
    for i in range(p):
        for k in range(j):
            lx, ly = mu[i, k, 0] - sp[i, 0], mu[i, k, 1] - sp[i, 1]
            rr = max(np.hypot(lx, ly), 1e-9)
            b = np.arctan2(ly, lx) - sp[i, 2]
            if b > np.pi:
                b -= 2 * np.pi
            if b <= -np.pi:
                b += 2 * np.pi
            z[i, k, 0], z[i, k, 1] = rr, b
            ux, uy = lx / rr, ly / rr
            c00, c01, c11 = cov[i, k, 0, 0], cov[i, k, 0, 1], cov[i, k, 1, 1]
            s_rad[i, k] = np.sqrt(max(ux**2 * c00 + 2 * ux * uy * c01 + uy**2 * c11, 0.0))
            s_lat[i, k] = np.sqrt(max(uy**2 * c00 - 2 * ux * uy * c01 + ux**2 * c11, 0.0))
    return z, s_rad, s_lat
