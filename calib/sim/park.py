"""A 2D park simulator whose truth is exported.

The world: tree trunks (circles, radii from a configurable distribution),
non-tree clutter sources -- bushes (irregular star-shaped polygons), walls and
fences (segments), thin posts (small circles) -- and spurious returns (dust)
drawn per beam. A vehicle drives a figure-eight or a lawnmower path through
it; a 2D laser mounted on the vehicle casts every beam against the world
(nearest hit, Gaussian range noise, missing returns, maximum range), and the
wheel odometry reports noisy pose increments.

Everything needed to re-derive any scan is exported: the world geometry, the
true poses at every odometry tick, the sensor model and the config with its
seed. Defaults resemble the thesis's park setting (Inostroza 2015, ch. 6):
361 beams over 180 degrees, 80 m range, sigma_r = 2 cm, 300 trees, and about
5.5 false alarms per scan after gating (the thesis measured 6.18).

Same config and seed, same bytes: all draws come from one
``numpy.random.Generator`` in a fixed order.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cached_property
from typing import Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, model_validator
from scipy.spatial import cKDTree

from calib.config import dump_yaml
from calib.sim import SIMULATORS, Simulated, Simulator
from detectors.geometry import cast, compose, relative
from detectors.sensor_log import Landmarks, Mount, Odometry, ReferencePoses, ScanBatch, SensorLog, SensorModel, seconds_to_stamp
from profiles.errors import DataError
from profiles.override import updated
from profiles.parameters import check_order


def _libm(fn, nin: int):
    """``fn`` of the platform's libm (Python's math) element by element, as float64 arrays. numpy hands float64
    sin, cos, exp, arctan2 and hypot to SIMD kernels chosen by the CPU, and the AVX-512 ones round some results
    differently in the last bit: the simulated log (and the bundled profile's provenance hash of it) would depend on
    the machine. The simulator's few thousand poses afford the scalar calls."""
    u = np.frompyfunc(fn, nin, 1)
    return lambda *a: np.asarray(u(*(np.asarray(x, dtype=np.float64) for x in a)), dtype=np.float64)


_sin, _cos, _exp = _libm(math.sin, 1), _libm(math.cos, 1), _libm(math.exp, 1)
_arctan2, _hypot = _libm(math.atan2, 2), _libm(math.hypot, 2)


#: odometry ticks a simulated run may hold at most (about 14 hours at 200 Hz): a slower speed or a faster rate is refused
MAX_TICKS = 10_000_000
#: beams a simulated run may hold at most (800 MB of ranges)
MAX_RETURNS = 200_000_000


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)


class RadiusDist(_Strict):
    """Trunk radius distribution [m]: uniform on [min, max] or log-normal clipped to it."""

    kind: Literal["uniform", "lognormal"] = "lognormal"
    min: float = Field(default=0.05, gt=0.0)
    max: float = Field(default=0.5, gt=0.0)
    median: float = Field(default=0.18, gt=0.0)
    sigma: float = Field(default=0.5, gt=0.0, description="log-space standard deviation")

    @model_validator(mode="after")
    def _order(self) -> RadiusDist:
        check_order(self, "min", "max")
        return self


class TreesConfig(_Strict):
    count: int = Field(default=300, ge=0)
    radius: RadiusDist = RadiusDist()
    min_spacing: float = Field(default=1.5, ge=0.0, description="minimum gap between trunk surfaces [m]")


class BushesConfig(_Strict):
    """Irregular shrubs: the main source of false alarms.

    Many small ones rather than a few big ones: the clutter rate of a world then
    varies little between worlds of the same statistics (docs/results.md).
    """

    count: int = Field(default=150, ge=0)
    min_radius: float = Field(default=0.3, gt=0.0)
    max_radius: float = Field(default=1.0, gt=0.0)
    vertices: int = Field(default=10, ge=3)
    irregularity: float = Field(default=0.35, ge=0.0, lt=1.0, description="radial jitter as a fraction of the radius")

    @model_validator(mode="after")
    def _order(self) -> BushesConfig:
        check_order(self, "min_radius", "max_radius")
        return self


