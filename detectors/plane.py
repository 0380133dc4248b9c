"""Plane detector for 3D lidar clouds: region growing on spherical cells, refitted with MSSE.

The paper the planar path follows (Gostar et al., Sensors 2019, sec. 5) segments
planes with the Modified Selective Statistical Estimator (MSSE, Bab-Hadiashar &
Suter 1999, their ref. [33]). MSSE is a scale estimator: given residuals sorted
by size it keeps the k smallest for the largest k at which the next residual
is still within T scale units of the fit of those k (T = 2.5). On its own it
needs candidate sets; here they come from region growing, which is what makes
the detector fast on a 120k-point sweep (measured against RANSAC in
``benchmarks/bench_planes.py``):

1. **cells**: returns binned in azimuth x elevation x log-range, so a cell
   holds about the same number of returns at 5 m and at 60 m; a cell is planar
   when its points' smallest principal spread is within the sensor noise and
   its middle one is not (not a single scan line). All cells' moments come
   from one pass of ``bincount``, their eigen-decompositions from one batched
   ``eigh``;
2. **regions**: neighbouring planar cells (26-neighbourhood) whose normals
   agree within ``merge_angle_deg`` and whose centroids lie within
   ``merge_offset`` of each other's plane are joined (connected components of
   that graph); non-planar cells at a region's border (edges, corners, a wall's
   foot) lend their points to the adjacent region whose plane passes closest;
3. **MSSE + least squares**: every region's residuals are sorted once
   (``lexsort`` over all regions together), MSSE picks each region's inliers,
   and the plane is refitted to them by total least squares (the smallest
   eigenvector of the inliers' scatter), ``refits`` times; regions that are one
   plane cut apart by an occluder (same normal and offset) are merged first;
4. **outputs** (sensor frame): Hesse parameters n . p = d with the normal
   pointing away from the sensor (d > 0), the covariance of the chart
   (azimuth, elevation, offset) of the normal and offset from the fit
   (residual variance over the inliers' spread, see :func:`chart_covariance`),
   the inlier count and residual sigma, the convex outline of the inliers in
   the plane (Qhull), its area, and the smallest enclosing rectangle (the four
   vertices the paper's vertex-distance table compares).

Every step is vectorised over points, cells or regions; only the convex
outlines are built per plane.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import ConvexHull, QhullError

from detectors.geometry3d import chart_from_normal, min_area_rectangle, plane_basis
from detectors.kinds import Detector, Measurements, register
from profiles.errors import DataError
from profiles.planes import PlaneDetectorParams

_OFFSETS = np.array([(a, b, c) for a in (-1, 0, 1) for b in (-1, 0, 1) for c in (-1, 0, 1) if (a, b, c) != (0, 0, 0)], dtype=np.int64)


@dataclass(frozen=True, eq=False)
class PlaneDetections:
    """Planes found in one or more clouds (struct of arrays, sensor frame).

    normal (M, 3) unit, pointing away from the sensor; offset (M,) [m] (n . p = d, d > 0);
    chart (M, 3) (azimuth, elevation [rad], offset [m]); cov (M, 3, 3) covariance of the chart;
    inliers (M,) int64; sigma (M,) residual std [m]; centroid (M, 3); area (M,) [m^2] of the
    convex outline; outline (V, 3) the outlines' vertices in order, plane m's are
    ``outline[outline_offsets[m]:outline_offsets[m+1]]``; rect (M, 4, 3) the smallest
    enclosing rectangle; frame (M,) int64 the cloud each plane came from.
    """

    normal: np.ndarray
    offset: np.ndarray
    chart: np.ndarray
    cov: np.ndarray
    inliers: np.ndarray
    sigma: np.ndarray
    centroid: np.ndarray
    area: np.ndarray
    outline: np.ndarray
    outline_offsets: np.ndarray
    rect: np.ndarray
    frame: np.ndarray

    def __len__(self) -> int:
        return int(self.offset.size)

    @property
    def width(self) -> np.ndarray:
        """(M,) the shorter side of each plane's enclosing rectangle [m]."""
        if len(self) == 0:
            return np.zeros(0)
        a = np.linalg.norm(self.rect[:, 1] - self.rect[:, 0], axis=-1)
        b = np.linalg.norm(self.rect[:, 2] - self.rect[:, 1], axis=-1)
        return np.minimum(a, b)

    def polygon(self, m: int) -> np.ndarray:
        """(V_m, 3) convex outline of plane m."""
        return self.outline[self.outline_offsets[m] : self.outline_offsets[m + 1]]

    def take(self, idx: np.ndarray) -> PlaneDetections:
        idx = np.asarray(idx, dtype=np.int64)
        polys = [self.polygon(int(i)) for i in idx]
        off = np.concatenate([[0], np.cumsum([p.shape[0] for p in polys])]).astype(np.int64)
        return PlaneDetections(
            self.normal[idx], self.offset[idx], self.chart[idx], self.cov[idx], self.inliers[idx], self.sigma[idx], self.centroid[idx],
            self.area[idx], np.vstack(polys) if polys else np.zeros((0, 3)), off, self.rect[idx], self.frame[idx],
        )

    def with_frame(self, k: int) -> PlaneDetections:
        return PlaneDetections(
            self.normal, self.offset, self.chart, self.cov, self.inliers, self.sigma, self.centroid, self.area, self.outline,
            self.outline_offsets, self.rect, np.full(len(self), k, dtype=np.int64),
        )

    @classmethod
    def empty(cls) -> PlaneDetections:
        z = np.zeros
        return cls(z((0, 3)), z(0), z((0, 3)), z((0, 3, 3)), z(0, np.int64), z(0), z((0, 3)), z(0), z((0, 3)), z(1, np.int64), z((0, 4, 3)), z(0, np.int64))

    @classmethod
    def concat(cls, parts: list[PlaneDetections]) -> PlaneDetections:
        parts = [p for p in parts if len(p)]
        if not parts:
            return cls.empty()
        off = [np.zeros(1, np.int64)]
        base = 0
        for p in parts:
            off.append(p.outline_offsets[1:] + base)
            base += p.outline.shape[0]
        cat = np.concatenate
        return cls(
            cat([p.normal for p in parts]), cat([p.offset for p in parts]), cat([p.chart for p in parts]), cat([p.cov for p in parts]),
            cat([p.inliers for p in parts]), cat([p.sigma for p in parts]), cat([p.centroid for p in parts]), cat([p.area for p in parts]),
            cat([p.outline for p in parts]), cat(off), cat([p.rect for p in parts]), cat([p.frame for p in parts]),
        )


