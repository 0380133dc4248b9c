"""The map re-estimated along the estimated trajectory after a run (``map_refine: true``, off by default).

A particle filter builds each landmark of its map estimate from associations
chosen scan by scan, against the landmark as it was then; under heavy
clutter those early choices stay in the estimate (versions merged, a finite
set of sampled hypotheses). :func:`refine_map` solves the map again, after
the run, given the run's trajectory (the estimate's, held fixed) and every
scan's measurements, with the associations *not* given: each feature in view
at a scan contributes the exact single-feature likelihood of that scan,

    (1 - P_D) + P_D sum_j N(z_j; h(x, m), R_j) / kappa(z_j)

(probabilistic data association; the multi-object likelihood when no two
features compete for a measurement), P_D and kappa from the run's detection
model (the profile) and R from the run's measurement noise. The features'
positions are found by EM from the filter's own estimate (each iteration the
responsibilities of every gated (measurement, feature) pair, then one
Gauss-Newton step per feature); which features are in view at a scan (P_D >
0) is decided once, at the start. Features no measurement supports keep
their position; the features and their weights are the filter's.

It is a batch step over the whole run: a filter with a smoother after it.
The run's metrics keep the filter's own map OSPA beside the refined one
(``map_ospa_filter``). Point features only (range-bearing).
"""

from __future__ import annotations

import numpy as np

from slam_runtime.features import RangeBearing


def refine_map(
    mapfilter,
    poses: np.ndarray,
    frames: list,
    x0: np.ndarray,
    *,
    gate: float = 36.0,
    iterations: int = 100,
    tolerance: float = 1e-9,
) -> tuple[np.ndarray, int]:
    """The features x0 (K, 2) re-estimated along the vehicle poses (T, 3), one per frame of ``frames`` (T
    :class:`slam_runtime.mapfilter.Measurements`), with the map filter's feature model, detection model (P_D),
    measurement noise and clutter. Returns (positions (K, 2), iterations run)."""
    feature, detection = mapfilter.feature, mapfilter.detection
    if not isinstance(feature, RangeBearing):
        raise TypeError("refine_map: point (range-bearing) features only")
    x = np.array(x0, dtype=np.float64).reshape(-1, 2)
    k_feat = x.shape[0]
    if k_feat == 0 or not frames:
        return x, 0
    sp = feature.sensor_pose(np.asarray(poses, dtype=np.float64))
    zs, ri, kap, fr = [], [], [], []
    pd_all = np.zeros((len(frames), k_feat))
    cov0 = np.zeros((1, k_feat, 2, 2))
    ones = np.ones((1, k_feat))
    # one frame at a time: an n_p profile's P_D needs each frame's own scan (once per run, after it)
    for t, meas in enumerate(frames):
        z, rz = mapfilter.measurements(meas)
        if z.shape[0] == 0:
            continue
        zs.append(z)
        ri.append(np.linalg.inv(rz))
        kap.append(mapfilter.clutter(z, meas))
        fr.append(np.full(z.shape[0], t, dtype=np.int64))
        pd, _ = detection.pd_features(sp[t : t + 1], x[None], cov0, meas, ones)
        pd_all[t] = np.clip(pd[0], 0.0, 1.0)
    if not zs:
        return x, 0
    z, rinv, kappa, frame = np.concatenate(zs), np.concatenate(ri), np.concatenate(kap), np.concatenate(fr)
    # candidate pairs: every measurement with every feature in view at its scan (P_D > 0 there), fixed for the run
    d_idx, j_idx = np.nonzero(pd_all[frame] > 0.0)
    if d_idx.size == 0:
        return x, 0
    pd_pair = pd_all[frame[d_idx], j_idx]
    groups, g_inv = np.unique(frame[d_idx] * k_feat + j_idx, return_inverse=True)
    miss = np.zeros(groups.size)
    miss[g_inv] = 1.0 - pd_pair
    sp_p, z_p, ri_p = sp[frame[d_idx]], z[d_idx], rinv[d_idx]
    scale = pd_pair * np.sqrt(np.linalg.det(ri_p)) / (2.0 * np.pi) / np.maximum(kappa[d_idx], 1e-300)
    it = 0
    for it in range(1, iterations + 1):
        zhat, h = feature.predict_sensor(sp_p, x[j_idx])
        nu = feature.innovation(z_p, zhat)
        d2 = np.einsum("mi,mij,mj->m", nu, ri_p, nu)
        gated = d2 < gate
        w, _ = association_weights(np.where(gated, scale * np.exp(-0.5 * np.minimum(d2, gate)), 0.0), g_inv, miss)
        # one Gauss-Newton step per feature of the responsibility-weighted least squares
        hr = np.einsum("mki,mkl->mil", h, ri_p)  # H^T R^-1 (M, 2, 2)
        a = np.zeros((k_feat, 2, 2))
        b = np.zeros((k_feat, 2))
        np.add.at(a, j_idx, w[:, None, None] * np.einsum("mil,mlj->mij", hr, h))
        np.add.at(b, j_idx, w[:, None] * np.einsum("mil,ml->mi", hr, nu))
        ok = np.linalg.det(a) > 1e-12 * np.maximum(np.einsum("kii->k", a) ** 2, 1e-300)
        step = np.zeros((k_feat, 2))
        if ok.any():
            step[ok] = np.linalg.solve(a[ok], b[ok][..., None])[..., 0]
        x += step
        if np.abs(step).max() < tolerance:
            break
    return x, it


def association_weights(ratio: np.ndarray, group: np.ndarray, miss: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The E-step of probabilistic data association: pairs (measurement, feature) with likelihood ratios ``ratio``
    (M,) = P_D g / kappa (0 for a pair outside the gate), each in the (scan, feature) group ``group`` (M,) whose
    missed-detection term is ``miss`` (G,) = 1 - P_D. Returns each pair's responsibility (M,) and each group's
    likelihood (1 - P_D) + sum of its ratios (G,)."""
    denom = np.bincount(group, weights=ratio, minlength=miss.size) + miss
    return ratio / denom[group], denom