class WallsConfig(_Strict):
    count: int = Field(default=8, ge=0)
    min_length: float = Field(default=5.0, gt=0.0)
    max_length: float = Field(default=30.0, gt=0.0)
    fence_fraction: float = Field(default=0.5, ge=0.0, le=1.0, description="share of walls that are open fences (short panels)")

    @model_validator(mode="after")
    def _order(self) -> WallsConfig:
        check_order(self, "min_length", "max_length")
        return self


class PostsConfig(_Strict):
    count: int = Field(default=40, ge=0)
    min_radius: float = Field(default=0.02, gt=0.0)
    max_radius: float = Field(default=0.04, gt=0.0)

    @model_validator(mode="after")
    def _order(self) -> PostsConfig:
        check_order(self, "min_radius", "max_radius")
        return self


class PathConfig(_Strict):
    kind: Literal["figure8", "lawnmower"] = "figure8"
    speed: float = Field(default=2.0, gt=0.0, description="m/s")
    laps: float = Field(default=1.0, gt=0.0)
    margin: float = Field(default=15.0, ge=0.0, description="distance kept from the park's edge [m]")
    clearance: float = Field(default=2.5, ge=0.0, description="no obstacle within this distance of the path [m]")
    row_spacing: float = Field(default=25.0, gt=0.0, description="lawnmower row spacing [m]")


class LaserConfig(_Strict):
    n_beams: int = Field(default=361, ge=2, le=100_000)
    fov_deg: float = Field(default=180.0, gt=0.0, le=360.0)
    range_max: float = Field(default=80.0, gt=0.0)
    range_sigma: float = Field(default=0.02, ge=0.0)
    p_miss: float = Field(default=0.01, ge=0.0, le=1.0, description="probability that a beam hitting something returns nothing")
    p_spurious: float = Field(default=0.002, ge=0.0, le=1.0, description="per-beam probability of a dust return")
    spurious_min: float = Field(default=0.5, gt=0.0, description="closest dust return [m]")
    landmark_dropout: float = Field(
        default=0.0, ge=0.0, le=1.0,
        description="probability that a tree farther than dropout_beyond returns nothing in a scan: a weaker sensor whose P_D there is "
        "(1 - landmark_dropout) times what it would be (validation's drift tests use it)",
    )
    dropout_beyond: float = Field(default=10.0, ge=0.0, description="range beyond which trees drop out [m], sensor to trunk centre")
    rate_hz: float = Field(default=5.0, gt=0.0)
    mount: Mount = Mount(x=0.5, y=0.0, theta=0.0)


class OdometryConfig(_Strict):
    """Noise of the odometry increments (probabilistic-robotics style).

    Translation std = alpha_trans * |d|, rotation std = alpha_rot * |dtheta| + alpha_rot_trans * |d|.
    """

    rate_hz: float = Field(default=20.0, gt=0.0)
    alpha_trans: float = Field(default=0.03, ge=0.0)
    alpha_rot: float = Field(default=0.03, ge=0.0)
    alpha_rot_trans: float = Field(default=0.005, ge=0.0, description="rad per m")
    lateral: float = Field(default=0.01, ge=0.0, description="lateral slip std per m travelled")


