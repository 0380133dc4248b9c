"""``two-stage``: the scenario of Li & Yang, *A Two-Stage Feature Point Detection and Marking Approach Based on
the LMB Filter* (Sensors 2022), sec. 3-4.

A sensor plans its path in two stages and detects ten feature points on the way:

* stage 1, the initial path (sec. 3.1, Fig. 4) over the square scene from (-800, -800) m to (800, 800) m (sec. 4):
  a *serpentine* of ``lanes`` straight lanes along x joined by half circles, or a *spiral*: straight sides
  inward, ``lanes`` apart, joined by quarter circles. Straight parts are the paper's constant-velocity (CV)
  motion, arcs its constant-turn (CT) motion (sec. 3.2); the lanes lie ``lanes`` apart so that the detection
  discs of neighbouring lanes cover the scene (sec. 4: "its detection range covers almost the entire given area");
* stage 2, local obstacle avoidance (sec. 3.4): a feature point the initial path passes within the safety distance
  ``safety_distance`` (sigma_min) of is an obstacle. Where the path first comes within sigma_min of it (the
  event trigger, eqs. 28-29: ||p(x_k) - p(m)|| <= sigma_min, K the first such k) the sensor leaves the path and
  goes round the obstacle on the circle of radius sigma_min about it, on the side the path passes, back to the
  path where it leaves that circle (the preview point y_k, eq. 30), where the sensor returns to driving mode;
* the joints of straight path and avoidance arc turn by up to 90 deg at once, which a moving sensor cannot do;
  the path is smoothed by a B-spline (sec. 3.4: C(u) = sum_i N_i,k(u) X(i), the Cox-de Boor basis of order k):
  the control polygon X(i) is the planned path resampled every ``spline_spacing`` metres, the curve a clamped
  cubic B-spline of it (``scipy.interpolate.BSpline``), which lies in the convex hull of every four consecutive
  control points and starts and ends at the polygon's ends;
* the sensor moves along the smoothed path in ``steps`` = 100 steps of ``dt`` = T = 1 s (sec. 4), at half speed
  on the arcs (Table 1: 2 m/s straight, 1 m/s on arcs). Table 1's speeds cover 200 m in 100 s, not the
  1,600 m scene of sec. 4 the paper's figures show covered, so by default (``speed: null``) the speed is the one
  that takes the whole path in the 100 steps, with Table 1's ratio of arc to straight speed kept; a ``speed``
  [m/s] given drives the straight parts at it and the run ends after ``steps`` wherever the sensor is;
* ``features`` = 10 feature points (sec. 4): ``on_path`` of them on the initial path (the paper's obstacles,
  "feature points that appear on the initial path"), the rest uniform over the scene. Static, or (``moving``)
  in uniform linear motion with process noise Q = 0.5^2 B B^T (sec. 4; the constant-velocity model, state
  (x, y, vx, vy)), each starting at speed ``feature_speed`` in a random direction; the path is planned
  around their initial positions;
* detection (sec. 4): every feature within the detection radius ``detection_radius`` (Table 1: 50, 100 or 150 m;
  150 m with ten features in Figs. 6a and 7a) is detected with P_D = 0.98; clutter is Poisson with "intensity 20"
  over "the clutter area S = [-1000, 1000] x [-1000, 1000]" (sec. 4): 20 false alarms per scan uniform over S,
  of which the sensor reports the ones inside its detection disc (``clutter_area: square``, the default: about
  0.35 per scan in a 150 m disc; a sensor that reports to 150 m reports nothing at 1 km), or 20 per scan uniform
  over the detection disc (``clutter_area: disc``: a 57 times denser clutter, in which a feature seen 1-4 times
  per run, as here, is hard to tell from it).

The paper does not state its measurement noise; its parameters (T, F, B, H, P_D, the clutter region) are those of
the public labelled-RFS toolbox of B.-N. Vo and B.-T. Vo, whose range-bearing model takes sigma_r = 10 m and
sigma_b = 2 deg, the defaults here. Detections are logged as range and bearing in the sensor frame (the sensor
heads along the path); odometry as pose increments with noise ``odometry_sigma`` per step (the paper's sensor
also observes its own position, y = O x + w, sec. 3.2, so its runs know the path to within that noise). The paper
gives no feature layout (Fig. 3 is drawn, not listed); the seed draws it. Same config and seed, same bytes.
"""

