"""The paper's evaluation of predicted against segmented planes (Gostar et al., Sensors 2019, sec. 5, Tables 1-6).

Planes segmented at frame k (vehicle frame) are carried to frame k+1 by the
plane transition of eq. 35 -- their parameters by ``beta^T M`` with
``M = R_k^{-1} R_{k+1}``, their outlines by ``r_{k+1} = R_{k+1}^{-1} R_k r_k``
(eq. 31) -- and compared with the planes segmented at k+1:

* **plane area** of the predicted plane and of its segmented counterpart;
* **vertex distance**: each of the predicted plane's four vertices (the
  smallest enclosing rectangle of its outline) to the closest vertex of the
  segmented plane's rectangle;
* **normal angle** between the two normals.

Pairs are formed by an optimal assignment on the normal angle and offset
within gates. The same measures against the simulator's true planes say how
much of the difference is the segmentation's and how much the transition's.
"""

from __future__ import annotations

import numpy as np
import pandas as pd
from scipy.optimize import linear_sum_assignment

from detectors.geometry3d import beta_from_hesse, hesse_from_beta, normal_angle, orient_away, pose_matrix, pose_matrix_inverse, transform_points


def transition(pose_k: np.ndarray, pose_k1: np.ndarray, height: float) -> np.ndarray:
    """M = R_k^{-1} R_{k+1} (eq. 35) between two planar sensor poses at ``height`` (the sensor frames)."""
    return pose_matrix_inverse(pose_k, height) @ pose_matrix(pose_k1, height)


def predict(normal: np.ndarray, offset: np.ndarray, rect: np.ndarray, m: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Planes (n (L, 3), d (L,)) and their rectangles (L, 4, 3) at k carried to k+1 by M (4, 4): eqs. 35 and 31."""
    b1 = beta_from_hesse(normal, offset) @ m
    n1, d1 = orient_away(*hesse_from_beta(b1))
    r1 = transform_points(rect.reshape(-1, 3), np.linalg.inv(m)).reshape(rect.shape)
    return n1, d1, r1


def vertex_distances(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(4,) each vertex of rectangle a (4, 3) to the closest vertex of rectangle b (4, 3)."""
    return np.linalg.norm(a[:, None, :] - b[None, :, :], axis=-1).min(axis=1)


def pair_planes(n_a, d_a, n_b, d_b, *, gate_angle_deg: float = 10.0, gate_offset: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
    """Indices (i, j) of the optimal one-to-one pairing of planes a and b within the gates (cost: angle in
    degrees plus offset difference in decimetres)."""
    if len(d_a) == 0 or len(d_b) == 0:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    ang = np.degrees(normal_angle(n_a[:, None, :], n_b[None, :, :]))
    dd = np.abs(np.asarray(d_a)[:, None] - np.asarray(d_b)[None, :])
    ok = (ang <= gate_angle_deg) & (dd <= gate_offset)
    cost = np.where(ok, ang + 10.0 * dd, 1e6)
    i, j = linear_sum_assignment(cost)
    keep = ok[i, j]
    return i[keep], j[keep]


def compare(pred_n, pred_d, pred_rect, pred_area, seg_n, seg_d, seg_rect, seg_area, **gates) -> pd.DataFrame:
    """One row per pair of predicted and segmented planes: areas, the four vertex distances, normal angle, offsets."""
    i, j = pair_planes(pred_n, pred_d, seg_n, seg_d, **gates)
    rows = []
    for a, b in zip(i, j, strict=True):
        vd = vertex_distances(pred_rect[a], seg_rect[b])
        rows.append(
            {
                "predicted": int(a), "segmented": int(b), "area_predicted": float(pred_area[a]), "area_segmented": float(seg_area[b]),
                **{f"vertex_{q + 1}_m": float(vd[q]) for q in range(4)},
                "normal_angle_deg": float(np.degrees(normal_angle(pred_n[a], seg_n[b]))),
                "offset_predicted": float(pred_d[a]), "offset_segmented": float(seg_d[b]),
            }
        )
    return pd.DataFrame(rows)
