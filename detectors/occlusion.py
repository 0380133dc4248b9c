"""Compiled occlusion test between the point features of detection-level maps.

Used by :meth:`detectors.model.DetectionModel.pd_features` when the profile
gives the occluders a radius (the n_p idea on a detection-level log): a
feature whose centre lies behind a nearer confirmed feature, within that
trunk's angular half-width, is hidden; one within the half-width widened by a
margin is in the buffer zone. Kept apart from :mod:`detectors.model` so that
calibration, which never needs it, does not import numba.
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