class ParkConfig(_Strict):
    """The whole simulation; every field has a default that works."""

    width: float = Field(default=200.0, gt=10.0, description="park extent in x [m]")
    height: float = Field(default=150.0, gt=10.0, description="park extent in y [m]")
    trees: TreesConfig = TreesConfig()
    bushes: BushesConfig = BushesConfig()
    walls: WallsConfig = WallsConfig()
    posts: PostsConfig = PostsConfig()
    path: PathConfig = PathConfig()
    laser: LaserConfig = LaserConfig()
    odometry: OdometryConfig = OdometryConfig()

    @model_validator(mode="after")
    def _room(self) -> ParkConfig:
        """The path's margin must leave room inside the park (checked here so that the message names the config)."""
        m, sp = self.path.margin, self.path.row_spacing
        if self.path.kind == "figure8" and m >= min(self.width, self.height) / 2:
            raise ValueError(
                f"path.margin ({m} m) leaves no room for the figure-eight in a {self.width} x {self.height} m park "
                "(it must be below half the smaller side)"
            )
        if self.path.kind == "lawnmower" and (np.arange(m, self.height - m + 1e-9, sp).size < 2 or self.width - 2 * m - sp <= 0):
            raise ValueError(
                f"path.margin ({m} m) and path.row_spacing ({sp} m) leave no room for two lawnmower rows in a "
                f"{self.width} x {self.height} m park"
            )
        return self


#: sensor changes a validation should catch (calib.drift; the docs' drift study): name -> what changes
CHANGES = {
    "pd_lower": "a tree beyond 10 m returns nothing in a scan with probability 0.1 (P_D x 0.9 there)",
    "clutter_double": "twice the clutter sources (bushes, posts, walls)",
    "noise_double": "twice the range noise",
}


def changed(cfg: ParkConfig, change: str) -> ParkConfig:
    """``cfg`` with one of :data:`CHANGES` applied (validated anew); ``same`` leaves it as it is."""
    if change == "pd_lower":
        return updated(cfg, {"laser.landmark_dropout": 0.1, "laser.dropout_beyond": 10.0})
    if change == "clutter_double":
        return updated(cfg, {f"{k}.count": 2 * getattr(cfg, k).count for k in ("bushes", "posts", "walls")})
    if change == "noise_double":
        return updated(cfg, {"laser.range_sigma": 2 * cfg.laser.range_sigma})
    if change != "same":
        raise ValueError(f"unknown change {change!r}; choose from same, {', '.join(CHANGES)}")
    return cfg


@dataclass(frozen=True, eq=False)
class World:
    """Static geometry, world frame.

    tree_xy (T, 2), tree_r (T,); post_xy (P, 2), post_r (P,);
    bush_vertices (V, 2) with bush_offsets (K + 1,) (polygon k is
    vertices[off[k]:off[k+1]], closed); wall_p0 / wall_p1 (W, 2) segments.
    """

    tree_xy: np.ndarray
    tree_r: np.ndarray
    post_xy: np.ndarray
    post_r: np.ndarray
    bush_vertices: np.ndarray
    bush_offsets: np.ndarray
    wall_p0: np.ndarray
    wall_p1: np.ndarray

    @cached_property
    def _circles(self) -> tuple[np.ndarray, np.ndarray]:
        return np.vstack([self.tree_xy, self.post_xy]), np.concatenate([self.tree_r, self.post_r])

    @cached_property
    def _segments(self) -> tuple[np.ndarray, np.ndarray]:
        v, off = self.bush_vertices, self.bush_offsets
        nxt = np.arange(1, v.shape[0] + 1)
        nxt[off[1:] - 1] = off[:-1]  # each polygon's last vertex closes on its first
        return np.vstack([v, self.wall_p0.reshape(-1, 2)]), np.vstack([v[nxt], self.wall_p1.reshape(-1, 2)])

    def circles(self) -> tuple[np.ndarray, np.ndarray]:
        """All circles: trees first, then posts (built once; every scan casts against them)."""
        return self._circles

    def segments(self) -> tuple[np.ndarray, np.ndarray]:
        """All segments: bush edges, then walls (built once)."""
        return self._segments

    def to_dict(self) -> dict:
        return {
            "trees": {"xy": self.tree_xy.tolist(), "radius": self.tree_r.tolist()},
            "posts": {"xy": self.post_xy.tolist(), "radius": self.post_r.tolist()},
            "bushes": [self.bush_vertices[a:b].tolist() for a, b in zip(self.bush_offsets[:-1], self.bush_offsets[1:], strict=True)],
            "walls": {"p0": self.wall_p0.tolist(), "p1": self.wall_p1.tolist()},
        }

    @classmethod
    def from_dict(cls, d: dict, where: str = "world") -> World:
        try:
            bushes = [np.asarray(b, dtype=np.float64).reshape(-1, 2) for b in d["bushes"]]
            return cls(
                tree_xy=np.asarray(d["trees"]["xy"], dtype=np.float64).reshape(-1, 2),
                tree_r=np.asarray(d["trees"]["radius"], dtype=np.float64).reshape(-1),
                post_xy=np.asarray(d["posts"]["xy"], dtype=np.float64).reshape(-1, 2),
                post_r=np.asarray(d["posts"]["radius"], dtype=np.float64).reshape(-1),
                bush_vertices=np.vstack(bushes) if bushes else np.zeros((0, 2)),
                bush_offsets=np.concatenate([[0], np.cumsum([b.shape[0] for b in bushes])]).astype(np.int64),
                wall_p0=np.asarray(d["walls"]["p0"], dtype=np.float64).reshape(-1, 2),
                wall_p1=np.asarray(d["walls"]["p1"], dtype=np.float64).reshape(-1, 2),
            )
        except (KeyError, TypeError, ValueError) as exc:
            raise DataError(f"{where}: malformed world description ({type(exc).__name__}: {exc})") from None