from __future__ import annotations

from dataclasses import dataclass
import numpy as np
from scipy.interpolate import BSpline

from calib.sim import SIMULATORS, Option, Simulated, Simulator, truth_provenance
from detectors.sensor_log import Detections, Landmarks, Odometry, ReferencePoses, SensorLog, SensorModel, wrap_angle
from profiles.parameters import TwoStageConfig

#: spacing of the densely sampled paths [m]
DENSE = 1.0
#: the B-spline's degree (order k = 4 in the paper's eq.: cubic)
DEGREE = 3


@dataclass
class TwoStageRun:
    """One simulated run: the log (detections, odometry, true poses, the features' positions at the last step as
    landmarks) and what the log cannot hold.

    features (T, F, 4): each feature's true state (x, y, vx, vy) at each step, world frame; initial (N, 2) the
    stage-1 path and planned (N', 2) the path after obstacle avoidance, densely sampled; control (C, 2) the
    B-spline's control polygon; path (N'', 2) the smoothed path; obstacles (F,) bool: the features avoided."""

    log: SensorLog
    features: np.ndarray
    initial: np.ndarray
    planned: np.ndarray
    control: np.ndarray
    path: np.ndarray
    obstacles: np.ndarray


# ---------------------------------------------------------------------- stage 1: the initial path
def _line(a, b) -> np.ndarray:
    n = max(int(np.ceil(np.hypot(*(np.subtract(b, a))) / DENSE)), 1)
    return np.asarray(a) + np.linspace(0.0, 1.0, n + 1)[:, None] * (np.asarray(b) - np.asarray(a))


def _arc(c, r, a0, a1) -> np.ndarray:
    n = max(int(np.ceil(abs(a1 - a0) * r / DENSE)), 2)
    t = np.linspace(a0, a1, n + 1)
    return np.column_stack([c[0] + r * np.cos(t), c[1] + r * np.sin(t)])


def _join(parts: list[tuple[np.ndarray, bool]]) -> tuple[np.ndarray, np.ndarray]:
    """The parts (points (n, 2), is an arc) as one polyline (N, 2) and whether each point lies on an arc (N,)."""
    pts, arc = [parts[0][0]], [np.full(len(parts[0][0]), parts[0][1])]
    for p, a in parts[1:]:
        pts.append(p[1:])
        arc.append(np.full(len(p) - 1, a))
    return np.concatenate(pts), np.concatenate(arc)


def initial_path(cfg: TwoStageConfig) -> tuple[np.ndarray, np.ndarray]:
    """The stage-1 path (N, 2) sampled every ~1 m and whether each point lies on an arc (N,) (sec. 3.1, Fig. 4)."""
    (x0, y0), (x1, y1) = cfg.start, cfg.end
    parts: list[tuple[np.ndarray, bool]] = []
    if cfg.path == "serpentine":
        # lanes along x from y0 to y1, joined by half circles outside the scene's x range
        s = (y1 - y0) / (cfg.lanes - 1)
        for i in range(cfg.lanes):
            y = y0 + i * s
            a, b = ((x0, y), (x1, y)) if i % 2 == 0 else ((x1, y), (x0, y))
            parts.append((_line(a, b), False))
            if i < cfg.lanes - 1:
                c = (b[0], y + s / 2)
                parts.append((_arc(c, s / 2, -np.pi / 2, np.pi / 2) if i % 2 == 0 else _arc(c, s / 2, 3 * np.pi / 2, np.pi / 2), True))
        return _join(parts)
    # spiral: straight sides inward, rings s apart, corners rounded by quarter circles of radius s / 2
    s = min(x1 - x0, y1 - y0) / cfg.lanes
    rr = s / 2
    lo = np.array([x0, y0], dtype=float)
    hi = np.array([x1, y1], dtype=float)
    heading = 0  # 0 +x, 1 +y, 2 -x, 3 -y
    pos = lo.copy()
    dirs = np.array([[1, 0], [0, 1], [-1, 0], [0, -1]], dtype=float)
    bounds = [hi[0], hi[1], lo[0], lo[1] + s]  # where each heading's side ends (the first ring's -y side stops short)
    while True:
        d = dirs[heading]
        stop = bounds[heading]
        length = (stop - pos[0]) * d[0] + (stop - pos[1]) * d[1] - rr
        if length <= rr:
            break
        end = pos + d * length
        parts.append((_line(pos, end), False))
        # the quarter turn left: centre r to the left of the end
        left = dirs[(heading + 1) % 4]
        c = end + left * rr
        a0 = np.arctan2(-left[1], -left[0])
        parts.append((_arc(c, rr, a0, a0 + np.pi / 2), True))
        pos = c + d * rr
        # the next ring's side for this heading ends s further in
        bounds[heading] -= s * (d[0] + d[1])
        heading = (heading + 1) % 4
    return _join(parts)


