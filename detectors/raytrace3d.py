"""3D ray tracing for a spinning multi-beam lidar: the street simulator's caster and n_p of planes.

A spinning lidar (Velodyne HDL-64E-like) fires R rings at fixed elevations
and C columns of azimuth per sweep; its beams form an (R, C) grid in the
sensor frame (:class:`BeamGrid`). A :class:`Scene` holds the world's
primitives (world frame): convex planar polygons (facades, walls, boards, car
faces, the ground), vertical cylinders (trunks, poles) and spheres (bushes,
crowns). Primitive ids run over polygons, then cylinders, then spheres.

* :func:`cast` -- the first hit of every beam of a sweep from one sensor pose:
  range (R, C) (inf = no hit) and primitive id (R, C) (-1 = none);
* :func:`visible_planes` -- the 3D form of n_p (Inostroza 2015, eq. 4.1, sec.
  6.1): for every polygon, the beams that would hit it if nothing were in the
  way (n_expected) and those of them not occluded in the measured range image
  (a return shorter than expected by more than k sigma_r occludes; a missing
  return does not), with the centroid of the unoccluded hits (its line of
  sight gives the incidence angle);
* :func:`range_image` -- a cloud back on its beam grid (each point's ring by
  its elevation, column by its azimuth; the nearest return per cell).

Both loops are compiled (numba): primitive-major with culling by the azimuth
sector and elevation band each primitive's bounding sphere covers, so a small
object costs only the beams that can reach it. The sweep is instantaneous (no
motion distortion).
"""

from __future__ import annotations

from dataclasses import dataclass

import numba
import numpy as np

from detectors.geometry3d import plane_basis


@dataclass(frozen=True, eq=False)
class BeamGrid:
    """Beam directions of a spinning lidar, sensor frame.

    elevations (R,) [rad] one per ring; columns C at azimuths ``azimuth_min + c * azimuth_increment``.
    """

    elevations: np.ndarray
    azimuth_increment: float
    azimuth_min: float = -np.pi

    @property
    def rings(self) -> int:
        return int(self.elevations.size)

    @property
    def columns(self) -> int:
        return int(round(2 * np.pi / self.azimuth_increment))

    @property
    def azimuths(self) -> np.ndarray:
        return self.azimuth_min + self.azimuth_increment * np.arange(self.columns)

    def directions(self) -> np.ndarray:
        """(R, C, 3) unit beam directions, sensor frame."""
        el = self.elevations[:, None]
        az = self.azimuths[None, :]
        return np.stack(np.broadcast_arrays(np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)), axis=-1)

    @classmethod
    def of(cls, lidar) -> BeamGrid:
        """From a :class:`profiles.schema.LidarGeometry`."""
        return cls(np.radians(np.asarray(lidar.vertical_angles_deg, dtype=np.float64)), float(np.radians(lidar.azimuth_increment_deg)))


def hdl64_elevations() -> np.ndarray:
    """(64,) [rad] elevations like a Velodyne HDL-64E: +2 to -8.33 deg (32, upper block), -8.83 to -24.8 deg (32)."""
    return np.radians(np.concatenate([np.linspace(2.0, -8.33, 32), np.linspace(-8.83, -24.8, 32)]))


