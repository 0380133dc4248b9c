"""The runtime detection model of planar landmarks: P_D from the current cloud, clutter in the plane chart.

Built from a ``lidar3d-planes`` profile (:mod:`profiles.planes`); a map filter
calls the same two methods as on :class:`detectors.model.DetectionModel`:

* :meth:`PlaneDetectionModel.pd_features` -- P_D (P, J) and buffer-zone flags of
  the map planes (world chart, :mod:`detectors.geometry3d`) of P particles. The
  covariate is the expected number of lidar returns on the plane's visible part
  (the n_p idea in 3D) and the incidence angle, as calibrated. A map plane has
  no extent, so at run time the visible part is read off the current cloud: the
  returns inside the plane's slab (half-width ``slab_k_sigma`` times the sensor
  noise combined with the plane's own offset and tilt uncertainty at each
  return's range) are the returns the plane gave -- an occluded part gives none,
  as the measured range shortens in the 2D n_p; the count is scaled by the
  calibration's ratio of slab counts to ray-traced counts (``slab_ratio``), and
  the incidence angle is that of the slab returns' centroid. A cloud
  subsample (at most ``sample`` returns, a fixed stride) keeps this to one
  matrix product per frame;
  **Extents** (``extents``; the settings' ``detection.plane_extents``): a map plane is bounded by the outlines of the detections that
  lie on it -- the model keeps every landmark detection's convex outline of earlier frames in the world frame
  (from the particles' mean sensor pose), and a map plane's extent is the convex hull of the outlines within
  ``extent_gate`` of it in the plane metric (L n, d), projected onto it. Its n_p is then what the calibration
  counts (:func:`detectors.raytrace3d.visible_planes`, the same code): the beams that would hit the bounded
  plane and are not occluded in the measured range image (a shorter return occludes; a longer one passes
  through, so a plane that is not there -- a duplicate track a few cm off a facade, a false plane born from
  clutter -- is visible, predicted detected, and pays for its misses, where the slab of an infinite plane holds
  no returns and would give it P_D 0). Map planes no outline bounds (none within the gate) fall back to the
  slab count;
* :meth:`PlaneDetectionModel.clutter_intensity` -- kappa(z) = lambda / |V| over the
  chart of landmark planes (azimuth over the full circle, elevation within
  ``max_elevation`` of vertical... i.e. |phi| <= max_elevation, offset up to
  ``offset_max``), 0 outside.

The slab counts are taken from the particles' mean sensor pose (``common_pose``):
with each particle's own pose, a particle turned a little off a plane finds
fewer returns in the plane's slab, predicts a lower P_D and so loses less
weight when the detector misses the plane -- a pull toward misaligned
particles that doubled the trajectory error on the simulated street. The
particles differ by centimetres; P_D is the scene's, not the pose hypothesis's.

Constant mode (for comparison): P_D = ``constant_pd`` for every plane in view.
Buffer zone (eq. 3.21): planes with 0 < P_D < 0.5 (the thesis's rule) or whose
offset is within ``buffer_sigmas`` of the range limit.
"""

from __future__ import annotations

from dataclasses import dataclass

import numba
import numpy as np

from detectors.geometry3d import normal_from_chart, plane_basis, world_to_sensor
from detectors.raytrace3d import BeamGrid, Scene, range_image, visible_planes
from profiles.errors import DataError
from profiles.planes import PdGrid, PlaneNoise
from profiles.schema import ClutterParams, PdTable


