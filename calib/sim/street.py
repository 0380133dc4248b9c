"""A 3D street simulator whose truth is exported: buildings, walls, boards, poles, cars, trees, bushes, a lidar.

The world (world frame, z up, the ground at z = 0): a route of straight
segments joined by constant-radius turns; along both sides of every straight,
building blocks (boxes: their four facades are planes) with gaps and random
setbacks, low walls across some gaps, free-standing boards, poles (thin
cylinders), parked cars (boxes: five planar faces), trees (a trunk cylinder and
a crown sphere) and bushes (a few spheres) -- the last three are non-planar
clutter -- and the ground (one large polygon).

The vehicle drives the route at constant speed: an Extended Constant Turn path
(Gostar et al. 2019, eq. 36) -- constant speed, yaw rate 0 on the straights and
v / R on the turns -- integrated exactly per odometry tick. Its odometry
reports speed and yaw rate (kind ``velocity``) with Gaussian noise. A spinning
lidar like a Velodyne HDL-64E (64 rings from +2 to -24.8 deg, 0.1728 deg
azimuth steps, 120 m, sigma_r = 2 cm, 2 % dropouts) mounted on the vehicle
sweeps at 10 Hz; every beam is cast against the world
(:mod:`detectors.raytrace3d`), so a frame has about 100k returns like a KITTI
frame. Sweeps are instantaneous (no motion distortion).

Exported truth: true poses at every odometry tick, every planar polygon as a
plane landmark with its outline (the log's ``planes`` stream), the whole world
(``world.yaml``) and the primitive each return came from. Same config and
seed, same bytes: every draw comes from one ``numpy.random.Generator`` in a
fixed order.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, model_validator

from calib.sim import SIMULATORS, Option, Simulated, Simulator
from detectors.geometry import compose
from detectors.sensor_log import Mount, Odometry, PlaneLandmarks, PointClouds, ReferencePoses, SensorLog, SensorModel, seconds_to_stamp, wrap_angle
from detectors.raytrace3d import BeamGrid, Scene, cast, hdl64_elevations
from profiles.errors import DataError
from profiles.parameters import check_order
from profiles.schema import LidarGeometry

#: odometry ticks a simulated run may hold at most (as calib.sim.park's)
MAX_TICKS = 10_000_000


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)


class Segment(_Strict):
    """One piece of the route: a straight of ``length`` [m], or a turn of ``angle_deg`` (left > 0) at ``radius`` [m]."""

    kind: Literal["straight", "turn"]
    length: float = Field(default=0.0, ge=0.0)
    angle_deg: float = Field(default=0.0, ge=-180.0, le=180.0)
    radius: float = Field(default=20.0, gt=0.0)

    @model_validator(mode="after")
    def _check(self) -> Segment:
        if self.kind == "straight" and self.length <= 0:
            raise ValueError("a straight needs a positive length")
        if self.kind == "turn" and self.angle_deg == 0:
            raise ValueError("a turn needs a non-zero angle_deg")
        return self


DEFAULT_ROUTE = [
    Segment(kind="straight", length=110.0),
    Segment(kind="turn", angle_deg=90.0, radius=20.0),
    Segment(kind="straight", length=100.0),
]


class Range(_Strict):
    min: float
    max: float

    @model_validator(mode="after")
    def _order(self) -> Range:
        check_order(self, "min", "max")
        return self

    def draw(self, rng: np.random.Generator, n: int | None = None):
        return rng.uniform(self.min, self.max, n)


class BuildingsConfig(_Strict):
    """Blocks along both sides of every straight; facades are at ``street_half_width + setback``."""

    length: Range = Range(min=10.0, max=30.0)
    gap: Range = Range(min=2.0, max=12.0)
    setback: Range = Range(min=0.0, max=3.0)
    setback_step: float = Field(default=0.5, ge=0.0, description="neighbouring facades differ in setback by at least this [m]")
    depth: Range = Range(min=8.0, max=15.0)
    height: Range = Range(min=6.0, max=20.0)
    wall_probability: float = Field(default=0.4, ge=0.0, le=1.0, description="chance that a gap is closed by a low wall")
    wall_height: Range = Range(min=1.0, max=2.5)


class StreetObjects(_Strict):
    """Street furniture per 100 m of straight and side."""

    cars: float = Field(default=4.0, ge=0.0)
    trees: float = Field(default=5.0, ge=0.0)
    poles: float = Field(default=3.0, ge=0.0)
    boards: float = Field(default=1.5, ge=0.0)
    bushes: float = Field(default=3.0, ge=0.0)


class LidarSimConfig(_Strict):
    """An HDL-64E-like spinning lidar."""

    vertical_angles_deg: list[float] | None = Field(
        default=None, min_length=1, description="ring elevations [deg]; default: HDL-64E-like, +2 to -24.8"
    )
    azimuth_increment_deg: float = Field(default=0.1728, gt=0.0, le=10.0)
    range_max: float = Field(default=120.0, gt=0.0)
    range_min: float = Field(default=0.9, ge=0.0)
    range_sigma: float = Field(default=0.02, ge=0.0)
    p_dropout: float = Field(default=0.02, ge=0.0, lt=1.0, description="chance that a beam that hits something returns nothing")
    rate_hz: float = Field(default=10.0, gt=0.0)
    height: float = Field(default=1.73, gt=0.0, description="sensor height above the ground [m] (KITTI's Velodyne)")
    mount: Mount = Mount(x=0.8, y=0.0, theta=0.0)

    @model_validator(mode="after")
    def _ranges(self) -> LidarSimConfig:
        check_order(self, "range_min", "range_max", strict=True)
        return self


class StreetOdometry(_Strict):
    """Speed and yaw-rate readings with Gaussian noise."""

    rate_hz: float = Field(default=20.0, gt=0.0)
    sigma_v: float = Field(default=0.15, ge=0.0, description="m/s")
    sigma_omega: float = Field(default=0.03, ge=0.0, description="rad/s")


class StreetConfig(_Strict):
    """The whole simulation; every field has a default that works."""

    route: list[Segment] = Field(default_factory=lambda: [s.model_copy() for s in DEFAULT_ROUTE], min_length=1)
    speed: float = Field(default=7.0, gt=0.0, description="m/s")
    street_half_width: float = Field(default=9.0, gt=3.0, description="route centre line to the building line [m]")
    extend: float = Field(default=40.0, ge=0.0, description="buildings continue this far beyond a straight's ends [m]")
    buildings: BuildingsConfig = BuildingsConfig()
    objects: StreetObjects = StreetObjects()
    lidar: LidarSimConfig = LidarSimConfig()
    odometry: StreetOdometry = StreetOdometry()
    frames: int | None = Field(default=None, ge=2, description="only the first N frames (default: the whole route)")


# ---------------------------------------------------------------------------- world


@dataclass
class World:
    """Every primitive of the street, world frame.

    polygons: list of (V, 3) outlines; poly_kind; cylinders (xy, r, z0, z1); spheres (centre, r)
    with their kinds.
    """

    polygons: list[np.ndarray] = field(default_factory=list)
    poly_kind: list[str] = field(default_factory=list)
    cyl: list[tuple[float, float, float, float, float]] = field(default_factory=list)
    cyl_kind: list[str] = field(default_factory=list)
    sph: list[tuple[float, float, float, float]] = field(default_factory=list)
    sph_kind: list[str] = field(default_factory=list)

    def scene(self) -> Scene:
        vmax = max(p.shape[0] for p in self.polygons)
        pv = np.zeros((len(self.polygons), vmax, 3))
        for i, p in enumerate(self.polygons):
            pv[i, : p.shape[0]] = p
        cyl = np.asarray(self.cyl, dtype=np.float64).reshape(-1, 5)
        sph = np.asarray(self.sph, dtype=np.float64).reshape(-1, 4)
        return Scene(pv, np.array([p.shape[0] for p in self.polygons]), cyl[:, :2], cyl[:, 2], cyl[:, 3:5], sph[:, :3], sph[:, 3])

    def kinds(self) -> list[str]:
        """Kind of every primitive id (polygons, cylinders, spheres)."""
        return self.poly_kind + self.cyl_kind + self.sph_kind

    def planes(self) -> PlaneLandmarks:
        sc = self.scene()
        off = np.concatenate([[0], np.cumsum([p.shape[0] for p in self.polygons])]).astype(np.int64)
        return PlaneLandmarks(
            np.arange(len(self.polygons), dtype=np.int64), sc.poly_normal, sc.poly_offset, np.vstack(self.polygons), off, np.array(self.poly_kind)
        )

    def to_dict(self) -> dict:
        return {
            "polygons": [{"kind": k, "vertices": np.round(p, 9).tolist()} for p, k in zip(self.polygons, self.poly_kind, strict=True)],
            "cylinders": [{"kind": k, "x": c[0], "y": c[1], "radius": c[2], "z0": c[3], "z1": c[4]} for c, k in zip(self.cyl, self.cyl_kind, strict=True)],
            "spheres": [{"kind": k, "x": s[0], "y": s[1], "z": s[2], "radius": s[3]} for s, k in zip(self.sph, self.sph_kind, strict=True)],
        }

    @classmethod
    def from_dict(cls, d: dict, where: str = "world") -> World:
        try:
            w = cls()
            for p in d["polygons"]:
                w.polygons.append(np.asarray(p["vertices"], dtype=np.float64).reshape(-1, 3))
                w.poly_kind.append(str(p["kind"]))
            for c in d["cylinders"]:
                w.cyl.append((float(c["x"]), float(c["y"]), float(c["radius"]), float(c["z0"]), float(c["z1"])))
                w.cyl_kind.append(str(c["kind"]))
            for s in d["spheres"]:
                w.sph.append((float(s["x"]), float(s["y"]), float(s["z"]), float(s["radius"])))
                w.sph_kind.append(str(s["kind"]))
            return w
        except (KeyError, TypeError, ValueError) as exc:
            raise DataError(f"{where}: malformed world description ({type(exc).__name__}: {exc})") from None


def _rect(centre_xy: np.ndarray, heading: float, length: float, width: float) -> np.ndarray:
    """(4, 2) corners of a rectangle (counter-clockwise)."""
    c, s = np.cos(heading), np.sin(heading)
    ax, lat = np.array([c, s]), np.array([-s, c])
    hl, hw = length / 2, width / 2
    return np.array([centre_xy - hl * ax - hw * lat, centre_xy + hl * ax - hw * lat, centre_xy + hl * ax + hw * lat, centre_xy - hl * ax + hw * lat])


def _box_faces(corners: np.ndarray, z0: float, z1: float, *, top: bool) -> list[np.ndarray]:
    """Vertical faces of a box over a footprint (4, 2), and optionally its top."""
    faces = []
    for i in range(4):
        a, b = corners[i], corners[(i + 1) % 4]
        faces.append(np.array([[a[0], a[1], z0], [b[0], b[1], z0], [b[0], b[1], z1], [a[0], a[1], z1]]))
    if top:
        faces.append(np.column_stack([corners, np.full(4, z1)]))
    return faces


@dataclass
class Route:
    """The designed route: straights (start (2,), heading, length) and a dense polyline of the centre line."""

    straights: list[tuple[np.ndarray, float, float]]
    polyline: np.ndarray  # (K, 2)
    length: float


def build_route(cfg: StreetConfig) -> Route:
    pos, hd = np.zeros(2), 0.0
    straights, pts = [], [pos.copy()]
    total = 0.0
    for seg in cfg.route:
        if seg.kind == "straight":
            straights.append((pos.copy(), hd, seg.length))
            s = np.linspace(0, seg.length, max(2, int(seg.length) + 1))[1:]
            pts.extend(pos + s[:, None] * np.array([np.cos(hd), np.sin(hd)]))
            pos = pos + seg.length * np.array([np.cos(hd), np.sin(hd)])
            total += seg.length
        else:
            ang = np.radians(seg.angle_deg)
            side = np.sign(ang)
            centre = pos + side * seg.radius * np.array([-np.sin(hd), np.cos(hd)])
            a = np.linspace(0, ang, max(3, int(abs(ang) * seg.radius) + 1))[1:]
            start = np.arctan2(pos[1] - centre[1], pos[0] - centre[0])
            pts.extend(centre + seg.radius * np.column_stack([np.cos(start + a), np.sin(start + a)]))
            pos = centre + seg.radius * np.array([np.cos(start + ang), np.sin(start + ang)])
            hd = hd + ang
            total += abs(ang) * seg.radius
    return Route(straights, np.asarray(pts), total)


def _clear_of_route(poly_xy: np.ndarray, route: Route, clearance: float) -> bool:
    """Whether no route point lies inside the polygon (4, 2) grown by ``clearance``."""
    c = poly_xy.mean(axis=0)
    q = route.polyline - c
    e0 = poly_xy[1] - poly_xy[0]
    e1 = poly_xy[3] - poly_xy[0]
    l0, l1 = np.linalg.norm(e0), np.linalg.norm(e1)
    a = np.abs(q @ (e0 / l0))
    b = np.abs(q @ (e1 / l1))
    return not bool(np.any((a <= l0 / 2 + clearance) & (b <= l1 / 2 + clearance)))


def _overlaps(poly_xy: np.ndarray, others: list[np.ndarray]) -> bool:
    """Separating-axis test of a rectangle against others."""
    for o in others:
        sep = False
        for r in (poly_xy, o):
            for i in range(2):
                e = r[(i + 1) % 4] - r[i]
                ax = np.array([-e[1], e[0]])
                pa, pb = poly_xy @ ax, o @ ax
                if pa.max() <= pb.min() + 1e-9 or pb.max() <= pa.min() + 1e-9:
                    sep = True
                    break
            if sep:
                break
        if not sep:
            return True
    return False


def build_world(cfg: StreetConfig, rng: np.random.Generator, route: Route) -> World:
    """The street's geometry (see the module docstring); draws from ``rng`` in a fixed order."""
    w = World()
    hw = cfg.street_half_width
    b = cfg.buildings
    footprints: list[np.ndarray] = []
    for p0, hd, length in route.straights:
        ax, lat = np.array([np.cos(hd), np.sin(hd)]), np.array([-np.sin(hd), np.cos(hd)])
        for side in (1.0, -1.0):
            a = -cfg.extend
            setback = float(b.setback.draw(rng))
            while a < length + cfg.extend:
                blen = float(b.length.draw(rng))
                depth, height = float(b.depth.draw(rng)), float(b.height.draw(rng))
                gap = float(b.gap.draw(rng))
                # neighbouring facades differ in setback (one plane per facade)
                step = float(rng.uniform(b.setback_step, max(b.setback_step, b.setback.max - b.setback.min)))
                cand = setback + step * (1.0 if rng.random() < 0.5 else -1.0)
                if cand < b.setback.min or cand > b.setback.max:
                    cand = setback - (cand - setback)
                setback = float(np.clip(cand, b.setback.min, b.setback.max))
                wall = rng.random() < b.wall_probability
                wall_h = float(b.wall_height.draw(rng))
                centre = p0 + (a + blen / 2) * ax + side * (hw + setback + depth / 2) * lat
                fp = _rect(centre, hd, blen, depth)
                if _clear_of_route(fp, route, hw - 0.5) and not _overlaps(fp, footprints):
                    footprints.append(fp)
                    for f in _box_faces(fp, 0.0, height, top=False):
                        w.polygons.append(f)
                        w.poly_kind.append("facade")
                    if wall and gap > 1.0:
                        s0 = p0 + (a + blen + 0.1) * ax + side * (hw + setback + 0.5) * lat
                        s1 = p0 + (a + blen + gap - 0.1) * ax + side * (hw + setback + 0.5) * lat
                        wall_fp = np.array([s0, s1, s1 + 0.01 * lat, s0 + 0.01 * lat])
                        if _clear_of_route(wall_fp, route, hw - 0.5):
                            w.polygons.append(np.array([[s0[0], s0[1], 0.0], [s1[0], s1[1], 0.0], [s1[0], s1[1], wall_h], [s0[0], s0[1], wall_h]]))
                            w.poly_kind.append("wall")
                a += blen + gap
    o = cfg.objects
    for p0, hd, length in route.straights:
        ax, lat = np.array([np.cos(hd), np.sin(hd)]), np.array([-np.sin(hd), np.cos(hd)])
        for side in (1.0, -1.0):
            span = length / 100.0

            def along(rate: float, spacing: float) -> np.ndarray:
                n = int(rng.poisson(rate * span))
                xs = np.sort(rng.uniform(0.0, length, n))
                keep = np.concatenate([[True], np.diff(xs) >= spacing]) if n else np.zeros(0, bool)
                return xs[keep]

            for x in along(o.cars, 5.5):
                # parked at their own distance from the curb and a little askew: no two share a plane
                c = p0 + x * ax + side * (hw - 4.5 + float(rng.uniform(-0.3, 0.3))) * lat
                fp = _rect(c, hd + float(np.radians(rng.uniform(-3.0, 3.0))), float(rng.uniform(4.2, 4.8)), float(rng.uniform(1.7, 1.9)))
                h = float(rng.uniform(1.4, 1.6))
                if _clear_of_route(fp, route, 2.5):
                    for f in _box_faces(fp, 0.3, h, top=True):
                        w.polygons.append(f)
                        w.poly_kind.append("car")
            for x in along(o.trees, 6.0):
                c = p0 + x * ax + side * (hw - 2.0) * lat
                r, h = float(rng.uniform(0.15, 0.3)), float(rng.uniform(2.5, 3.5))
                cr = float(rng.uniform(1.5, 2.5))
                if _clear_of_route(_rect(c, hd, 2 * cr, 2 * cr), route, 1.0):
                    w.cyl.append((float(c[0]), float(c[1]), r, 0.0, h + 0.5 * cr))
                    w.cyl_kind.append("trunk")
                    w.sph.append((float(c[0]), float(c[1]), h + cr * 0.8, cr))
                    w.sph_kind.append("crown")
            for x in along(o.poles, 8.0):
                c = p0 + x * ax + side * (hw - 3.0) * lat
                if _clear_of_route(_rect(c, hd, 0.4, 0.4), route, 1.0):
                    w.cyl.append((float(c[0]), float(c[1]), float(rng.uniform(0.08, 0.15)), 0.0, float(rng.uniform(4.0, 8.0))))
                    w.cyl_kind.append("pole")
            for x in along(o.boards, 10.0):
                c = p0 + x * ax + side * (hw - 1.2) * lat
                bw, bh, z0 = float(rng.uniform(2.0, 4.0)), float(rng.uniform(1.0, 2.5)), float(rng.uniform(0.5, 2.0))
                facing = rng.random() < 0.5  # parallel to the street or across it
                u = ax if facing else lat
                q0, q1 = c - bw / 2 * u, c + bw / 2 * u
                if _clear_of_route(_rect(c, hd, bw + 0.2, bw + 0.2), route, 1.0):
                    w.polygons.append(np.array([[q0[0], q0[1], z0], [q1[0], q1[1], z0], [q1[0], q1[1], z0 + bh], [q0[0], q0[1], z0 + bh]]))
                    w.poly_kind.append("board")
            for x in along(o.bushes, 3.0):
                c = p0 + x * ax + side * (hw - 0.8) * lat
                if _clear_of_route(_rect(c, hd, 2.0, 2.0), route, 1.0):
                    for _ in range(3):
                        r = float(rng.uniform(0.4, 0.9))
                        dx, dy = rng.uniform(-0.6, 0.6, 2)
                        w.sph.append((float(c[0] + dx), float(c[1] + dy), r * 0.6, r))
                        w.sph_kind.append("bush")
    lo = route.polyline.min(axis=0) - 200.0
    hi = route.polyline.max(axis=0) + 200.0
    w.polygons.append(np.array([[lo[0], lo[1], 0.0], [hi[0], lo[1], 0.0], [hi[0], hi[1], 0.0], [lo[0], hi[1], 0.0]]))
    w.poly_kind.append("ground")
    return w