@dataclass(frozen=True, eq=False)
class Scene:
    """World-frame primitives.

    polygons: ``poly_vertices`` (K, V, 3) padded convex outlines (counter-clockwise about
    ``poly_normal``), ``poly_count`` (K,) vertices used; cylinders: ``cyl_xy`` (L, 2),
    ``cyl_r`` (L,), ``cyl_z`` (L, 2) bottom and top; spheres: ``sph_centre`` (S, 3), ``sph_r`` (S,).
    """

    poly_vertices: np.ndarray
    poly_count: np.ndarray
    cyl_xy: np.ndarray
    cyl_r: np.ndarray
    cyl_z: np.ndarray
    sph_centre: np.ndarray
    sph_r: np.ndarray

    def __post_init__(self) -> None:
        v = np.ascontiguousarray(self.poly_vertices, dtype=np.float64)
        if v.ndim != 3 or v.shape[-1] != 3:
            v = v.reshape(0, 3, 3) if v.size == 0 else v.reshape(v.shape[0], -1, 3)
        cnt = np.ascontiguousarray(self.poly_count, dtype=np.int64).reshape(-1)
        object.__setattr__(self, "poly_vertices", v)
        object.__setattr__(self, "poly_count", cnt)
        n, d, o, u, w, v2, bc, br = _polygon_frames(v, cnt)
        object.__setattr__(self, "_poly", (n, d, o, u, w, v2, bc, br))
        object.__setattr__(self, "cyl_xy", np.ascontiguousarray(self.cyl_xy, dtype=np.float64).reshape(-1, 2))
        object.__setattr__(self, "cyl_r", np.ascontiguousarray(self.cyl_r, dtype=np.float64).reshape(-1))
        object.__setattr__(self, "cyl_z", np.ascontiguousarray(self.cyl_z, dtype=np.float64).reshape(-1, 2))
        object.__setattr__(self, "sph_centre", np.ascontiguousarray(self.sph_centre, dtype=np.float64).reshape(-1, 3))
        object.__setattr__(self, "sph_r", np.ascontiguousarray(self.sph_r, dtype=np.float64).reshape(-1))

    @property
    def n_polygons(self) -> int:
        return int(self.poly_count.size)

    @property
    def poly_normal(self) -> np.ndarray:
        return self._poly[0]

    @property
    def poly_offset(self) -> np.ndarray:
        return self._poly[1]


def polygon_scene(planes) -> Scene:
    """A scene of the polygons of a :class:`detectors.sensor_log.PlaneLandmarks` (no other primitives)."""
    counts = np.diff(planes.offsets)
    v = np.zeros((len(planes), int(counts.max()) if counts.size else 3, 3))
    for i in range(len(planes)):
        v[i, : counts[i]] = planes.polygon(i)
    z = np.zeros
    return Scene(v, counts, z((0, 2)), z(0), z((0, 2)), z((0, 3)), z(0))


def _polygon_frames(v: np.ndarray, cnt: np.ndarray):
    """Per polygon: unit normal, offset, origin, in-plane basis, 2D vertices (CCW), bounding sphere."""
    k = cnt.size
    vmax = v.shape[1]
    idx = np.arange(vmax)[None, :] < cnt[:, None]
    o = np.where(idx[..., None], v, 0.0).sum(axis=1) / np.maximum(cnt, 1)[:, None]
    # Newell's normal (robust for any simple polygon)
    nxt = np.where(np.arange(vmax)[None, :] + 1 < cnt[:, None], np.arange(vmax)[None, :] + 1, 0)
    vn = np.take_along_axis(v, nxt[..., None], axis=1)
    cur = np.where(idx[..., None], v, 0.0)
    vn = np.where(idx[..., None], vn, 0.0)
    nrm = np.stack(
        [
            ((cur[..., 1] - vn[..., 1]) * (cur[..., 2] + vn[..., 2])).sum(1),
            ((cur[..., 2] - vn[..., 2]) * (cur[..., 0] + vn[..., 0])).sum(1),
            ((cur[..., 0] - vn[..., 0]) * (cur[..., 1] + vn[..., 1])).sum(1),
        ],
        axis=-1,
    )
    nrm = nrm / np.maximum(np.linalg.norm(nrm, axis=1), 1e-300)[:, None]
    u, w = plane_basis(nrm)
    rel = v - o[:, None, :]
    v2 = np.stack([(rel * u[:, None, :]).sum(-1), (rel * w[:, None, :]).sum(-1)], axis=-1)
    v2 = np.where(idx[..., None], v2, 0.0)
    br = np.where(idx, np.linalg.norm(rel, axis=-1), 0.0).max(axis=1) if k else np.zeros(0)
    d = (nrm * o).sum(axis=1)
    return nrm, d, o, u, w, np.ascontiguousarray(v2), o.copy(), br