@dataclass(frozen=True, eq=False)
class Simulation:
    config: ParkConfig
    seed: int
    world: World
    log: SensorLog


# ---------------------------------------------------------------------------- path


def _figure8(cfg: ParkConfig) -> np.ndarray:
    """Dense (N, 2) polyline of a lemniscate of Gerono filling the park inside the margin."""
    a = cfg.width / 2 - cfg.path.margin
    b = cfg.height / 2 - cfg.path.margin
    if a <= 0 or b <= 0:
        raise DataError("path.margin leaves no room for the figure-eight")
    s = np.linspace(0.0, 2 * np.pi, 20001)
    return np.column_stack([cfg.width / 2 + a * _sin(s), cfg.height / 2 + b * _sin(s) * _cos(s) * 2.0])


def _lawnmower(cfg: ParkConfig) -> np.ndarray:
    m, sp = cfg.path.margin, cfg.path.row_spacing
    ys = np.arange(m, cfg.height - m + 1e-9, sp)
    if ys.size < 2:
        raise DataError("path.row_spacing and path.margin leave fewer than two lawnmower rows")
    pts = []
    r = sp / 2
    x0, x1 = m + r, cfg.width - m - r
    if x1 <= x0:
        raise DataError("path.margin and path.row_spacing leave no room for lawnmower rows")
    for k, y in enumerate(ys):
        xs = np.linspace(x0, x1, 2000)
        row = np.column_stack([xs if k % 2 == 0 else xs[::-1], np.full(xs.size, y)])
        pts.append(row)
        if k + 1 < ys.size:  # semicircular turn to the next row
            cx = x1 if k % 2 == 0 else x0
            ang = np.linspace(-np.pi / 2, np.pi / 2, 200)[1:-1]
            side = 1.0 if k % 2 == 0 else -1.0
            pts.append(np.column_stack([cx + side * r * _cos(ang), y + r + r * _sin(ang)]))
    return np.vstack(pts)