def check_cloud(points: np.ndarray, where: str = "cloud") -> np.ndarray:
    """The (N, 3) float64 coordinates of a cloud given as (N, 3) or (N, 4) (x, y, z[, reflectance]);
    a DataError naming ``where`` for a wrong shape, an empty frame or a non-finite coordinate."""
    a = np.asarray(points)
    if a.ndim != 2 or a.shape[1] not in (3, 4):
        raise DataError(f"{where}: expected an (N, 3) or (N, 4) array of x, y, z[, reflectance], got shape {a.shape}")
    if a.shape[0] == 0:
        raise DataError(f"{where}: empty frame (no points)")
    if not np.issubdtype(a.dtype, np.number):
        raise DataError(f"{where}: coordinates must be numbers, got dtype {a.dtype}")
    xyz = np.asarray(a[:, :3], dtype=np.float64)
    bad = np.flatnonzero(~np.isfinite(xyz).all(axis=1))
    if bad.size:
        raise DataError(f"{where}: point {int(bad[0])} has a NaN or infinite coordinate ({bad.size} such points)")
    return xyz


def chart_covariance(normal: np.ndarray, centroid: np.ndarray, spread: np.ndarray, axes: np.ndarray, sigma2: np.ndarray, n: np.ndarray) -> np.ndarray:
    """(M, 3, 3) covariance of the chart (azimuth, elevation, offset) of total-least-squares planes.

    normal (M, 3), centroid (M, 3) sensor frame; spread (M, 2) the sums of squared
    in-plane deviations along the two in-plane principal axes (M, 2, 3); sigma2 (M,)
    residual variance; n (M,) inliers. A tilt of the normal by alpha along axis e_i
    has variance sigma2 / spread_i; the offset d = n . c moves by alpha (e_i . c) and
    by the centroid's own error (variance sigma2 / n), independent of the tilts.
    The tilts are then mapped to (azimuth, elevation) by their Jacobian.
    """
    m = normal.shape[0]
    va = sigma2[:, None] / np.maximum(spread, 1e-12)  # (M, 2)
    lever = (axes * centroid[:, None, :]).sum(-1)  # (M, 2) e_i . c
    c = np.zeros((m, 3, 3))
    c[:, 0, 0], c[:, 1, 1] = va[:, 0], va[:, 1]
    c[:, 0, 2] = c[:, 2, 0] = va[:, 0] * lever[:, 0]
    c[:, 1, 2] = c[:, 2, 1] = va[:, 1] * lever[:, 1]
    c[:, 2, 2] = (va * lever**2).sum(1) + sigma2 / np.maximum(n, 1)
    ch = chart_from_normal(normal, np.zeros(m))
    th, ph = ch[:, 0], ch[:, 1]
    t_th = np.stack([-np.sin(th), np.cos(th), np.zeros(m)], axis=-1)
    t_ph = np.stack([-np.sin(ph) * np.cos(th), -np.sin(ph) * np.sin(th), np.cos(ph)], axis=-1)
    cp = np.maximum(np.cos(ph), 1e-6)
    a = np.zeros((m, 3, 3))
    a[:, 0, 0] = (t_th * axes[:, 0]).sum(-1) / cp
    a[:, 0, 1] = (t_th * axes[:, 1]).sum(-1) / cp
    a[:, 1, 0] = (t_ph * axes[:, 0]).sum(-1)
    a[:, 1, 1] = (t_ph * axes[:, 1]).sum(-1)
    a[:, 2, 2] = 1.0
    out = a @ c @ np.swapaxes(a, -1, -2)
    return 0.5 * (out + np.swapaxes(out, -1, -2))


