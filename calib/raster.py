"""Likelihood-field rasters and correlative scan matching on them.

A scan is matched to a map by scoring every candidate pose in a window: the
score of a pose is the mean, over the scan's points put in the world frame by
that pose, of a likelihood field ``L = exp(-d^2 / (2 sigma^2))``, ``d`` being
the distance to the nearest map point (Olson, "Real-time correlative scan
matching", ICRA 2009). The search does not depend on the initial guess lying
inside a local optimiser's basin: every pose of the window on a grid of
``resolution`` metres and ``angle_step`` radians is considered.

The window is searched by branch and bound (Hess et al., "Real-time loop
closure in 2D LIDAR SLAM", ICRA 2016, sec. V.C): level ``h`` of the field holds
the maximum of level 0 over the ``2^h x 2^h`` block of cells starting at each
cell, so the score of one level-``h`` candidate bounds the scores of the
``4^h`` translations of its block. Branches whose bound cannot beat the best
exact score found are cut. Here the tree is walked level by level, every
surviving candidate of a level scored at once (vectorised over candidates and
points), which keeps the search exact while avoiding a Python loop per node.

OpenCV does the raster work: the distance transform (``cv2.distanceTransform``)
and the block maxima (``cv2.dilate`` with a square kernel anchored at its corner).

Frames: ``points`` are (N, 2) in the vehicle frame [m]; poses (x, y, theta)
map the vehicle frame into the world frame of the field.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

#: candidates scored in one vectorised batch (bounds the (candidates, points) gather's memory)
_BATCH = 1 << 14


@dataclass(frozen=True)
class LikelihoodField:
    """A likelihood field over a rectangle of the world, with its block-maximum levels.

    origin: (2,) world x, y [m] of the lower-left corner of cell (row 0, column 0); rows run along y.
    resolution: cell side [m]; sigma: the field's spread [m].
    levels: ``levels[h]`` (H, W) float32; ``levels[0]`` is the field, ``levels[h][r, c]`` the maximum
    of ``levels[0]`` over rows r..r+2^h-1 and columns c..c+2^h-1. The outermost ring of cells is 0, so
    clipped indices read 0 for points off the raster.
    """

    origin: np.ndarray
    resolution: float
    levels: tuple[np.ndarray, ...]
    sigma: float

    @classmethod
    def from_points(cls, pts: np.ndarray, resolution: float, sigma: float, depth: int = 0, margin: float = 1.0) -> LikelihoodField:
        """The field of world points ``pts`` (N, 2) [m], with block-maximum levels 1..``depth``.

        sigma [m]: spread of the field around each point (sensor noise plus the raster's own, about a cell).
        margin [m]: free border around the points' bounding box.
        """
        pts = np.asarray(pts, dtype=np.float64)
        if pts.ndim != 2 or pts.shape[1] != 2 or pts.shape[0] == 0:
            raise ValueError("pts: expected (N, 2) points, N >= 1")
        lo = pts.min(axis=0) - margin
        shape = np.ceil((pts.max(axis=0) + margin - lo) / resolution).astype(int) + 1
        cells = np.floor((pts - lo) / resolution).astype(np.int64)
        free = np.full((shape[1], shape[0]), 255, dtype=np.uint8)
        free[cells[:, 1], cells[:, 0]] = 0
        # distance [cells] from every cell to the nearest occupied one
        dist = cv2.distanceTransform(free, cv2.DIST_L2, cv2.DIST_MASK_PRECISE)
        field = np.exp(-0.5 * (dist * (resolution / sigma)) ** 2).astype(np.float32)
        field[0, :] = field[-1, :] = field[:, 0] = field[:, -1] = 0.0
        return cls(lo, float(resolution), (field,), float(sigma)).deepened(depth)

    def deepened(self, depth: int) -> LikelihoodField:
        """This field with block-maximum levels up to ``depth`` (itself when it has them already)."""
        if depth <= self.depth:
            return self
        levels = list(self.levels)
        for h in range(len(levels), depth + 1):
            k = 1 << h
            # dilate with anchor (0, 0): dst[r, c] = max of src[r:r+k, c:c+k]; outside the raster counts as 0
            levels.append(
                cv2.dilate(levels[0], np.ones((k, k), np.uint8), anchor=(0, 0), borderType=cv2.BORDER_CONSTANT, borderValue=0.0)
            )
        return LikelihoodField(self.origin, self.resolution, tuple(levels), self.sigma)

    @property
    def occupied(self) -> float:
        """Field value of a cell whose centre is half a cell from a map point (the occupied cells are above it)."""
        return float(np.exp(-0.5 * (0.5 * self.resolution / self.sigma) ** 2))

    @property
    def depth(self) -> int:
        return len(self.levels) - 1

    def score(self, world: np.ndarray) -> float:
        """Mean field value at world points (M, 2) (nearest cell; 0 off the raster)."""
        c = np.floor((world - self.origin) / self.resolution).astype(np.int64)
        f = self.levels[0]
        c[:, 0] = np.clip(c[:, 0], 0, f.shape[1] - 1)
        c[:, 1] = np.clip(c[:, 1], 0, f.shape[0] - 1)
        return float(f[c[:, 1], c[:, 0]].mean()) if world.shape[0] else 0.0


def see_through(field: LikelihoodField, origin: np.ndarray, ends: np.ndarray, clearance: np.ndarray | float) -> np.ndarray:
    """(N,) bool: beams from ``origin`` (2,) to their returns ``ends`` (N, 2) (world frame) that pass through the map.

    A beam passes through the map when it crosses an occupied cell (within half a cell of a map point)
    between 0.3 m after its start and ``clearance`` (scalar or (N,)) [m] before its return: the scan saw
    free space where the map has a surface. A correct alignment has few such beams (moving things); an
    aliased one, laid over a look-alike place, has many. The clearance must cover the stretch where a beam
    runs close to the surface it ends on (long for grazing incidence).
    """
    res = field.resolution
    d = ends - origin
    length = np.hypot(d[:, 0], d[:, 1])
    start = 0.3
    steps = np.arange(start, max(float(length.max(initial=0.0)), start), res / 2)
    if steps.size == 0:
        return np.zeros(ends.shape[0], dtype=bool)
    u = d / np.maximum(length, 1e-9)[:, None]
    inside = steps[None, :] <= (length - np.broadcast_to(clearance, length.shape))[:, None]  # (N, T)
    x = origin[0] + u[:, 0:1] * steps[None, :]
    y = origin[1] + u[:, 1:2] * steps[None, :]
    f = field.levels[0]
    c = np.clip(np.floor((x - field.origin[0]) / res).astype(np.int64), 0, f.shape[1] - 1)
    r = np.clip(np.floor((y - field.origin[1]) / res).astype(np.int64), 0, f.shape[0] - 1)
    return ((f[r, c] >= field.occupied) & inside).any(axis=1)


@dataclass(frozen=True)
class CorrelativeMatch:
    """Best pose of a correlative search and its score (mean likelihood over the scan's points, 0..1, without
    the motion prior's cost)."""

    pose: np.ndarray  # (3,) world pose of the vehicle
    score: float
    candidates: int  # candidates scored (all levels), a measure of the work done


def voxel_filter(points: np.ndarray, size: float) -> np.ndarray:
    """One point (the first in scan order) per ``size``-metre square cell: (M, 2), M <= N.

    Evens out the density of a scan (near walls would otherwise dominate a mean score).
    """
    if points.shape[0] == 0:
        return points
    key = np.floor(points / size).astype(np.int64)
    _, first = np.unique(key[:, 0] * 2_000_003 + key[:, 1], return_index=True)
    return points[np.sort(first)]


def angle_step_for(points: np.ndarray, resolution: float) -> float:
    """Angular step [rad] that moves a far point by about one cell (Hess et al. 2016, eq. 7).

    "Far" is the 90th percentile of the points' distances rather than the farthest (a few stray far returns
    would make the step, and the search's cost, several times finer for nothing the ICP refinement needs).
    """
    d_max = float(np.quantile(np.hypot(points[:, 0], points[:, 1]), 0.9)) if points.shape[0] else 1.0
    d_max = max(d_max, resolution)
    return float(np.arccos(max(-1.0, 1.0 - resolution**2 / (2.0 * d_max**2))))


def correlative_match(
    field: LikelihoodField,
    points: np.ndarray,
    guess: np.ndarray,
    linear_window: float,
    angular_window: float,
    *,
    angle_step: float | None = None,
    min_score: float = 0.0,
    translation_cost: float = 0.0,
    rotation_cost: float = 0.0,
) -> CorrelativeMatch | None:
    """Best pose of ``points`` (N, 2, vehicle frame) within ``guess`` +- windows, by exact branch and bound.

    linear_window [m]: half-width of the square of translations searched around the guess.
    angular_window [rad]: half-width of the headings searched; ``angle_step`` defaults to one cell
    at the farthest point. Returns None when no candidate scores above ``min_score``.

    translation_cost [1/m^2], rotation_cost [1/rad^2]: a motion prior; a candidate's score is its mean
    likelihood less ``translation_cost * |t - t_guess|^2 + rotation_cost * (theta - theta_guess)^2``,
    so that among poses the scan cannot tell apart (a corridor's axis) the one nearest the guess wins.
    The field must have ``ceil(log2(2 * linear_window / resolution + 1))`` levels for the full
    branch and bound; with fewer the search starts at its deepest level (exact, more candidates).
    """
    pts = np.asarray(points, dtype=np.float64)
    if pts.shape[0] == 0:
        return None
    res = field.resolution
    step = angle_step or angle_step_for(pts, res)
    n_ang = int(np.ceil(angular_window / step)) if angular_window > 0 else 0
    thetas = guess[2] + step * np.arange(-n_ang, n_ang + 1)
    c, s = np.cos(thetas), np.sin(thetas)
    # (A, N) cell coordinates of every point for every heading, translation at the guess
    wx = c[:, None] * pts[None, :, 0] - s[:, None] * pts[None, :, 1] + guess[0]
    wy = s[:, None] * pts[None, :, 0] + c[:, None] * pts[None, :, 1] + guess[1]
    bc = np.floor((wx - field.origin[0]) / res).astype(np.int32)
    br = np.floor((wy - field.origin[1]) / res).astype(np.int32)
    w = int(np.ceil(linear_window / res))
    depth = min(field.depth, int(np.ceil(np.log2(2 * w + 1))) if w > 0 else 0)
    shape = field.levels[0].shape

    ang_pen = rotation_cost * (thetas - guess[2]) ** 2

    def nearest(lo: np.ndarray, size: int) -> np.ndarray:
        """|offset| [cells] nearest 0 within the block lo..lo+size-1 (clipped to the window)."""
        hi = np.minimum(lo + size - 1, w)
        return np.where((lo <= 0) & (hi >= 0), 0, np.minimum(np.abs(lo), np.abs(hi)))

    def scores(level: int, a: np.ndarray, dx: np.ndarray, dy: np.ndarray) -> np.ndarray:
        grid = field.levels[level]
        out = np.empty(a.size, dtype=np.float64)
        for lo in range(0, a.size, _BATCH):
            sl = slice(lo, lo + _BATCH)
            rows = np.clip(br[a[sl]] + dy[sl, None], 0, shape[0] - 1)
            cols = np.clip(bc[a[sl]] + dx[sl, None], 0, shape[1] - 1)
            out[sl] = grid[rows, cols].mean(axis=1)
        if translation_cost or rotation_cost:
            size = 1 << level
            mx, my = nearest(dx, size) * res, nearest(dy, size) * res
            out -= translation_cost * (mx**2 + my**2) + ang_pen[a]
        return out

    def scores_raw(ia: int, dx: int, dy: int) -> float:
        rows = np.clip(br[ia] + dy, 0, shape[0] - 1)
        cols = np.clip(bc[ia] + dx, 0, shape[1] - 1)
        return field.levels[0][rows, cols].mean()

    top = 1 << depth
    starts = np.arange(-w, w + 1, top, dtype=np.int32)
    a, ix, iy = (g.ravel() for g in np.meshgrid(np.arange(thetas.size, dtype=np.int32), starts, starts, indexing="ij"))
    sc = scores(depth, a, ix, iy)
    work = sc.size
    best, best_cand = min_score, None

    def children(a, ix, iy, half):
        offs = np.array([[0, 0], [half, 0], [0, half], [half, half]], dtype=np.int32)
        ca = np.repeat(a, 4)
        cx = (ix[:, None] + offs[None, :, 0]).ravel()
        cy = (iy[:, None] + offs[None, :, 1]).ravel()
        keep = (cx <= w) & (cy <= w)
        return ca[keep], cx[keep], cy[keep]

    # a first exact score to cut with: dive greedily from the best few top-level candidates
    for i in np.argsort(-sc, kind="stable")[:3]:
        if sc[i] <= best:
            break
        da, dx, dy = a[i : i + 1], ix[i : i + 1], iy[i : i + 1]
        for h in range(depth, 0, -1):
            da, dx, dy = children(da, dx, dy, 1 << (h - 1))
            ds = scores(h - 1, da, dx, dy)
            work += ds.size
            j = int(np.argmax(ds))
            da, dx, dy = da[j : j + 1], dx[j : j + 1], dy[j : j + 1]
        exact = scores(0, da, dx, dy)[0] if depth == 0 else ds[j]
        if exact > best:
            best, best_cand = float(exact), (int(da[0]), int(dx[0]), int(dy[0]))
    for h in range(depth, 0, -1):
        keep = sc > best
        a, ix, iy = children(a[keep], ix[keep], iy[keep], 1 << (h - 1))
        sc = scores(h - 1, a, ix, iy)
        work += sc.size
        if a.size == 0:
            break
    if a.size:
        i = int(np.argmax(sc))
        if sc[i] > best:
            best, best_cand = float(sc[i]), (int(a[i]), int(ix[i]), int(iy[i]))
    if best_cand is None:
        return None
    ia, dx, dy = best_cand
    pose = np.array([guess[0] + dx * res, guess[1] + dy * res, np.mod(thetas[ia] + np.pi, 2 * np.pi) - np.pi])
    raw = best if not (translation_cost or rotation_cost) else float(scores_raw(ia, dx, dy))
    return CorrelativeMatch(pose, raw, work)