def _trajectory(cfg: ParkConfig, dense: np.ndarray, closed: bool) -> tuple[np.ndarray, np.ndarray]:
    """Poses (K, 3) at the odometry ticks moving along ``dense`` at constant speed, and their times (K,)."""
    seg = _hypot(*np.diff(dense, axis=0).T)
    s = np.concatenate([[0.0], np.cumsum(seg)])
    length = s[-1]
    total = length * cfg.path.laps if closed else length
    dt = 1.0 / cfg.odometry.rate_hz
    ticks = np.floor(total / cfg.path.speed / dt) + 1
    if ticks > MAX_TICKS:
        raise DataError(
            f"path.speed ({cfg.path.speed} m/s) and odometry.rate_hz ({cfg.odometry.rate_hz}) give {ticks:.3g} odometry ticks "
            f"over the {total:.0f} m path; at most {MAX_TICKS:,} are simulated"
        )
    t = np.arange(int(ticks)) * dt
    dist = cfg.path.speed * t
    dist = np.mod(dist, length) if closed else np.minimum(dist, length)

    def at(d: np.ndarray) -> np.ndarray:
        d = np.mod(d, length) if closed else np.clip(d, 0.0, length)
        return np.column_stack([np.interp(d, s, dense[:, 0]), np.interp(d, s, dense[:, 1])])

    xy = at(dist)
    ahead, behind = at(dist + 0.05), at(dist - 0.05)  # heading from a central difference along the path
    theta = _arctan2(ahead[:, 1] - behind[:, 1], ahead[:, 0] - behind[:, 0])
    return np.column_stack([xy, theta]), t


# ---------------------------------------------------------------------------- world


def _place(rng: np.random.Generator, n: int, radius: np.ndarray, cfg: ParkConfig, path_tree: cKDTree, taken: list, gap: float) -> np.ndarray:
    """Rejection-sample n centres away from the path and from shapes already placed."""
    out = np.zeros((n, 2))
    placed_xy = [t[0] for t in taken]
    placed_r = [t[1] for t in taken]
    xy_all = np.vstack(placed_xy) if placed_xy else np.zeros((0, 2))
    r_all = np.concatenate(placed_r) if placed_r else np.zeros(0)
    for i in range(n):  # sequential by nature (each placement constrains the next); n is a few hundred
        for _ in range(1000):
            p = rng.uniform([0.0, 0.0], [cfg.width, cfg.height])
            if path_tree.query(p)[0] < cfg.path.clearance + radius[i]:
                continue
            if xy_all.shape[0] and np.min(_hypot(*(xy_all - p).T) - r_all) < radius[i] + gap:
                continue
            break
        else:
            raise DataError("the park is too crowded: could not place every object; lower the counts or the spacing")
        out[i] = p
        xy_all = np.vstack([xy_all, p])
        r_all = np.append(r_all, radius[i])
    taken.append((out, radius))
    return out


def _radii(rng: np.random.Generator, d: RadiusDist, n: int) -> np.ndarray:
    if d.kind == "uniform":
        return rng.uniform(d.min, d.max, n)
    return np.clip(d.median * _exp(d.sigma * rng.standard_normal(n)), d.min, d.max)


def make_world(cfg: ParkConfig, rng: np.random.Generator, path: np.ndarray) -> World:
    path_tree = cKDTree(path[::5])
    taken: list = []
    # largest objects first: a wall needs a free disc of its half length
    w = cfg.walls
    length = rng.uniform(w.min_length, max(w.min_length, w.max_length), w.count)
    half = length / 2
    wall_c = _place(rng, w.count, half, cfg, path_tree, taken, 0.5)
    b = cfg.bushes
    bush_r = rng.uniform(b.min_radius, max(b.min_radius, b.max_radius), b.count)
    bush_c = _place(rng, b.count, bush_r, cfg, path_tree, taken, 0.5)
    tree_r = _radii(rng, cfg.trees.radius, cfg.trees.count)
    tree_xy = _place(rng, cfg.trees.count, tree_r, cfg, path_tree, taken, cfg.trees.min_spacing)
    p = cfg.posts
    post_r = rng.uniform(p.min_radius, max(p.min_radius, p.max_radius), p.count)
    post_xy = _place(rng, p.count, post_r, cfg, path_tree, taken, 0.5)
    ang = np.sort(rng.uniform(0, 2 * np.pi, (b.count, b.vertices)), axis=1)
    rad = bush_r[:, None] * (1.0 - b.irregularity * rng.uniform(0, 1, (b.count, b.vertices)))
    verts = bush_c[:, None, :] + rad[..., None] * np.stack([_cos(ang), _sin(ang)], axis=-1)
    heading = rng.uniform(0, np.pi, w.count)
    u = np.column_stack([_cos(heading), _sin(heading)])
    fence = rng.uniform(0, 1, w.count) < w.fence_fraction
    p0, p1 = [], []
    for k in range(w.count):  # a fence is panels of 2 m with 0.5 m gaps; a wall is one segment
        a, e = wall_c[k] - half[k] * u[k], wall_c[k] + half[k] * u[k]
        if fence[k]:
            starts = np.arange(0.0, length[k], 2.5)
            ends = np.minimum(starts + 2.0, length[k])
            p0.append(a + starts[:, None] * u[k])
            p1.append(a + ends[:, None] * u[k])
        else:
            p0.append(a[None])
            p1.append(e[None])
    return World(
        tree_xy=tree_xy,
        tree_r=tree_r,
        post_xy=post_xy,
        post_r=post_r,
        bush_vertices=verts.reshape(-1, 2),
        bush_offsets=np.arange(b.count + 1, dtype=np.int64) * b.vertices,
        wall_p0=np.vstack(p0) if p0 else np.zeros((0, 2)),
        wall_p1=np.vstack(p1) if p1 else np.zeros((0, 2)),
    )