def cast(scene: Scene, grid: BeamGrid, sensor_pose: np.ndarray, height: float, range_max: float) -> tuple[np.ndarray, np.ndarray]:
    """First hits of every beam from a sensor at planar pose (x, y, yaw) and ``height``.

    Returns range (R, C) float64 [m] (inf where nothing is hit within ``range_max``)
    and the primitive id (R, C) int32 (-1 = none).
    """
    sp = np.asarray(sensor_pose, dtype=np.float64)
    origin = np.array([sp[0], sp[1], height])
    n, d, o, u, w, v2, bc, br = scene._poly
    t, ids = _cast_kernel(
        origin, float(sp[2]), np.ascontiguousarray(grid.elevations, dtype=np.float64), float(grid.azimuth_min), float(grid.azimuth_increment),
        grid.columns, n, d, o, u, w, v2, scene.poly_count, bc, br, scene.cyl_xy, scene.cyl_r, scene.cyl_z, scene.sph_centre, scene.sph_r, float(range_max),
    )
    return t, ids


def visible_planes(
    scene: Scene,
    grid: BeamGrid,
    sensor_pose: np.ndarray,
    height: float,
    measured: np.ndarray,
    *,
    range_sigma: float,
    k_sigma: float = 3.0,
    range_max: float,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """n_p of every polygon of ``scene`` from one sensor pose given the measured range image (R, C) (NaN = no return).

    Returns n_p (K,) int64 (expected hits not occluded), n_expected (K,) int64
    (beams whose ray meets the polygon within range), and the centroid (K, 3) of the
    unoccluded hits in the sensor frame (NaN where n_p = 0).
    """
    sp = np.asarray(sensor_pose, dtype=np.float64)
    origin = np.array([sp[0], sp[1], height])
    n, d, o, u, w, v2, bc, br = scene._poly
    n_p, n_exp, acc = _visible_kernel(
        origin, float(sp[2]), np.ascontiguousarray(grid.elevations, dtype=np.float64), float(grid.azimuth_min), float(grid.azimuth_increment),
        grid.columns, n, d, o, u, w, v2, scene.poly_count, bc, br, np.ascontiguousarray(measured, dtype=np.float64),
        float(k_sigma * range_sigma), float(range_max),
    )
    cen = np.where(n_p[:, None] > 0, acc / np.maximum(n_p, 1)[:, None], np.nan)
    return n_p, n_exp, cen


def range_image(points: np.ndarray, grid: BeamGrid) -> np.ndarray:
    """(R, C) ranges [m] of a cloud (N, >=3) put back on its beam grid (NaN = no return; nearest return per cell).

    Each point's ring is the nearest elevation, its column the nearest azimuth.
    """
    p = np.asarray(points, dtype=np.float64)[:, :3]
    r = np.linalg.norm(p, axis=1)
    out = np.full((grid.rings, grid.columns), np.inf)
    if p.shape[0]:
        el = np.arcsin(np.clip(p[:, 2] / np.maximum(r, 1e-12), -1.0, 1.0))
        order = np.argsort(grid.elevations)
        se = grid.elevations[order]
        pos = np.clip(np.searchsorted(se, el), 1, se.size - 1) if se.size > 1 else np.zeros(el.size, dtype=np.int64)
        if se.size > 1:
            pos = np.where(np.abs(el - se[pos - 1]) <= np.abs(el - se[pos]), pos - 1, pos)
        ring = order[pos]
        az = np.arctan2(p[:, 1], p[:, 0])
        col = np.mod(np.rint((az - grid.azimuth_min) / grid.azimuth_increment).astype(np.int64), grid.columns)
        np.minimum.at(out, (ring, col), r)
    out[np.isinf(out)] = np.nan
    return out


# ---------------------------------------------------------------------------- compiled kernels


@numba.njit(cache=True, nogil=True)
def _sector(origin, yaw, centre, radius, az0, daz, ncol, elev):  # pragma: no cover - compiled
    """Columns [c0, c0 + nc) (mod C) and the ring mask a bounding sphere can reach."""
    rx, ry, rz = centre[0] - origin[0], centre[1] - origin[1], centre[2] - origin[2]
    dxy = np.sqrt(rx * rx + ry * ry)
    dist = np.sqrt(dxy * dxy + rz * rz)
    nr = elev.size
    rings = np.ones(nr, dtype=np.bool_)
    if dxy <= radius * 1.0001 + 1e-9:
        return 0, ncol, rings
    half = np.arcsin(min(1.0, radius / dxy)) + daz
    a = np.arctan2(ry, rx) - yaw
    c0 = int(np.floor((a - half - az0) / daz))
    c1 = int(np.ceil((a + half - az0) / daz))
    nc = min(ncol, c1 - c0 + 1)
    if dist > radius:
        el_c = np.arctan2(rz, dxy)
        hel = np.arcsin(min(1.0, radius / dist)) + 1e-3
        for i in range(nr):
            rings[i] = abs(elev[i] - el_c) <= hel
    c0 = c0 % ncol
    return c0, nc, rings


@numba.njit(cache=True, nogil=True)
def _hit_polygon(ox, oy, oz, ux, uy, uz, n, d, o, pu, pv, v2, cnt, tmin, tmax):  # pragma: no cover - compiled
    den = n[0] * ux + n[1] * uy + n[2] * uz
    if abs(den) < 1e-12:
        return np.inf
    t = (d - (n[0] * ox + n[1] * oy + n[2] * oz)) / den
    if t <= tmin or t >= tmax:
        return np.inf
    px, py, pz = ox + t * ux - o[0], oy + t * uy - o[1], oz + t * uz - o[2]
    a = px * pu[0] + py * pu[1] + pz * pu[2]
    b = px * pv[0] + py * pv[1] + pz * pv[2]
    # inside the convex outline: on the same side of every edge (either orientation)
    pos = False
    neg = False
    for i in range(cnt):
        j = i + 1 if i + 1 < cnt else 0
        ex, ey = v2[j, 0] - v2[i, 0], v2[j, 1] - v2[i, 1]
        cr = ex * (b - v2[i, 1]) - ey * (a - v2[i, 0])
        if cr > 1e-12:
            pos = True
        elif cr < -1e-12:
            neg = True
        if pos and neg:
            return np.inf
    return t


@numba.njit(cache=True, nogil=True)
def _cast_kernel(
    origin, yaw, elev, az0, daz, ncol, pn, pd, po, pu, pv, pv2, pcnt, pbc, pbr, cxy, cr, cz, sc, sr, rmax
):  # pragma: no cover - compiled
    nr = elev.size
    best = np.full((nr, ncol), np.inf)
    ids = np.full((nr, ncol), -1, dtype=np.int32)
    ce = np.cos(elev)
    se = np.sin(elev)
    ox, oy, oz = origin[0], origin[1], origin[2]
    tmin = 1e-6
    kp = pcnt.size
    for k in range(kp):
        c0, nc, rings = _sector(origin, yaw, pbc[k], pbr[k], az0, daz, ncol, elev)
        for cc in range(nc):
            c = (c0 + cc) % ncol
            az = az0 + c * daz + yaw
            ca, sa = np.cos(az), np.sin(az)
            for r in range(nr):
                if not rings[r]:
                    continue
                ux, uy, uz = ce[r] * ca, ce[r] * sa, se[r]
                t = _hit_polygon(ox, oy, oz, ux, uy, uz, pn[k], pd[k], po[k], pu[k], pv[k], pv2[k], pcnt[k], tmin, best[r, c])
                if t < best[r, c]:
                    best[r, c] = t
                    ids[r, c] = k
    ctr = np.zeros(3)
    for k in range(cr.size):
        ctr[0], ctr[1], ctr[2] = cxy[k, 0], cxy[k, 1], 0.5 * (cz[k, 0] + cz[k, 1])
        rad = np.sqrt(cr[k] * cr[k] + 0.25 * (cz[k, 1] - cz[k, 0]) ** 2)
        c0, nc, rings = _sector(origin, yaw, ctr, rad, az0, daz, ncol, elev)
        qx, qy = ox - cxy[k, 0], oy - cxy[k, 1]
        for cc in range(nc):
            c = (c0 + cc) % ncol
            az = az0 + c * daz + yaw
            ca, sa = np.cos(az), np.sin(az)
            for r in range(nr):
                if not rings[r]:
                    continue
                ux, uy, uz = ce[r] * ca, ce[r] * sa, se[r]
                a = ux * ux + uy * uy
                if a < 1e-18:
                    continue
                b = 2.0 * (qx * ux + qy * uy)
                c2 = qx * qx + qy * qy - cr[k] * cr[k]
                disc = b * b - 4 * a * c2
                if disc < 0:
                    continue
                t = (-b - np.sqrt(disc)) / (2 * a)
                if t <= tmin or t >= best[r, c]:
                    continue
                z = oz + t * uz
                if z < cz[k, 0] or z > cz[k, 1]:
                    continue
                best[r, c] = t
                ids[r, c] = kp + k
    kc = kp + cr.size
    for k in range(sr.size):
        c0, nc, rings = _sector(origin, yaw, sc[k], sr[k], az0, daz, ncol, elev)
        qx, qy, qz = ox - sc[k, 0], oy - sc[k, 1], oz - sc[k, 2]
        for cc in range(nc):
            c = (c0 + cc) % ncol
            az = az0 + c * daz + yaw
            ca, sa = np.cos(az), np.sin(az)
            for r in range(nr):
                if not rings[r]:
                    continue
                ux, uy, uz = ce[r] * ca, ce[r] * sa, se[r]
                b = qx * ux + qy * uy + qz * uz
                c2 = qx * qx + qy * qy + qz * qz - sr[k] * sr[k]
                disc = b * b - c2
                if disc < 0:
                    continue
                t = -b - np.sqrt(disc)
                if t <= tmin or t >= best[r, c]:
                    continue
                best[r, c] = t
                ids[r, c] = kc + k
    for r in range(nr):
        for c in range(ncol):
            if best[r, c] > rmax:
                best[r, c] = np.inf
                ids[r, c] = -1
    return best, ids


@numba.njit(cache=True, nogil=True)
def _visible_kernel(origin, yaw, elev, az0, daz, ncol, pn, pd, po, pu, pv, pv2, pcnt, pbc, pbr, meas, tol, rmax):  # pragma: no cover - compiled
    nr = elev.size
    kp = pcnt.size
    n_p = np.zeros(kp, dtype=np.int64)
    n_exp = np.zeros(kp, dtype=np.int64)
    acc = np.zeros((kp, 3))
    ce = np.cos(elev)
    se = np.sin(elev)
    ox, oy, oz = origin[0], origin[1], origin[2]
    cy, sy = np.cos(yaw), np.sin(yaw)
    for k in range(kp):
        c0, nc, rings = _sector(origin, yaw, pbc[k], pbr[k], az0, daz, ncol, elev)
        for cc in range(nc):
            c = (c0 + cc) % ncol
            az_s = az0 + c * daz
            az = az_s + yaw
            ca, sa = np.cos(az), np.sin(az)
            for r in range(nr):
                if not rings[r]:
                    continue
                ux, uy, uz = ce[r] * ca, ce[r] * sa, se[r]
                t = _hit_polygon(ox, oy, oz, ux, uy, uz, pn[k], pd[k], po[k], pu[k], pv[k], pv2[k], pcnt[k], 1e-6, rmax)
                if not np.isfinite(t):
                    continue
                n_exp[k] += 1
                m = meas[r, c]
                if np.isnan(m) or m >= t - tol:
                    n_p[k] += 1
                    # the hit in the sensor frame (rotate the world offset back by -yaw)
                    wx, wy = t * ux, t * uy
                    acc[k, 0] += cy * wx + sy * wy
                    acc[k, 1] += -sy * wx + cy * wy
                    acc[k, 2] += t * uz
    return n_p, n_exp, acc