# ---------------------------------------------------------------------------- motion


def true_motion(cfg: StreetConfig, route: Route) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Odometry ticks: times (K,) [s], true (v, omega) held over each tick (K, 2), true poses at the ticks (K, 3).

    The yaw rate over a tick is the route's at the tick's midpoint (0 on straights,
    v / R on turns); poses are integrated exactly (constant speed and turn rate per tick).
    """
    dt = 1.0 / cfg.odometry.rate_hz
    duration = route.length / cfg.speed
    ticks = np.floor(duration / dt) + 1
    if ticks > MAX_TICKS:
        raise DataError(
            f"speed ({cfg.speed} m/s) and odometry.rate_hz ({cfg.odometry.rate_hz}) give {ticks:.3g} odometry ticks over the "
            f"{route.length:.0f} m route; at most {MAX_TICKS:,} are simulated"
        )
    k = int(ticks)
    t = np.arange(k) * dt
    # yaw rate along the route by arc length
    bounds, rates = [0.0], []
    for seg in cfg.route:
        if seg.kind == "straight":
            bounds.append(bounds[-1] + seg.length)
            rates.append(0.0)
        else:
            ang = np.radians(seg.angle_deg)
            bounds.append(bounds[-1] + abs(ang) * seg.radius)
            rates.append(np.sign(ang) * cfg.speed / seg.radius)
    mid = (t + dt / 2) * cfg.speed
    seg_i = np.clip(np.searchsorted(np.asarray(bounds), mid, side="right") - 1, 0, len(rates) - 1)
    omega = np.asarray(rates)[seg_i]
    v = np.full(k, cfg.speed)
    poses = np.zeros((k, 3))
    for i in range(1, k):  # one step per tick; sequential by nature
        poses[i] = _arc(poses[i - 1], v[i - 1], omega[i - 1], dt)
    return t, np.column_stack([v, omega]), poses


def _arc(p: np.ndarray, v: float, w: float, dt: float) -> np.ndarray:
    th = p[2]
    if abs(w) < 1e-12:
        return np.array([p[0] + v * dt * np.cos(th), p[1] + v * dt * np.sin(th), th])
    return np.array([p[0] + v / w * (np.sin(th + w * dt) - np.sin(th)), p[1] - v / w * (np.cos(th + w * dt) - np.cos(th)), float(wrap_angle(th + w * dt))])


# ---------------------------------------------------------------------------- the sweep


def lidar_geometry(cfg: LidarSimConfig) -> LidarGeometry:
    ang = cfg.vertical_angles_deg if cfg.vertical_angles_deg is not None else np.degrees(hdl64_elevations()).round(6).tolist()
    return LidarGeometry(vertical_angles_deg=list(ang), azimuth_increment_deg=cfg.azimuth_increment_deg, height=cfg.height)


def sensor_model(cfg: StreetConfig) -> SensorModel:
    li = cfg.lidar
    return SensorModel(kind="lidar3d", range_min=li.range_min, range_max=li.range_max, range_sigma=li.range_sigma, mount=li.mount, lidar=lidar_geometry(li))


_REFLECTANCE = {"facade": 0.35, "wall": 0.3, "board": 0.6, "car": 0.5, "ground": 0.15, "trunk": 0.25, "pole": 0.4, "crown": 0.2, "bush": 0.2}


def sweep(
    scene: Scene, kinds: np.ndarray, grid: BeamGrid, sensor_pose: np.ndarray, li: LidarSimConfig, rng: np.random.Generator
) -> tuple[np.ndarray, np.ndarray]:
    """One frame: points (N, 4) float32 (x, y, z, reflectance; sensor frame, column by column) and the
    primitive id (N,) of each return. Draws dropouts, then range noise, then reflectance noise."""
    rng_img, ids = cast(scene, grid, sensor_pose, li.height, li.range_max)
    r, c = grid.rings, grid.columns
    hit = np.isfinite(rng_img) & (rng_img >= li.range_min)
    drop = rng.random((r, c)) < li.p_dropout
    noise = rng.standard_normal((r, c)) * li.range_sigma
    refl_noise = rng.standard_normal((r, c)) * 0.05
    keep = (hit & ~drop).T  # column-major: the order a spinning sensor fires
    dirs = np.swapaxes(grid.directions(), 0, 1)[keep]
    rr = (rng_img + noise).T[keep]
    pid = ids.T[keep]
    refl = np.clip(kinds[pid] + refl_noise.T[keep], 0.0, 1.0)
    pts = np.column_stack([dirs * rr[:, None], refl]).astype(np.float32)
    return pts, pid.astype(np.int32)


@dataclass(frozen=True, eq=False)
class StreetSimulation:
    config: StreetConfig
    seed: int
    world: World
    log: SensorLog
    labels: np.ndarray  # (P,) int32 primitive id of every return (aligned with log.clouds.points)
    frame_poses: np.ndarray  # (F, 3) true vehicle poses at the frames


def simulate_street(cfg: StreetConfig, seed: int, *, progress=None) -> StreetSimulation:
    """Simulate the street (see the module docstring)."""
    rng = np.random.default_rng(seed)
    route = build_route(cfg)
    if not route.straights:
        raise DataError("route: needs at least one straight for the buildings")
    world = build_world(cfg, rng, route)
    scene = world.scene()
    t, vel, poses = true_motion(cfg, route)
    od = cfg.odometry
    noisy = vel + rng.standard_normal(vel.shape) * np.array([od.sigma_v, od.sigma_omega])
    li = cfg.lidar
    period = 1.0 / li.rate_hz
    n_frames = int(np.floor(t[-1] / period)) + 1
    if cfg.frames is not None:
        n_frames = min(n_frames, cfg.frames)
    if n_frames < 2:
        raise DataError("the route is too short for two lidar frames")
    ft = np.arange(n_frames) * period
    # true pose at each frame time: integrate from the last tick at or before it
    k = np.searchsorted(t, ft + 1e-9, side="right") - 1
    fposes = np.array([_arc(poses[i], vel[i, 0], vel[i, 1], float(ft[j] - t[i])) for j, i in enumerate(k)])
    mount = np.array([li.mount.x, li.mount.y, li.mount.theta])
    spose = compose(fposes, mount)
    grid = BeamGrid(np.radians(np.asarray(lidar_geometry(li).vertical_angles_deg)), float(np.radians(li.azimuth_increment_deg)))
    kinds = np.array([_REFLECTANCE.get(kd, 0.3) for kd in world.kinds()])
    clouds, labels = [], []
    it = range(n_frames) if progress is None else progress(range(n_frames), n_frames, "simulating street")
    for j in it:
        pts, pid = sweep(scene, kinds, grid, spose[j], li, rng)
        clouds.append(pts)
        labels.append(pid)
    offsets = np.concatenate([[0], np.cumsum([c.shape[0] for c in clouds])]).astype(np.int64)
    stop = int(np.searchsorted(t, ft[-1] + 1e-9, side="right"))
    log = SensorLog(
        name=f"street_seed{seed}",
        sensor=sensor_model(cfg),
        odometry=Odometry("velocity", seconds_to_stamp(t[:stop]), noisy[:stop]),
        reference={"ground_truth": ReferencePoses("ground_truth", seconds_to_stamp(t[:stop]), poses[:stop])},
        clouds=PointClouds(seconds_to_stamp(ft), offsets, np.concatenate(clouds)),
        planes=world.planes(),
        source={"reader": "simulator", "simulator": "street", "seed": seed},
    )
    return StreetSimulation(cfg, seed, world, log, np.concatenate(labels), fposes)


# ---------------------------------------------------------------------------- the run folder


def street_summary(sim: StreetSimulation) -> dict:
    log = sim.log
    pts = np.diff(log.clouds.offsets)
    gt = log.reference["ground_truth"].poses
    kinds, counts = np.unique(log.planes.kind, return_counts=True)
    return {
        "seed": sim.seed,
        "frames": len(log.clouds),
        "points_per_frame_mean": float(pts.mean()),
        "points_per_frame_min": int(pts.min()),
        "points_per_frame_max": int(pts.max()),
        "odometry_rows": len(log.odometry),
        "duration_s": float((log.clouds.stamp[-1] - log.clouds.stamp[0]) / 1e9),
        "path_length_m": float(np.sum(np.hypot(*np.diff(gt[:, :2], axis=0).T))),
        "planes": {str(k): int(c) for k, c in zip(kinds, counts, strict=True)},
        "cylinders": len(sim.world.cyl),
        "spheres": len(sim.world.sph),
    }


def _run(cfg: StreetConfig, seed: int, progress=None) -> Simulated:
    import io

    from calib.config import dump_yaml

    sim = simulate_street(cfg, seed, progress=progress)
    buf = io.BytesIO()
    np.lib.format.write_array(buf, sim.labels, allow_pickle=False)
    files = {"world.yaml": dump_yaml(sim.world.to_dict()), "labels.npy": buf.getvalue()}
    return Simulated(sim.log, street_summary(sim), files, sim)


SIMULATORS.add("street", Simulator(
    StreetConfig, "street",
    "Simulate a 3D street (buildings, walls, boards, poles, cars, trees, bushes) swept by an HDL-64E-like lidar on a vehicle "
    "on an Extended Constant Turn path; writes the log with plane truth and the world.",
    "simulated street", _run, Option("frames", int, "Only the first N lidar frames (default: the whole route, about 340)."),
))  # fmt: skip