@dataclass(frozen=True, eq=False)
class PlaneDetectionModel:
    """P_D over (expected visible points x incidence) + Poisson clutter of a plane detector on a 3D lidar.

    height: sensor height [m]; range_sigma: the lidar's range noise [m]; max_elevation [rad]
    and offset_max [m]: which planes are landmarks (the view); noise: the measured chart noise.
    """

    pd_table: PdTable | None
    clutter: ClutterParams
    height: float
    range_sigma: float
    max_elevation: float
    offset_max: float
    pd_grid: PdGrid | None = None
    noise: PlaneNoise | None = None
    slab_k_sigma: float = 3.0
    slab_ratio: float = 1.0
    constant_pd: float | None = None
    buffer: bool = True
    buffer_sigmas: float = 2.0
    sample: int = 8000
    common_pose: bool = True
    grid: BeamGrid | None = None
    range_max: float = 120.0
    extents: bool = False
    frame_clutter: bool = False
    clutter_memory: float = 0.0
    extent_gate: float = 0.15
    metric_length: float = 10.0

    def __post_init__(self) -> None:
        # the outline store (world frame): filled between frames by pd_features, so frozen fields stay frozen
        object.__setattr__(self, "_store", _OutlineStore())
        if self.constant_pd is None and self.pd_table is None and self.pd_grid is None:
            raise DataError("a plane detection model needs a P_D table (or constant P_D)")
        if self.pd_table is not None and self.pd_table.covariate != "points":
            raise DataError(f"a plane detection model needs a P_D table over points, not {self.pd_table.covariate}")

    @classmethod
    def from_options(cls, profile, sensor, options, k_sigma: float | None = None) -> PlaneDetectionModel:
        """The runtime model with a filter's detection options (P_D mode, buffer zone; the point features' options
        and the occlusion tolerance do not apply to planes)."""
        o = options
        return cls.from_profile(
            profile, constant_pd=o.constant_pd if o.pd_mode == "constant" else None, buffer=o.buffer_zone, buffer_sigmas=o.buffer_sigmas,
            extents=o.plane_extents, frame_clutter=o.frame_clutter, clutter_memory=o.clutter_memory,
        )

    @classmethod
    def from_profile(
        cls, profile, *, constant_pd: float | None = None, buffer: bool = True, buffer_sigmas: float = 2.0, extents: bool = False,
        frame_clutter: bool = False, clutter_memory: float = 0.0, **_ignored
    ) -> PlaneDetectionModel:
        """The runtime model of a ``lidar3d-planes`` :class:`profiles.profile.DetectorProfile`."""
        st = profile.planes
        if st is None or profile.sensor.lidar is None:
            raise DataError(f"profile {profile.ref} is not a lidar3d-planes profile")
        return cls(
            pd_table=profile.pd,
            clutter=profile.clutter,
            height=profile.sensor.lidar.height,
            range_sigma=float(profile.sensor.range_sigma or 0.02),
            max_elevation=float(np.radians(st.max_elevation_deg)),
            offset_max=st.offset_max,
            pd_grid=st.pd_grid,
            noise=st.noise,
            slab_k_sigma=st.slab_k_sigma,
            slab_ratio=st.slab_ratio or 1.0,
            constant_pd=constant_pd,
            buffer=buffer,
            buffer_sigmas=buffer_sigmas,
            grid=BeamGrid.of(profile.sensor.lidar),
            range_max=float(profile.sensor.range_max or 120.0),
            extents=extents,
            frame_clutter=frame_clutter,
            clutter_memory=clutter_memory,
        )

    @property
    def noise_sigmas(self) -> tuple[float, float, float]:
        """(azimuth [rad], elevation [rad], offset [m]) standard deviations of a detected plane."""
        if self.noise is not None:
            return float(self.noise.azimuth_sigma), float(self.noise.elevation_sigma), float(self.noise.offset_sigma)
        return 0.01, 0.01, 0.05

    def in_view(self, z: np.ndarray) -> np.ndarray:
        """(...) whether sensor-frame planes z (..., 3) are landmarks the detector reports."""
        z = np.asarray(z, dtype=np.float64)
        return (np.abs(z[..., 1]) <= self.max_elevation) & (z[..., 2] > 0.0) & (z[..., 2] <= self.offset_max)

    def clutter_intensity(self, z: np.ndarray) -> np.ndarray:
        """kappa(z) (M,) for sensor-frame plane measurements z (M, 3), per unit of the chart (rad^2 m)."""
        z = np.atleast_2d(np.asarray(z, dtype=np.float64))
        return np.where(self.in_view(z), self.clutter.kappa, 0.0)

    @staticmethod
    def chart_volume(max_elevation: float, offset_max: float) -> float:
        """|V| of the chart of landmark planes: 2 pi x 2 max_elevation x offset_max [rad^2 m]."""
        return float(2 * np.pi * 2 * max_elevation * offset_max)

    # ------------------------------------------------------------------ P_D
    def visible_points(self, sensor_poses: np.ndarray, mu: np.ndarray, cov: np.ndarray, cloud: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Expected visible returns (P, J) (slab count / slab_ratio) and incidence angle [rad] (P, J) of map planes
        mu (P, J, 3) (world chart) with covariances cov (P, J, 3, 3) from sensor poses (P, 3), given the frame's
        cloud (N, >=3) in the sensor frame. Planes out of view get 0 points and NaN angles."""
        p, j = mu.shape[:2]
        n_out = np.zeros((p, j))
        ang_out = np.full((p, j), np.nan)
        q_all = np.asarray(cloud, dtype=np.float64)[:, :3]
        if j == 0 or q_all.shape[0] == 0:
            return n_out, ang_out
        stride = max(1, int(np.ceil(q_all.shape[0] / self.sample)))
        q = q_all[::stride]
        scale = q_all.shape[0] / q.shape[0]
        rq = np.linalg.norm(q, axis=1)
        z, h = world_to_sensor(mu, np.asarray(sensor_poses, dtype=np.float64)[:, None, :], self.height)
        view = self.in_view(z)
        if not view.any():
            return n_out, ang_out
        pi_, ji = np.nonzero(view)
        zs = z[pi_, ji]
        s = h[pi_, ji] @ cov[pi_, ji] @ np.swapaxes(h[pi_, ji], -1, -2)
        ns, ds = normal_from_chart(zs)
        k = self.slab_k_sigma
        base = k * np.sqrt(self.range_sigma**2 + np.maximum(s[:, 2, 2], 0.0))
        tilt = k * np.sqrt(np.maximum(s[:, 0, 0] * np.cos(zs[:, 1]) ** 2 + s[:, 1, 1], 0.0))
        # particles share most map planes after resampling: count each distinct (plane, spread) once
        key = np.column_stack([ns, ds, base, tilt])
        uniq, first, inv = np.unique(key, axis=0, return_index=True, return_inverse=True)
        cnt_u, acc_u = _slab_counts(ns[first], ds[first], base[first], tilt[first], np.ascontiguousarray(q), rq)
        cnt, acc = cnt_u[inv.reshape(-1)], acc_u[inv.reshape(-1)]
        cen = acc / np.maximum(cnt, 1.0)[:, None]
        cos_inc = np.abs((ns * cen).sum(1)) / np.maximum(np.linalg.norm(cen, axis=1), 1e-9)
        n_out[pi_, ji] = cnt * scale / self.slab_ratio
        ang_out[pi_, ji] = np.where(cnt > 0, np.arccos(np.clip(cos_inc, 0.0, 1.0)), np.nan)
        return n_out, ang_out

    def bounded_points(self, sensor_pose: np.ndarray, mu: np.ndarray, cloud: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """n_p (P, J), incidence angle [rad] (P, J) and whether an extent bounds the plane (P, J), for map planes mu
        (P, J, 3) (world chart) from one sensor pose (3,) given the frame's cloud: each plane bounded by the convex
        hull of the stored outlines within ``extent_gate`` (module docstring), ray-traced against the cloud's range
        image by the calibration's :func:`detectors.raytrace3d.visible_planes`."""
        p, j = mu.shape[:2]
        n_out, ang_out, has = np.zeros((p, j)), np.full((p, j), np.nan), np.zeros((p, j), dtype=bool)
        st = self._store
        if j == 0 or st.count == 0:
            return n_out, ang_out, has
        flat = mu.reshape(-1, 3)
        uniq, inv = np.unique(flat, axis=0, return_inverse=True)  # particles share most map planes
        nrm, off = normal_from_chart(uniq)
        polys = st.extents(nrm, off, self.extent_gate, self.metric_length)
        ok = np.array([q is not None for q in polys], dtype=bool)
        if not ok.any():
            return n_out, ang_out, has
        idx = np.flatnonzero(ok)
        cnt = np.array([polys[i].shape[0] for i in idx])
        v = np.zeros((idx.size, int(cnt.max()), 3))
        for r, i in enumerate(idx):  # one polygon per distinct map plane (tens), not per pair
            v[r, : cnt[r]] = polys[i]
        z = np.zeros
        scene = Scene(v, cnt, z((0, 2)), z(0), z((0, 2)), z((0, 3)), z(0))
        n_p, _, cen = visible_planes(
            scene, self.grid, sensor_pose, self.height, range_image(cloud, self.grid), range_sigma=self.range_sigma, range_max=self.range_max
        )
        # incidence in the sensor frame: the world normal turned by the heading, against the hits' centroid
        c, s_ = np.cos(sensor_pose[2]), np.sin(sensor_pose[2])
        ns = nrm[idx]
        ns = np.column_stack([c * ns[:, 0] + s_ * ns[:, 1], -s_ * ns[:, 0] + c * ns[:, 1], ns[:, 2]])
        cos_inc = np.abs((ns * np.nan_to_num(cen)).sum(1)) / np.maximum(np.linalg.norm(np.nan_to_num(cen), axis=1), 1e-9)
        n_u, ang_u = np.zeros(uniq.shape[0]), np.full(uniq.shape[0], np.nan)
        n_u[idx] = n_p
        ang_u[idx] = np.where(n_p > 0, np.arccos(np.clip(cos_inc, 0.0, 1.0)), np.nan)
        inv = inv.reshape(-1)
        return n_u[inv].reshape(p, j), ang_u[inv].reshape(p, j), ok[inv].reshape(p, j)

    def pd_of(self, points: np.ndarray, angle: np.ndarray) -> np.ndarray:
        """P_D for expected visible points and incidence angles [rad] (the grid when calibrated, else the 1-D table)."""
        if self.pd_grid is not None:
            return self.pd_grid.lookup(points, np.nan_to_num(angle, nan=0.0))
        return self.pd_table.lookup(points)

    def pd_features(
        self, sensor_poses: np.ndarray, mu: np.ndarray, cov: np.ndarray, meas, weights: np.ndarray | None = None
    ) -> tuple[np.ndarray, np.ndarray]:
        """What a map filter calls: P_D (P, J) and buffer flags (P, J) of map planes mu (P, J, 3) (world chart)
        with covariances cov (P, J, 3, 3) from sensor poses (P, 3), given the frame's measurements (its cloud).
        ``weights`` (the features' weights) are not needed: occlusion is read off the cloud itself."""
        p, j = mu.shape[:2]
        if j == 0:
            return np.zeros((p, 0)), np.zeros((p, 0), dtype=bool)
        z, h = world_to_sensor(mu, np.asarray(sensor_poses, dtype=np.float64)[:, None, :], self.height)
        view = self.in_view(z)
        if self.constant_pd is not None:
            pd = np.where(view, self.constant_pd, 0.0)
        else:
            cloud = getattr(meas, "cloud", None)
            if cloud is None:
                raise DataError("P_D of planes needs the frame's point cloud")
            sp = np.asarray(sensor_poses, dtype=np.float64)
            if self.common_pose:
                sp = np.broadcast_to(mean_pose(sp), sp.shape)
            n, ang = self.visible_points(sp, mu, cov, cloud)
            if self.extents and self.grid is not None:
                self._store.frame(meas, sp[0], self.height)
                n_b, ang_b, bounded = self.bounded_points(sp[0], mu, cloud)
                n, ang = np.where(bounded, n_b, n), np.where(bounded, ang_b, ang)
            pd = np.where(view, self.pd_of(n, ang), 0.0)
        if not self.buffer:
            return pd, np.zeros((p, j), dtype=bool)
        s_off = np.sqrt(np.maximum(np.einsum("pji,pjik,pjk->pj", h[..., 2, :], cov, h[..., 2, :]), 0.0))
        band = self.buffer_sigmas * np.sqrt(self.range_sigma**2 + s_off**2)
        near_edge = view & (z[..., 2] >= self.offset_max - band)
        buf = ((pd > 0) & (pd < 0.5)) | near_edge
        return pd, buf


class _OutlineStore:
    """Landmark detections' convex outlines, world frame, from every frame before the current one.

    ``frame(meas, pose, height)`` is called by every P_D evaluation of a frame: on a new frame it files the
    previous frame's outlines (so a frame's own detections never bound the planes whose P_D they are scored
    with), then holds this frame's. Each outline is kept as its plane (unit normal (3,), offset) and vertices."""

    def __init__(self) -> None:
        self.normals: list[np.ndarray] = []
        self.offsets: list[np.ndarray] = []
        self.verts: list[np.ndarray] = []
        self._pending = None
        self._key = None
        self._cache = None

    @property
    def count(self) -> int:
        return len(self.verts)

    def frame(self, meas, pose: np.ndarray, height: float) -> None:
        if meas is self._key:
            return
        if self._pending is not None:
            self._file(*self._pending)
        self._key = meas
        out = getattr(meas, "outlines", None)
        self._pending = (out, np.array(pose, dtype=np.float64), height) if out is not None else None

    def _file(self, outlines, pose: np.ndarray, height: float) -> None:
        vert, offs = outlines
        if len(offs) < 2:
            return
        c, s = np.cos(pose[2]), np.sin(pose[2])
        w = np.column_stack([pose[0] + c * vert[:, 0] - s * vert[:, 1], pose[1] + s * vert[:, 0] + c * vert[:, 1], height + vert[:, 2]])
        for m in range(len(offs) - 1):  # a handful of landmark detections a frame
            q = w[offs[m] : offs[m + 1]]
            if q.shape[0] < 3:
                continue
            cen = q.mean(axis=0)
            _, _, vt = np.linalg.svd(q - cen, full_matrices=False)
            n = vt[-1]
            self.normals.append(n)
            self.offsets.append(np.array(n @ cen))
            self.verts.append(q)
        self._cache = None

    def extents(self, nrm: np.ndarray, off: np.ndarray, gate: float, length: float) -> list:
        """For planes (K, 3) unit normals and (K,) offsets (world): the convex hull (V, 3) on each plane of the stored
        outlines within ``gate`` of it in the metric sqrt(L^2 |n1 - n2|^2 + (d1 - d2)^2) (either orientation), or None."""
        from scipy.spatial import ConvexHull, QhullError

        if self._cache is None:
            self._cache = (np.array(self.normals), np.array(self.offsets))
        sn, so = self._cache
        a = np.concatenate([length * nrm, off[:, None]], axis=1)
        b = np.concatenate([length * sn, so[:, None]], axis=1)
        d = np.minimum(np.linalg.norm(a[:, None] - b[None], axis=-1), np.linalg.norm(a[:, None] + b[None], axis=-1))
        out: list = [None] * nrm.shape[0]
        u, v = plane_basis(nrm)
        for k in np.flatnonzero((d < gate).any(axis=1)):  # one hull per distinct map plane
            q = np.vstack([self.verts[i] for i in np.flatnonzero(d[k] < gate)])
            q = q - ((q @ nrm[k]) - off[k])[:, None] * nrm[k]  # onto the map plane
            q2 = np.column_stack([q @ u[k], q @ v[k]])
            try:
                hull = ConvexHull(q2)
            except QhullError:  # degenerate (collinear) outlines bound nothing
                continue
            out[k] = q[hull.vertices]
        return out


def mean_pose(poses: np.ndarray) -> np.ndarray:
    """(3,) the mean of planar poses (P, 3), the heading as a circular mean."""
    return np.array([poses[:, 0].mean(), poses[:, 1].mean(), np.arctan2(np.sin(poses[:, 2]).mean(), np.cos(poses[:, 2]).mean())])


@numba.njit(cache=True, nogil=True)
def _slab_counts(ns, ds, base, tilt, q, rq):  # pragma: no cover - compiled
    """Returns inside each plane's slab |n . q - d| <= base + tilt |q| (count (K,), sum of the returns (K, 3)).

    One fused pass over (planes x returns): the numpy form builds three (K, N) temporaries
    (distances, the test, the mask as floats), several times the memory traffic for the same sums.
    """
    k, n = ns.shape[0], q.shape[0]
    cnt = np.zeros(k)
    acc = np.zeros((k, 3))
    for i in range(k):
        a, b, c, d = ns[i, 0], ns[i, 1], ns[i, 2], ds[i]
        w0, w1 = base[i], tilt[i]
        s0 = s1 = s2 = 0.0
        m = 0.0
        for j in range(n):
            dist = a * q[j, 0] + b * q[j, 1] + c * q[j, 2] - d
            if abs(dist) <= w0 + w1 * rq[j]:
                m += 1.0
                s0 += q[j, 0]
                s1 += q[j, 1]
                s2 += q[j, 2]
        cnt[i] = m
        acc[i, 0], acc[i, 1], acc[i, 2] = s0, s1, s2
    return cnt, acc