# ---------------------------------------------------------------------------- sensors


def sensor_model(cfg: ParkConfig) -> SensorModel:
    las = cfg.laser
    fov = np.deg2rad(las.fov_deg)
    return SensorModel(
        kind="laser2d",
        n_beams=las.n_beams,
        angle_min=-fov / 2,
        angle_increment=fov / (las.n_beams - 1),
        range_min=0.0,
        range_max=las.range_max,
        range_sigma=las.range_sigma,
        mount=las.mount,
    )


def sensor_poses(vehicle_poses: np.ndarray, mount: Mount) -> np.ndarray:
    """(K, 3) sensor poses, world frame, from vehicle poses and the mounting pose."""
    return compose(vehicle_poses, np.array([mount.x, mount.y, mount.theta]), cos=_cos, sin=_sin)


def cast_world(world: World, pose: np.ndarray, sensor: SensorModel) -> tuple[np.ndarray, np.ndarray]:
    """Noise-free ranges (B,) (inf = nothing within range) and hit ids of one sensor pose."""
    c, r = world.circles()
    p0, p1 = world.segments()
    return cast(pose, sensor.angles(), c, r, p0, p1, float(sensor.range_max))


def _noisy_increments(rng: np.random.Generator, poses: np.ndarray, cfg: OdometryConfig) -> np.ndarray:
    inc = relative(poses[:-1], poses[1:], cos=_cos, sin=_sin)
    d = _hypot(inc[:, 0], inc[:, 1])
    n = rng.standard_normal((inc.shape[0], 3))
    out = inc.copy()
    out[:, 0] += cfg.alpha_trans * d * n[:, 0]
    out[:, 1] += cfg.lateral * d * n[:, 1]
    out[:, 2] += (cfg.alpha_rot * np.abs(inc[:, 2]) + cfg.alpha_rot_trans * d) * n[:, 2]
    return out