def _moments(lab: np.ndarray, p: np.ndarray, k: int, w: np.ndarray | None = None):
    """Count, sum and second moments (k, ...) of points p (N, 3) grouped by lab (N,) in 0..k-1."""
    cnt = np.bincount(lab, weights=w, minlength=k)
    s = np.stack([np.bincount(lab, weights=p[:, i] if w is None else p[:, i] * w, minlength=k) for i in range(3)], axis=-1)
    ss = np.zeros((k, 3, 3))
    for i in range(3):
        for j in range(i, 3):
            v = p[:, i] * p[:, j]
            ss[:, i, j] = np.bincount(lab, weights=v if w is None else v * w, minlength=k)
            ss[:, j, i] = ss[:, i, j]
    return cnt, s, ss


def _fit(cnt: np.ndarray, s: np.ndarray, ss: np.ndarray):
    """Total least squares planes from moments: normal (k, 3), offset, centroid, eigenvalues (k, 3) (ascending, as
    sums of squares), eigenvectors (k, 3, 3) (columns)."""
    n = np.maximum(cnt, 1.0)
    mean = s / n[:, None]
    scat = ss - n[:, None, None] * mean[:, :, None] * mean[:, None, :]
    lam, vec = np.linalg.eigh(scat)
    normal = vec[:, :, 0]
    return normal, (normal * mean).sum(-1), mean, np.maximum(lam, 0.0), vec