# ---------------------------------------------------------------------- stage 2: obstacle avoidance and smoothing
def avoid(path: np.ndarray, arc: np.ndarray, obstacles: np.ndarray, radius: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The path (N, 2) with a detour round every obstacle (K, 2) it passes within ``radius`` of (sec. 3.4): from the
    first point within ``radius`` (the trigger, eqs. 28-29) along the circle of that radius about the obstacle, on
    the side the path passes (left of the path when it runs through the obstacle), to where the path leaves the
    circle (the preview point, eq. 30). Obstacles are taken in the order the path reaches them. Returns the new path,
    its arc flags (the detours are arcs) and which obstacles were avoided (K,) bool."""
    avoided = np.zeros(len(obstacles), dtype=bool)
    first = [int(np.argmax(np.hypot(*(path - o).T) < radius)) if np.any(np.hypot(*(path - o).T) < radius) else -1 for o in obstacles]
    for k in np.argsort([f if f >= 0 else np.iinfo(np.int64).max for f in first], kind="stable"):
        o = obstacles[k]
        inside = np.hypot(*(path - o).T) < radius
        if not inside.any():
            continue
        i0 = int(np.argmax(inside))
        i1 = i0 + int(np.argmin(inside[i0:])) - 1 if not inside[i0:].all() else len(path) - 1
        if i0 == 0 or i1 == len(path) - 1:
            continue  # the path starts or ends inside: nothing to go round
        avoided[k] = True
        a0 = np.arctan2(*(path[i0 - 1] - o)[::-1])
        a1 = np.arctan2(*(path[i1 + 1] - o)[::-1])
        # the side the path passes: its closest point; on the obstacle itself, the path's left
        j = i0 + int(np.argmin(np.hypot(*(path[i0 : i1 + 1] - o).T)))
        off = path[j] - o
        if np.hypot(*off) < 1e-9:
            t = path[min(j + 1, len(path) - 1)] - path[max(j - 1, 0)]
            off = np.array([-t[1], t[0]])
        am = np.arctan2(off[1], off[0])
        ccw = (a1 - a0) % (2 * np.pi)
        through = (am - a0) % (2 * np.pi) <= ccw  # going counter-clockwise from a0 to a1 passes am
        sweep = ccw if through else ccw - 2 * np.pi
        det = _arc(o, radius, a0, a0 + sweep)[1:-1]
        path = np.concatenate([path[:i0], det, path[i1 + 1 :]])
        arc = np.concatenate([arc[:i0], np.ones(len(det), dtype=bool), arc[i1 + 1 :]])
    return path, arc, avoided


def _resample(path: np.ndarray, flags: np.ndarray, spacing: float) -> tuple[np.ndarray, np.ndarray]:
    """Points every ``spacing`` metres along the polyline (the ends kept), with the flag of the nearest vertex."""
    s = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(path, axis=0).T))])
    n = max(int(np.ceil(s[-1] / spacing)), DEGREE)
    at = np.linspace(0.0, s[-1], n + 1)
    pts = np.column_stack([np.interp(at, s, path[:, 0]), np.interp(at, s, path[:, 1])])
    return pts, flags[np.clip(np.searchsorted(s, at), 0, len(s) - 1)]


def bspline(control: np.ndarray) -> BSpline:
    """The clamped cubic B-spline C(u) = sum_i N_i,k(u) X(i), u in [0, 1], of the control polygon X (C, 2), C >= 4:
    uniform interior knots, the end knots repeated k + 1 times so that C(0) = X(0) and C(1) = X(C - 1)."""
    c = len(control)
    inner = np.linspace(0.0, 1.0, c - DEGREE + 1)
    knots = np.concatenate([np.zeros(DEGREE), inner, np.ones(DEGREE)])
    return BSpline(knots, np.asarray(control, dtype=np.float64), DEGREE)


# ---------------------------------------------------------------------- the run
def _features(cfg: TwoStageConfig, initial: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """(F, 2) initial feature positions: on_path on the initial path (away from its ends), the rest uniform."""
    s = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(initial, axis=0).T))])
    margin = min(2 * cfg.safety_distance + cfg.detection_radius, 0.25 * s[-1])
    at = rng.uniform(margin, s[-1] - margin, cfg.on_path)
    on = np.column_stack([np.interp(at, s, initial[:, 0]), np.interp(at, s, initial[:, 1])])
    lo, hi = np.asarray(cfg.start), np.asarray(cfg.end)
    off = rng.uniform(lo, hi, (cfg.features - cfg.on_path, 2))
    return np.vstack([on, off])


def _motion(cfg: TwoStageConfig, x0: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """(T, F, 4) the features' states at every step: static, or constant velocity driven by the acceleration noise
    of Q = sigma^2 B B^T (m_k+1 = F m_k + B v_k, v_k ~ N(0, sigma^2 I))."""
    t, f = cfg.steps, len(x0)
    out = np.zeros((t, f, 4))
    out[0, :, :2] = x0
    if not cfg.moving:
        out[:, :, :2] = x0
        return out
    ang = rng.uniform(-np.pi, np.pi, f)
    out[0, :, 2:] = cfg.feature_speed * np.column_stack([np.cos(ang), np.sin(ang)])
    acc = rng.standard_normal((t - 1, f, 2)) * cfg.process_noise
    dt = cfg.dt
    for k in range(1, t):  # a loop over time steps (100): each vectorised over the features
        out[k, :, :2] = out[k - 1, :, :2] + dt * out[k - 1, :, 2:] + 0.5 * dt * dt * acc[k - 1]
        out[k, :, 2:] = out[k - 1, :, 2:] + dt * acc[k - 1]
    return out


def _timing(cfg: TwoStageConfig, curve: np.ndarray, on_arc: np.ndarray) -> np.ndarray:
    """(T, 3) poses at the steps along the smoothed path (M, 2) whose points lie on arcs where on_arc (M,): half
    speed there (Table 1's ratio); the speed fitted to the steps unless given; heading along the path."""
    seg = np.hypot(*np.diff(curve, axis=0).T)
    rate = np.where(on_arc[1:] | on_arc[:-1], cfg.arc_speed_ratio, 1.0)  # relative speed on each segment
    tau = np.concatenate([[0.0], np.cumsum(seg / rate)])  # time at unit straight speed
    v = tau[-1] / ((cfg.steps - 1) * cfg.dt) if cfg.speed is None else cfg.speed
    t = np.minimum(np.arange(cfg.steps) * cfg.dt * v, tau[-1])
    xy = np.column_stack([np.interp(t, tau, curve[:, 0]), np.interp(t, tau, curve[:, 1])])
    i = np.clip(np.searchsorted(tau, t, side="right") - 1, 0, len(curve) - 2)
    d = curve[i + 1] - curve[i]
    return np.column_stack([xy, np.arctan2(d[:, 1], d[:, 0])])


def sensor_model(cfg: TwoStageConfig) -> SensorModel:
    """The sensor as the filter sees it: full circle, reports out to 4 range sigmas past the detection radius."""
    return SensorModel(kind="detector", range_min=0.0, range_max=reach(cfg), fov=2 * np.pi, range_sigma=cfg.sigma_range)


def reach(cfg: TwoStageConfig) -> float:
    """The largest range a detection reports: the detection radius plus 4 sigma of range noise [m]."""
    return float(cfg.detection_radius + 4.0 * cfg.sigma_range)


def simulate_two_stage(cfg: TwoStageConfig, seed: int) -> TwoStageRun:
    """One run of the scenario (module docstring). The layout, the features' motion, the odometry noise, the
    detections and the clutter are drawn from separate streams of the seed."""
    rng_lay, rng_mov, rng_odo, rng_det, rng_clut = (np.random.default_rng(s) for s in np.random.SeedSequence(seed).spawn(5))
    initial, arc0 = initial_path(cfg)
    x0 = _features(cfg, initial, rng_lay)
    planned, arc1, avoided = avoid(initial, arc0, x0, cfg.safety_distance)
    control, c_arc = _resample(planned, arc1, cfg.spline_spacing)
    spl = bspline(control)
    u = np.linspace(0.0, 1.0, int(np.ceil(np.sum(np.hypot(*np.diff(planned, axis=0).T)) / DENSE)) + 1)
    curve = spl(u)
    # a smoothed point is on an arc where the control points that shape it (the k + 1 nearest in u) include one
    span = np.clip(np.searchsorted(spl.t, u, side="right") - 1, DEGREE, len(control) - 1)
    on_arc = np.zeros(u.size, dtype=bool)
    for q in range(DEGREE + 1):  # the k + 1 control points of each span (four: a loop over the degree, not the points)
        on_arc |= c_arc[span - DEGREE + q]
    poses = _timing(cfg, curve, on_arc)
    truth = _motion(cfg, x0, rng_mov)
    t, f = cfg.steps, cfg.features
    stamps = np.arange(t, dtype=np.int64) * int(round(cfg.dt * 1e9))
    # odometry: the true increment between consecutive poses, in the previous pose's frame, plus noise
    d = poses[1:, :2] - poses[:-1, :2]
    c, s = np.cos(poses[:-1, 2]), np.sin(poses[:-1, 2])
    inc = np.column_stack([c * d[:, 0] + s * d[:, 1], -s * d[:, 0] + c * d[:, 1], wrap_angle(np.diff(poses[:, 2]))])
    inc = inc + rng_odo.standard_normal(inc.shape) * [cfg.odometry_sigma, cfg.odometry_sigma, cfg.odometry_heading_sigma]
    odo = np.vstack([np.zeros((1, 3)), inc])
    # detections: every feature in the detection disc with P_D, noisy range and bearing in the sensor frame
    rel = truth[:, :, :2] - poses[:, None, :2]
    r_true = np.hypot(rel[..., 0], rel[..., 1])
    b_true = wrap_angle(np.arctan2(rel[..., 1], rel[..., 0]) - poses[:, None, 2])
    seen = (r_true <= cfg.detection_radius) & (rng_det.uniform(size=r_true.shape) < cfg.pd)
    zr = r_true + rng_det.standard_normal(r_true.shape) * cfg.sigma_range
    zb = wrap_angle(b_true + rng_det.standard_normal(r_true.shape) * cfg.sigma_bearing)
    keep = seen & (zr > 0.0)
    ck, cr, cb = _clutter(cfg, poses, rng_clut)
    kk, ll = np.nonzero(keep)
    frame = np.concatenate([kk, ck])
    order = np.argsort(frame, kind="stable")
    det = Detections(
        stamps, frame[order].astype(np.int64), np.concatenate([zr[keep], cr])[order], np.concatenate([zb[keep], cb])[order],
        {"landmark": np.concatenate([ll + 1, np.zeros(ck.size, np.int64)])[order].astype(np.int64)},
    )
    log = SensorLog(
        name=f"two_stage_{cfg.path}_{'moving' if cfg.moving else 'static'}_{seed}",
        sensor=sensor_model(cfg),
        odometry=Odometry("increment", stamps, odo),
        reference={"ground_truth": ReferencePoses("ground_truth", stamps, poses)},
        # the features where they are at the last step: the map a run ends with (static: where they always are)
        landmarks=Landmarks(np.arange(1, f + 1, dtype=np.int64), truth[-1, :, :2]),
        detections=det,
        source={"reader": "simulate two-stage", "seed": int(seed), "config": cfg.model_dump(mode="json")},
    )
    return TwoStageRun(log, truth, initial, planned, control, curve, avoided)


def _clutter(cfg: TwoStageConfig, poses: np.ndarray, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """False alarms: (frame (C,), range (C,), bearing (C,)) in the sensor frame of each step's pose."""
    t = poses.shape[0]
    rad = cfg.detection_radius
    if cfg.clutter_area == "disc":
        n = rng.poisson(cfg.clutter, t)
        k = np.repeat(np.arange(t), n)
        return k, rad * np.sqrt(rng.uniform(size=k.size)), rng.uniform(-np.pi, np.pi, k.size)
    w = cfg.clutter_half_width
    n = rng.poisson(cfg.clutter, t)
    k = np.repeat(np.arange(t), n)
    xy = rng.uniform(-w, w, (k.size, 2)) - poses[k, :2]
    r = np.hypot(xy[:, 0], xy[:, 1])
    b = wrap_angle(np.arctan2(xy[:, 1], xy[:, 0]) - poses[k, 2])
    inside = r <= rad
    return k[inside], r[inside], b[inside]


def truth_profile(cfg: TwoStageConfig, *, name: str | None = None, version: str = "1.0.0"):
    """The profile of the simulated detector's true statistics: P_D out to the detection radius (0 beyond, over a
    field of view that reaches as far as a noisy report can), clutter uniform per unit area (``space: xy``) at the
    scenario's density, the noise."""
    from profiles.profile import DetectorProfile, DetectorSpec
    from profiles.schema import ClutterParams, MeasurementNoise, PdTable

    far = reach(cfg)
    rad = cfg.detection_radius
    # the density of false alarms per m^2 inside the detection disc, over the disc the field of view spans
    dens = cfg.clutter / (np.pi * rad**2) if cfg.clutter_area == "disc" else cfg.clutter / (2 * cfg.clutter_half_width) ** 2
    area = np.pi * far**2
    return DetectorProfile(
        name=name or f"two-stage-{cfg.path}",
        version=version,
        description="The two-stage scenario's true detection statistics (the simulator's settings, not a calibration).",
        detector=DetectorSpec(kind="external"),
        sensor=sensor_model(cfg),
        pd=PdTable(covariate="range", edges=[0.0, rad, far], pd=[cfg.pd, 0.0], clamping="none (simulator truth)"),
        clutter=ClutterParams(rate=max(dens * area, 1e-12), space="xy", volume=area),
        noise=MeasurementNoise(range_sigma=cfg.sigma_range, bearing_sigma=cfg.sigma_bearing),
        provenance=truth_provenance(cfg, "detcal simulate two-stage"),
    )


def summary(run: TwoStageRun, cfg: TwoStageConfig) -> dict:
    d = run.log.detections
    lab = np.asarray(d.descriptors["landmark"])
    poses = run.log.reference["ground_truth"].poses
    return {
        "steps": int(cfg.steps),
        "path": cfg.path,
        "moving": bool(cfg.moving),
        "path_length_m": float(np.sum(np.hypot(*np.diff(run.path, axis=0).T))),
        "travelled_m": float(np.sum(np.hypot(*np.diff(poses[:, :2], axis=0).T))),
        "features": int(cfg.features),
        "obstacles_avoided": int(run.obstacles.sum()),
        "features_seen": int(np.unique(lab[lab > 0]).size),
        "detections": int(len(d)),
        "false_alarms": int((lab == 0).sum()),
        "false_alarms_per_scan": float((lab == 0).sum() / max(cfg.steps, 1)),
    }


def features_csv(run: TwoStageRun) -> str:
    """Every feature's true state at every step as CSV text: step, id, x, y, vx, vy [m, m/s], world frame."""
    t, f = run.features.shape[:2]
    rows = np.column_stack([np.repeat(np.arange(t), f), np.tile(np.arange(1, f + 1), t), run.features.reshape(-1, 4)])
    lines = ["step,id,x,y,vx,vy"] + [f"{int(r[0])},{int(r[1])},{r[2]:.6f},{r[3]:.6f},{r[4]:.6f},{r[5]:.6f}" for r in rows]
    return "\n".join(lines) + "\n"


def _run(cfg: TwoStageConfig, seed: int, progress=None) -> Simulated:
    """The run folder's contents: log.dlog (the features' last positions as landmarks), features.csv (every feature's
    state at every step) and profile.yaml (the simulator's true statistics)."""
    from profiles.store import dump_profile

    run = simulate_two_stage(cfg, seed)
    return Simulated(run.log, {"seed": seed, **summary(run, cfg)}, {"features.csv": features_csv(run), "profile.yaml": dump_profile(truth_profile(cfg))}, run)


SIMULATORS.add("two-stage", Simulator(
    TwoStageConfig, "two_stage",
    "The two-stage scenario of Li & Yang (Sensors 2022): a sensor on a planned path (serpentine or spiral, obstacle avoidance "
    "smoothed by a B-spline), ten feature points, static or moving, P_D 0.98, clutter; writes the log, every feature's state "
    "(features.csv) and the profile of its true statistics.",
    "two-stage scenario", _run, (
        Option("path", str, "Initial path: serpentine or spiral (Fig. 4a / 4b; default: the config's, serpentine)."),
        Option("moving", bool, "Feature points in constant-velocity motion (--moving) or static (--static; default: the config's, static).", "--moving/--static"),
    ),
))  # fmt: skip