def simulate_park(cfg: ParkConfig, seed: int, progress=None) -> Simulation:
    """Run the simulator; the returned log holds scans, odometry, true poses and the trees.

    ``progress(iterable, total, label)`` may wrap the per-scan loop (a progress bar).
    """
    rng = np.random.default_rng(seed)
    dense = _figure8(cfg) if cfg.path.kind == "figure8" else _lawnmower(cfg)
    poses, t = _trajectory(cfg, dense, closed=cfg.path.kind == "figure8")
    world = make_world(cfg, rng, dense)
    sensor = sensor_model(cfg)

    inc = _noisy_increments(rng, poses, cfg.odometry)
    step = max(1, int(round(cfg.odometry.rate_hz / cfg.laser.rate_hz)))
    scan_idx = np.arange(0, poses.shape[0], step)
    spose = sensor_poses(poses[scan_idx], cfg.laser.mount)
    las = cfg.laser
    if scan_idx.size * las.n_beams > MAX_RETURNS:
        raise DataError(
            f"laser.rate_hz ({las.rate_hz}) and laser.n_beams ({las.n_beams}) over the run give {scan_idx.size:,} scans of "
            f"{las.n_beams:,} beams; at most {MAX_RETURNS:,} beams are simulated"
        )
    ranges = np.empty((scan_idx.size, las.n_beams), dtype=np.float32)
    scans = range(scan_idx.size) if progress is None else progress(range(scan_idx.size), scan_idx.size, "simulating scans")
    n_trees = world.tree_r.size
    for k in scans:  # one vectorised cast (beams x shapes) per scan
        truth, hit = cast_world(world, spose[k], sensor)
        noisy = truth + las.range_sigma * rng.standard_normal(las.n_beams)
        miss = rng.uniform(size=las.n_beams) < las.p_miss
        dust = rng.uniform(size=las.n_beams) < las.p_spurious
        dust_r = rng.uniform(las.spurious_min, np.minimum(truth, las.range_max))
        r = np.where(np.isfinite(truth) & ~miss, noisy, np.nan)
        r = np.where(dust & (dust_r > las.spurious_min), dust_r, r)
        r = np.where(r > las.range_max, np.nan, r)
        if las.landmark_dropout > 0 and n_trees:  # drawn only when asked for: the default run keeps its random stream
            lost = (rng.uniform(size=n_trees) < las.landmark_dropout) & (_hypot(*(world.tree_xy - spose[k, :2]).T) > las.dropout_beyond)
            on_tree = (hit >= 0) & (hit < n_trees)
            r = np.where(on_tree & lost[np.where(on_tree, hit, 0)], np.nan, r)
        ranges[k] = np.maximum(r, 0.0)

    stamp = seconds_to_stamp(t)
    log = SensorLog(
        name=f"park_seed{seed}",
        sensor=sensor,
        scans=ScanBatch(stamp[scan_idx], ranges),
        odometry=Odometry("increment", stamp[1:], inc),
        reference={"ground_truth": ReferencePoses("ground_truth", stamp, poses)},
        landmarks=Landmarks(np.arange(world.tree_r.size), world.tree_xy, world.tree_r),
        source={"reader": "simulator", "simulator": "park", "seed": seed},
    )
    return Simulation(cfg, seed, world, log)


def park_summary(sim: Simulation) -> dict:
    """What a park simulation holds: scans, beams, odometry, duration, path length, returns, the world's objects."""
    log = sim.log
    r = log.scans.ranges
    return {
        "seed": sim.seed,
        "scans": len(log.scans),
        "beams": log.scans.n_beams,
        "odometry_rows": len(log.odometry),
        "duration_s": float((log.scans.stamp[-1] - log.scans.stamp[0]) / 1e9),
        "path_length_m": float(np.sum(_hypot(*np.diff(log.reference["ground_truth"].poses[:, :2], axis=0).T))),
        "returning_beam_share": float(np.isfinite(r).mean()),
        "trees": int(sim.world.tree_r.size),
        "posts": int(sim.world.post_r.size),
        "bushes": int(sim.world.bush_offsets.size - 1),
        "wall_segments": int(sim.world.wall_p0.shape[0]),
    }


def _run(cfg: ParkConfig, seed: int, progress=None) -> Simulated:
    sim = simulate_park(cfg, seed, progress=progress)
    return Simulated(sim.log, park_summary(sim), {"world.yaml": dump_yaml(sim.world.to_dict())}, sim)


SIMULATORS.add("park", Simulator(ParkConfig, "park", "Simulate a 2D park (trees, bushes, walls, posts, dust) seen by a laser on a moving vehicle.", "simulated park", _run))