def _segments(lab: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """For labels sorted ascending: start index of each run and each element's run start."""
    starts = np.flatnonzero(np.concatenate([[True], lab[1:] != lab[:-1]]))
    run = np.cumsum(np.concatenate([[False], lab[1:] != lab[:-1]]))
    return starts, starts[run]


def _msse(lab: np.ndarray, res: np.ndarray, t: float, frac: float, p: int = 3) -> np.ndarray:
    """MSSE inliers (bool (N,)) of every labelled group at once (lab >= 0); -1 are ignored.

    Per group, residuals sorted ascending r_1..r_n: the scale of the first k is
    sigma_k^2 = sum_{i<=k} r_i^2 / (k - p); k grows from the smallest acceptable inlier
    count until r_{k+1} > t sigma_k (Bab-Hadiashar & Suter 1999).
    """
    keep = np.zeros(lab.size, dtype=bool)
    idx = np.flatnonzero(lab >= 0)
    if idx.size == 0:
        return keep
    ar = np.abs(res[idx])
    # one argsort on a combined key (group, then residual within the group) instead of a lexsort
    order = idx[np.argsort(lab[idx] + ar / (2.0 * ar.max() + 1e-300))]
    ls, rs = lab[order], np.abs(res[order])
    starts, first = _segments(ls)
    rank = np.arange(ls.size) - first + 1  # 1-based rank in the group
    csum = np.cumsum(rs * rs)
    before = np.concatenate([[0.0], csum])[first]
    sig2 = (csum - before) / np.maximum(rank - p, 1)
    size = np.diff(np.concatenate([starts, [ls.size]]))
    gsize = np.repeat(size, size)
    nxt = np.concatenate([rs[1:], [np.inf]])
    nxt = np.where(rank == gsize, np.inf, nxt)
    kmin = np.maximum(p + 2, np.ceil(frac * gsize))
    stop = (nxt * nxt > t * t * sig2) & (rank >= kmin)
    big = np.iinfo(np.int64).max
    kstar = np.minimum.reduceat(np.where(stop, rank, big), starts)
    kstar = np.minimum(kstar, size)
    keep[order] = rank <= np.repeat(kstar, size)
    return keep


def detect_planes(points: np.ndarray, params: PlaneDetectorParams | None = None, *, where: str = "cloud", return_labels: bool = False):
    """Planes of one cloud (N, 3|4), sensor frame (see the module docstring).

    Returns :class:`PlaneDetections` (``frame`` 0), and with ``return_labels`` also
    labels (N,) int64: the plane of each point (its index in the detections) or -1.
    """
    prm = params or PlaneDetectorParams()
    xyz = check_cloud(points, where)
    n_all = xyz.shape[0]
    labels_out = np.full(n_all, -1, dtype=np.int64)
    r = np.linalg.norm(xyz, axis=1)
    use = np.flatnonzero(r >= prm.range_min)
    p = xyz[use]
    r = r[use]
    if p.shape[0] < prm.min_points:
        return (PlaneDetections.empty(), labels_out) if return_labels else PlaneDetections.empty()
    sig = prm.range_sigma
    # 1. spherical cells and their local planes; near the sensor the angular size grows by whole
    # multiples (nested grids) so that a cell is at least min_cell_size wide: a cell only a few
    # noise sigmas wide has no usable normal
    daz, del_ = np.radians(prm.cell_azimuth_deg), np.radians(prm.cell_elevation_deg)
    na = int(np.ceil(2 * np.pi / daz))
    ne = int(np.ceil(np.pi / del_)) + 1
    lr = np.log(prm.cell_range_ratio)
    ia = np.minimum((np.arctan2(p[:, 1], p[:, 0]) + np.pi) // daz, na - 1).astype(np.int64)
    ie = ((np.arcsin(np.clip(p[:, 2] / r, -1, 1)) + np.pi / 2) // del_).astype(np.int64)
    ir = (np.log(r / prm.range_min) // lr).astype(np.int64)
    n_rb = int(ir.max()) + 2
    r_lo = prm.range_min * np.exp(np.arange(n_rb) * lr)
    fac = np.clip(np.ceil(prm.min_cell_size / (r_lo * daz)), 1, 32).astype(np.int64)  # (range bins,)
    f = fac[ir]
    key = (ir * ne + ie // f) * na + ia // f
    ukeys, cell = np.unique(key, return_inverse=True)
    k = ukeys.size
    cnt, s, ss = _moments(cell, p, k)
    normal, off, mean, lam, vec = _fit(cnt, s, ss)
    nn = np.maximum(cnt, 1.0)
    thick = np.sqrt(lam[:, 0] / nn)
    mid = np.sqrt(lam[:, 1] / nn)
    planar = (cnt >= prm.min_cell_points) & (thick <= 2.5 * sig) & (mid >= 2.5 * np.maximum(thick, 0.5 * sig))
    # 2. regions: connected planar neighbours with agreeing planes
    cr, rem = np.divmod(ukeys, ne * na)
    ce, ca = np.divmod(rem, na)
    cf = fac[cr]
    pl = np.flatnonzero(planar)
    cos_m = np.cos(np.radians(prm.merge_angle_deg))

    def neighbours(cells: np.ndarray) -> np.ndarray:
        """(len(cells), 26) a neighbour cell per direction, -1 where it has no returns. Probes just past each
        face, edge and corner at the base resolution, then looks the probe up in the neighbour's range bin
        (whose cells may be larger or smaller)."""
        fo = cf[cells, None]
        nr_ = cr[cells, None] + _OFFSETS[None, :, 0]
        ft = fac[np.clip(nr_, 0, n_rb - 1)]
        # centre of the own cell at base resolution (x2 to stay integral), then one step past its side
        pe = (2 * ce[cells, None] * fo + fo) + _OFFSETS[None, :, 1] * (fo + 1)
        pa = (2 * ca[cells, None] * fo + fo) + _OFFSETS[None, :, 2] * (fo + 1)
        be, ba = pe // 2, np.mod(pa // 2, na)
        nk = (nr_ * ne + be // ft) * na + ba // ft
        pos = np.clip(np.searchsorted(ukeys, nk), 0, k - 1)
        return np.where((ukeys[pos] == nk) & (nr_ >= 0) & (be >= 0) & (be < ne * 1), pos, -1)

    nb = neighbours(pl)
    a_i = np.repeat(pl, 26)
    b_i = nb.reshape(-1)
    ok = b_i >= 0
    a_i, b_i = a_i[ok], b_i[ok]
    ok = planar[b_i]
    a_i, b_i = a_i[ok], b_i[ok]
    na_, nb_ = normal[a_i], normal[b_i]
    dm = mean[b_i] - mean[a_i]
    ok = (np.abs((na_ * nb_).sum(1)) >= cos_m) & (np.abs((na_ * dm).sum(1)) <= prm.merge_offset) & (np.abs((nb_ * dm).sum(1)) <= prm.merge_offset)
    g = coo_matrix((np.ones(int(ok.sum())), (a_i[ok], b_i[ok])), shape=(k, k))
    _, comp = connected_components(g, directed=False)
    comp = np.where(planar, comp, -1)
    # keep regions with enough returns; renumber 0..R-1
    pts_per = np.bincount(comp[planar], weights=cnt[planar], minlength=k) if pl.size else np.zeros(k)
    good = pts_per >= prm.min_points
    region = np.where(comp >= 0, np.where(good[np.maximum(comp, 0)], comp, -1), -1)
    uniq, region_c = np.unique(region, return_inverse=True)
    region = np.where(region >= 0, region_c - (1 if uniq[0] < 0 else 0), -1)
    nreg = int(region.max()) + 1 if region.size else 0
    if nreg == 0:
        return (PlaneDetections.empty(), labels_out) if return_labels else PlaneDetections.empty()
    # initial region planes from their planar cells' moments
    inreg = region >= 0
    rc, rs, rss = (np.bincount(region[inreg], weights=cnt[inreg], minlength=nreg),
                   np.stack([np.bincount(region[inreg], weights=s[inreg, i], minlength=nreg) for i in range(3)], -1),
                   np.zeros((nreg, 3, 3)))
    for i in range(3):
        for j in range(3):
            rss[:, i, j] = np.bincount(region[inreg], weights=ss[inreg, i, j], minlength=nreg)
    rn, rd, _, _, _ = _fit(rc, rs, rss)
    # border cells lend their returns to the neighbouring region whose plane passes closest
    free = np.flatnonzero(region < 0)
    if free.size:
        nbf = neighbours(free)
        reg_nb = np.where(nbf >= 0, region[np.maximum(nbf, 0)], -1)
        dist = np.abs((rn[np.maximum(reg_nb, 0)] * mean[free, None, :]).sum(-1) - rd[np.maximum(reg_nb, 0)])
        dist = np.where(reg_nb >= 0, dist, np.inf)
        j = np.argmin(dist, axis=1)
        best = reg_nb[np.arange(free.size), j]
        region[free] = np.where(np.isfinite(dist[np.arange(free.size), j]), best, -1)
    region = _grow(region, cell, cnt, mean, p, rn, rd, neighbours, k, 3.0 * sig, prm)
    lab_all = region[cell]
    sub = np.flatnonzero(lab_all >= 0)  # only returns that some region may take
    p, lab, use = p[sub], lab_all[sub], use[sub]
    # 3. MSSE + total least squares, merging regions that are one plane
    for it in range(prm.refits + 1):
        res = np.where(lab >= 0, (rn[np.maximum(lab, 0)] * p).sum(1) - rd[np.maximum(lab, 0)], 0.0)
        keep = _msse(lab, res, prm.msse_t, prm.msse_min_fraction)
        li = np.where(keep, lab, nreg)  # outliers to a spare group
        c_, s_, ss_ = _moments(li, p, nreg + 1)
        rn, rd, rmean, rlam, rvec = _fit(c_[:nreg], s_[:nreg], ss_[:nreg])
        rcount = c_[:nreg]
        if it == 0 and nreg > 1:
            lab, nreg, rn, rd = _merge_coplanar(lab, rn, rd, rcount, rlam, s_[:nreg], ss_[:nreg], prm)
    rsig2 = rlam[:, 0] / np.maximum(rcount - 3, 1)
    ok = (rcount >= prm.min_points) & (np.sqrt(rsig2) <= prm.max_sigma)
    # orient away from the sensor: d > 0
    flip = np.where(rd < 0, -1.0, 1.0)
    rn, rd = rn * flip[:, None], rd * flip
    order = np.flatnonzero(ok)[np.argsort(-rcount[ok], kind="stable")]
    m = order.size
    if m == 0:
        return (PlaneDetections.empty(), labels_out) if return_labels else PlaneDetections.empty()
    newid = np.full(nreg + 1, -1, dtype=np.int64)
    newid[order] = np.arange(m)
    plab = np.where(keep, newid[np.where(lab >= 0, lab, nreg)], -1)
    normal_m, d_m, cen_m = rn[order], rd[order], rmean[order]
    axes = np.swapaxes(rvec[order][:, :, 1:], 1, 2)  # (M, 2, 3) in-plane principal axes
    cov = chart_covariance(normal_m, cen_m, rlam[order][:, 1:], axes, rsig2[order], rcount[order])
    outline, offs, area, rect = _outlines(p, plab, normal_m, d_m, cen_m, m)
    det = PlaneDetections(
        normal_m, d_m, chart_from_normal(normal_m, d_m), cov, rcount[order].astype(np.int64), np.sqrt(rsig2[order]), cen_m, area,
        outline, offs, rect, np.zeros(m, dtype=np.int64),
    )
    if return_labels:
        labels_out[use] = plab
        return det, labels_out
    return det


def _grow(region, cell, cnt, mean, p, rn, rd, neighbours, k, tol, prm):
    """Regions grown further out, cell by cell (``prm.grow_steps`` rings at most), while at least ``prm.grow_share``
    of a cell's returns lie within ``tol`` of the neighbouring region's plane (a plane seen through a bush or behind
    a pole's cells keeps its returns there): the region of each cell (k,), -1 for none."""
    region = region.copy()
    for _ in range(prm.grow_steps):
        free = np.flatnonzero(region < 0)
        if free.size == 0:
            break
        nbf = neighbours(free)
        reg_nb = np.where(nbf >= 0, region[np.maximum(nbf, 0)], -1)
        dist = np.where(reg_nb >= 0, np.abs((rn[np.maximum(reg_nb, 0)] * mean[free, None, :]).sum(-1) - rd[np.maximum(reg_nb, 0)]), np.inf)
        j = np.argmin(dist, axis=1)
        cand = np.where(np.isfinite(dist[np.arange(free.size), j]), reg_nb[np.arange(free.size), j], -1)
        if not (cand >= 0).any():
            break
        cand_of = np.full(k, -1)
        cand_of[free] = cand
        pc = cand_of[cell]
        m_ = np.flatnonzero(pc >= 0)
        near = np.zeros(p.shape[0])
        near[m_] = np.abs((rn[pc[m_]] * p[m_]).sum(1) - rd[pc[m_]]) <= tol
        share = np.bincount(cell, weights=near, minlength=k) / np.maximum(cnt, 1.0)
        adopt = free[(cand >= 0) & (share[free] >= prm.grow_share)]
        if adopt.size == 0:
            break
        region[adopt] = cand_of[adopt]
    return region


def _merge_coplanar(lab, rn, rd, rcount, rlam, s_, ss_, prm):
    """Regions that are one plane become one: region j joins a larger region i when j's inliers fit i's plane
    (their rms residual to it, from j's moments, is within ``msse_t`` sensor sigmas, and the normals agree within
    ``merge_angle_deg``) -- fragments at a plane's edges whose own normal is poorly determined -- or when the two
    planes agree within ``coplanar_angle_deg`` and ``coplanar_offset`` (parts of one plane cut apart by an
    occluder). Greedy from the largest region down, and only into regions that stay themselves, so no chain of
    small regions can join two different planes."""
    nreg = rn.shape[0]
    # sum over j's inliers of (n_i . p - d_i)^2 = n_i^T SS_j n_i - 2 d_i n_i . S_j + N_j d_i^2, for every (i, j)
    q = np.einsum("ia,jab,ib->ij", rn, ss_, rn) - 2 * rd[:, None] * (rn @ s_.T) + rd[:, None] ** 2 * rcount[None, :]
    rms = np.sqrt(np.maximum(q, 0.0) / np.maximum(rcount, 1)[None, :])
    c = rn @ rn.T
    same = (rms <= prm.msse_t * prm.range_sigma) & (np.abs(c) >= np.cos(np.radians(prm.merge_angle_deg)))
    if prm.coplanar_offset > 0:
        sgn = np.where(c < 0, -1.0, 1.0)
        same |= (np.abs(c) >= np.cos(np.radians(prm.coplanar_angle_deg))) & (np.abs(rd[:, None] - sgn * rd[None, :]) <= prm.coplanar_offset)
    live = rcount >= 3
    same &= live[:, None] & live[None, :]
    np.fill_diagonal(same, False)
    if not same.any():
        return lab, nreg, rn, rd
    target = np.arange(nreg)
    root = np.ones(nreg, dtype=bool)
    for j in np.argsort(-rcount, kind="stable"):  # at most a few hundred regions
        cand = np.flatnonzero(same[:, j] & root & (rcount > rcount[j]))
        if cand.size:
            target[j] = cand[np.argmax(rcount[cand])]
            root[j] = False
    keep = np.flatnonzero(root)
    new = np.full(nreg, -1)
    new[keep] = np.arange(keep.size)
    comp = new[target]
    lab = np.where(lab >= 0, comp[np.maximum(lab, 0)], -1)
    return lab, int(keep.size), rn[keep], rd[keep]


def _outlines(p, plab, normal, d, cen, m):
    """Convex outline (in the plane), its area and smallest enclosing rectangle of every plane's inliers."""
    u, v = plane_basis(normal)
    sel = np.flatnonzero(plab >= 0)
    order = sel[np.argsort(plab[sel], kind="stable")]
    lab_s = plab[order]
    bounds = np.searchsorted(lab_s, np.arange(m + 1))
    polys, areas, rects = [], np.zeros(m), np.zeros((m, 4, 3))
    for i in range(m):  # one Qhull call per plane (tens per frame)
        q = p[order[bounds[i] : bounds[i + 1]]] - cen[i]
        a, b = q @ u[i], q @ v[i]
        xy = np.column_stack([a, b])
        try:
            hull = ConvexHull(xy)
            h2 = xy[hull.vertices]
            areas[i] = float(hull.volume)
        except (QhullError, ValueError):
            lo, hi = xy.min(0), xy.max(0)
            h2 = np.array([[lo[0], lo[1]], [hi[0], lo[1]], [hi[0], hi[1]], [lo[0], hi[1]]])
            areas[i] = 0.0
        base = cen[i] - ((cen[i] @ normal[i]) - d[i]) * normal[i]  # the centroid projected on the plane
        polys.append(base + h2[:, :1] * u[i] + h2[:, 1:] * v[i])
        rc = min_area_rectangle(h2)
        rects[i] = base + rc[:, :1] * u[i] + rc[:, 1:] * v[i]
    offs = np.concatenate([[0], np.cumsum([q.shape[0] for q in polys])]).astype(np.int64)
    return (np.vstack(polys) if polys else np.zeros((0, 3))), offs, areas, rects


# ---------------------------------------------------------------------------- the kind at run time


class CloudPlanes:
    """The profile's plane detector on every cloud; the landmark planes (steep enough, enough inliers) as
    sensor-frame charts (azimuth, elevation, offset) with their fit covariances, and the cloud for P_D."""

    def __init__(self, log, profile, detection) -> None:
        self.log = log
        self.params = profile.detector.plane
        self.detection = detection
        self.min_points = profile.planes.min_points
        self.min_width = profile.planes.min_width

    def __call__(self, frame) -> Measurements:
        cloud = self.log.clouds.frame(frame.rows)
        det = detect_planes(cloud, self.params, where=f"{self.log.name}: cloud {frame.rows}")
        use = self.detection.in_view(det.chart) & (det.inliers >= self.min_points) & (det.width >= self.min_width)
        return Measurements(det.chart[use], det.cov[use], cloud=cloud)


class PlaneDetector(Detector):
    """``plane3d``: detcal's plane detector, run on every 3D lidar cloud of the log."""

    stream = "clouds"
    needs = "detects planes in point clouds"
    features = "planes"

    def detection_model(self, profile, sensor, options, k_sigma):
        from detectors.plane_model import PlaneDetectionModel

        return PlaneDetectionModel.from_options(profile, sensor, options, k_sigma)

    def source(self, log, profile, detection, options):
        return CloudPlanes(log, profile, detection)


register("plane3d", PlaneDetector())
