"""Calibration and validation of the plane detector on 3D lidar logs with truth (profile kind ``lidar3d-planes``).

The thesis's recipe (Inostroza 2015, ch. 4-6) carried to planes:

1. **poses**: the sensor pose of every cloud from the log's ground truth (and the mount);
2. **labelling** per frame: the plane detector (:mod:`detectors.plane`) on the
   cloud; every true plane (the log's ``planes`` stream) put in the sensor frame;
   a detection is a true plane's when its normal and offset are within the gate
   (``gate_angle_deg``, ``gate_offset``) and at least half of its inliers lie
   on that plane's surface (within the slab and inside its outline grown by
   ``surface_margin``) -- without the surface test a board in front of a facade
   would count as the facade -- one detection per plane, by an optimal
   assignment on the share;
3. **n_p in 3D**: for every true plane, the beams that would hit its polygon
   and are not occluded in the measured range image
   (:func:`detectors.raytrace3d.visible_planes`; a shorter return occludes, a
   missing one does not) -- the expected number of returns on its visible part
   -- and the incidence angle of their centroid's line of sight;
4. **fits**: P_D over expected points (bins that widen with the count) with 95 %
   Wilson intervals and the thesis's clamping (eq. 6.2, ch. 6), and over
   (points x incidence angle) where cells are populated; clutter: detections of
   landmark planes (steep enough, enough inliers, in range) that are no true
   plane's, per frame, as a Poisson rate with Pearson's chi-square test (sec.
   4.2), spread over the chart of landmark planes; the chart noise of true
   detections (robust sigmas); and the ratio of the runtime's slab counts to
   the ray-traced counts (the runtime's stand-in for n_p).

``validate_planes`` scores a profile on a held-out log with the same labelling:
the reliability (ECE) of its P_D predictions and observed against predicted
false alarms per frame.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import pandas as pd
from pydantic import BaseModel, ConfigDict, Field
from scipy.optimize import linear_sum_assignment

from calib import __version__
from profiles.version import build_stamp
from calib.calibrate import created_now
from calib.fits import ClutterFit, PdFitConfig, clutter_params, fit_clutter, wilson
from detectors.geometry import compose, interpolate_poses
from detectors.geometry3d import chart_from_normal, normal_angle, orient_away, plane_basis, wrap
from detectors.sensor_log import SensorLog
from detectors.plane import PlaneDetections, detect_planes, landmark_detections
from detectors.plane_model import PlaneDetectionModel
from detectors.raytrace3d import BeamGrid, polygon_scene, range_image, visible_planes
from profiles.errors import DataError, UsageError
from profiles.planes import PdGrid, PlaneDetectorParams, PlaneNoise, PlaneStats
from profiles.profile import DetectorProfile, DetectorSpec, InputRef, Provenance
from profiles.schema import ClutterParams, PdTable

POINTS_EDGES = [0, 1, 10, 25, 50, 100, 200, 400, 800, 1600, 3200, 6400]
ANGLE_EDGES = [0.0, 30.0, 50.0, 65.0, 75.0, 90.0]


class PlaneCalibConfig(BaseModel):
    """Everything ``detcal calibrate --config`` accepts for a lidar log (planes)."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)
    detector: PlaneDetectorParams = PlaneDetectorParams()
    gate_angle_deg: float = Field(default=5.0, gt=0.0, le=45.0, description="detection-truth gate on the normal angle")
    gate_offset: float = Field(default=0.3, gt=0.0, description="detection-truth gate on the offset [m]")
    surface_share: float = Field(default=0.5, gt=0.0, le=1.0, description="share of a detection's inliers that must lie on the true plane")
    surface_margin: float = Field(default=0.3, ge=0.0, description="outline growth for the surface test [m]")
    max_elevation_deg: float = Field(default=45.0, gt=0.0, le=90.0, description="landmark planes: |normal elevation| at most this")
    min_points: int = Field(default=40, ge=1, description="landmark detections have at least this many inliers")
    min_width: float = Field(default=0.6, ge=0.0, description="landmark detections are at least this wide [m] (poles and trunks are not)")
    offset_max: float | None = Field(default=None, gt=0.0, description="farthest landmark plane [m] (default: the sensor's range_max)")
    points_edges: list[float] = Field(default_factory=lambda: list(POINTS_EDGES), min_length=2)
    angle_edges_deg: list[float] = Field(default_factory=lambda: list(ANGLE_EDGES), min_length=2)
    pd: PdFitConfig = PdFitConfig(min_count=50)
    slab_k_sigma: float = Field(default=3.0, gt=0.0)
    every: int = Field(default=1, ge=1, description="use every N-th frame")


@dataclass
class PlaneLabels:
    """Labelled frames: detections (one row per detection) and pairs (one row per (frame, true plane) in view)."""

    detections: pd.DataFrame
    pairs: pd.DataFrame
    frames: int
    planes_per_frame: list[PlaneDetections] = field(default_factory=list)


def sensor_poses_at(log: SensorLog, stamps: np.ndarray) -> np.ndarray:
    """(F, 3) sensor poses at ``stamps`` from the log's ground truth and the mount."""
    ref = log.reference.get("ground_truth")
    if ref is None:
        raise UsageError(f"log {log.name!r} has no ground-truth poses; plane calibration needs them")
    if stamps[0] < ref.stamp[0] or stamps[-1] > ref.stamp[-1]:
        raise DataError(f"log {log.name!r}: clouds extend beyond the ground-truth poses")
    m = log.sensor.mount
    return compose(interpolate_poses(ref.stamp, ref.poses, stamps), np.array([m.x, m.y, m.theta]))


def _need(log: SensorLog) -> None:
    if log.clouds is None:
        raise UsageError(f"log {log.name!r} has no point clouds")
    if log.planes is None:
        raise UsageError(f"log {log.name!r} has no plane truth (the street simulator writes it)")
    if log.sensor is None or log.sensor.lidar is None:
        raise DataError(f"log {log.name!r}: the sensor model has no lidar geometry (rings and azimuth step)")


def true_planes_sensor(log: SensorLog, sp: np.ndarray, height: float) -> tuple[np.ndarray, np.ndarray]:
    """(n (L, 3), d (L,)) of the true planes in the sensor frame at pose sp (3,), oriented away from the sensor."""
    pl = log.planes
    c, s = np.cos(sp[2]), np.sin(sp[2])
    n = pl.normal
    ns = np.column_stack([c * n[:, 0] + s * n[:, 1], -s * n[:, 0] + c * n[:, 1], n[:, 2]])
    ds = pl.offset - (n[:, 0] * sp[0] + n[:, 1] * sp[1] + n[:, 2] * height)
    return orient_away(ns, ds)


def _surface_share(pts: np.ndarray, poly_world: np.ndarray, sp: np.ndarray, height: float, n_s, d_s, tol: float, margin: float) -> float:
    """Share of points (sensor frame) on a true polygon: within ``tol`` of its plane and inside its outline grown by ``margin``."""
    c, s = np.cos(sp[2]), np.sin(sp[2])
    rel = poly_world - np.array([sp[0], sp[1], height])
    poly = np.column_stack([c * rel[:, 0] + s * rel[:, 1], -s * rel[:, 0] + c * rel[:, 1], rel[:, 2]])
    on = np.abs(pts @ n_s - d_s) <= tol
    if not on.any():
        return 0.0
    u, v = plane_basis(n_s)
    o = poly.mean(axis=0)
    p2 = np.column_stack([(poly - o) @ u, (poly - o) @ v])
    q2 = np.column_stack([(pts[on] - o) @ u, (pts[on] - o) @ v])
    # inside the convex outline grown by the margin: every edge's signed distance >= -margin
    e = np.roll(p2, -1, axis=0) - p2
    orient = np.sign(np.sum(p2[:, 0] * np.roll(p2[:, 1], -1) - np.roll(p2[:, 0], -1) * p2[:, 1])) or 1.0
    nrm = np.linalg.norm(e, axis=1)
    cross = (e[None, :, 0] * (q2[:, None, 1] - p2[None, :, 1]) - e[None, :, 1] * (q2[:, None, 0] - p2[None, :, 0])) * orient / np.maximum(nrm, 1e-12)
    inside = (cross >= -margin).all(axis=1)
    return float(inside.sum() / pts.shape[0])


def label_planes(log: SensorLog, cfg: PlaneCalibConfig, *, keep_detections: bool = False) -> PlaneLabels:
    """Detect, associate and ray-trace every used frame of ``log`` (module docstring, steps 1-3)."""
    _need(log)
    sensor = log.sensor
    height = sensor.lidar.height
    grid = BeamGrid.of(sensor.lidar)
    sigma = float(sensor.range_sigma or cfg.detector.range_sigma)
    rmax = float(sensor.range_max or 120.0)
    offset_max = cfg.offset_max or rmax
    steep_max = np.sin(np.radians(cfg.max_elevation_deg))
    steep_idx = np.flatnonzero(np.abs(log.planes.normal[:, 2]) <= steep_max)  # only landmark planes are ray-traced
    scene = polygon_scene(log.planes.take(steep_idx))
    frames = np.arange(0, len(log.clouds), cfg.every)
    sps = sensor_poses_at(log, log.clouds.stamp[frames])
    # the runtime's slab counts of the true planes (its P_D table is not used here)
    slab_model = PlaneDetectionModel(
        None, ClutterParams(rate=0.0, space="plane", volume=1.0), height, sigma, np.radians(cfg.max_elevation_deg), offset_max,
        constant_pd=1.0, slab_k_sigma=cfg.slab_k_sigma,
    )
    det_rows, pair_rows, kept = [], [], []
    pl = log.planes
    tol = 3.0 * sigma + 0.02
    for fi, f in enumerate(frames):  # per frame: one detector run (vectorised inside) and one ray trace
        cloud = log.clouds.frame(int(f))
        sp = sps[fi]
        det, lab = detect_planes(cloud, cfg.detector, where=f"{log.name}: cloud {int(f)}", return_labels=True)
        if keep_detections:
            kept.append(det.with_frame(int(f)))
        meas = range_image(cloud, grid)
        n_p, n_exp, cen = np.zeros(len(pl), np.int64), np.zeros(len(pl), np.int64), np.full((len(pl), 3), np.nan)
        n_p[steep_idx], n_exp[steep_idx], cen[steep_idx] = visible_planes(scene, grid, sp, height, meas, range_sigma=sigma, range_max=rmax)
        ns, ds = true_planes_sensor(log, sp, height)
        inc = np.where(n_p > 0, normal_angle(ns, np.nan_to_num(cen)), np.nan)
        # association: gate on normal and offset, then the surface share, one detection per plane
        m = len(det)
        assoc = np.full(m, -1)
        share_of = np.zeros(m)
        if m:
            ang = normal_angle(det.normal[:, None, :], ns[None, :, :])
            dd = np.abs(det.offset[:, None] - ds[None, :])
            gated = (ang <= np.radians(cfg.gate_angle_deg)) & (dd <= cfg.gate_offset) & (n_exp[None, :] > 0)
            share = np.zeros(gated.shape)
            xyz = np.asarray(cloud[:, :3], dtype=np.float64)
            by = np.argsort(lab, kind="stable")
            bounds = np.searchsorted(lab[by], np.arange(m + 1))
            for a, b in zip(*np.nonzero(gated), strict=True):  # gated pairs only (about one per detection)
                pts = xyz[by[bounds[a] : bounds[a + 1]]]
                share[a, b] = _surface_share(pts, pl.polygon(int(b)), sp, height, ns[b], ds[b], tol, cfg.surface_margin)
            ok = share >= cfg.surface_share
            if ok.any():
                r, c = linear_sum_assignment(-np.where(ok, share, 0.0))
                good = ok[r, c]
                assoc[r[good]] = c[good]
                share_of[r[good]] = share[r[good], c[good]]
        # slab counts of the true planes (the runtime's stand-in for n_p), for the ratio
        away = np.where(pl.offset - pl.normal @ np.array([sp[0], sp[1], height]) < 0, -1.0, 1.0)  # as a map plane born here
        wc = chart_from_normal(pl.normal * away[:, None], pl.offset * away)
        slab, _ = slab_model.visible_points(sp[None], wc[None], np.zeros((1, len(pl), 3, 3)), cloud)
        landmark_det = landmark_detections(det, slab_model.in_view, cfg.min_points, cfg.min_width)  # the runtime's rule
        det_rows.append(
            pd.DataFrame(
                {
                    "log": log.name, "frame": int(f), "azimuth": det.chart[:, 0], "elevation": det.chart[:, 1], "offset": det.offset,
                    "inliers": det.inliers, "sigma": det.sigma, "area": det.area, "width": det.width, "plane": np.where(assoc >= 0, pl.ids[np.maximum(assoc, 0)], -1),
                    "share": share_of, "landmark": landmark_det,
                }
            )
        )
        view = (n_exp > 0) & (np.abs(ns[:, 2]) <= steep_max) & (ds <= offset_max)
        idx = np.flatnonzero(view)
        found = np.zeros(len(pl), dtype=bool)
        found[assoc[(assoc >= 0) & landmark_det]] = True
        det_of = np.full(len(pl), -1)
        det_of[assoc[assoc >= 0]] = np.flatnonzero(assoc >= 0)
        zs = chart_from_normal(ns, ds)
        dj = np.maximum(det_of, 0)
        pair_rows.append(
            pd.DataFrame(
                {
                    "log": log.name, "frame": int(f), "plane": pl.ids[idx], "kind": pl.kind[idx], "n_p": n_p[idx], "n_expected": n_exp[idx],
                    "incidence_deg": np.degrees(inc[idx]), "offset": ds[idx], "slab": slab[0, idx], "detected": found[idx],
                    "det_azimuth": np.where(found[idx], det.chart[dj[idx], 0] if m else np.nan, np.nan),
                    "det_elevation": np.where(found[idx], det.chart[dj[idx], 1] if m else np.nan, np.nan),
                    "det_offset": np.where(found[idx], det.offset[dj[idx]] if m else np.nan, np.nan),
                    "true_azimuth": zs[idx, 0], "true_elevation": zs[idx, 1],
                    "normal_err_deg": np.where(found[idx], np.degrees(normal_angle(det.normal[dj[idx]], ns[idx])) if m else np.nan, np.nan),
                }
            )
        )
    return PlaneLabels(pd.concat(det_rows, ignore_index=True), pd.concat(pair_rows, ignore_index=True), int(frames.size), kept)


def fit_points_table(values: np.ndarray, detected: np.ndarray, edges: list[float], cfg: PdFitConfig) -> PdTable:
    """P_D over expected visible points in the given bins (eq. 6.2), Wilson intervals, the thesis's clamping."""
    values = np.asarray(values, dtype=np.float64)
    detected = np.asarray(detected, dtype=bool)
    if values.size == 0:
        raise DataError("no (frame, plane) pairs in view to fit P_D to")
    e = np.asarray(edges, dtype=np.float64)
    idx = np.clip(np.searchsorted(e, values, side="right") - 1, 0, e.size - 2)
    n = np.bincount(idx, minlength=e.size - 1)
    k = np.bincount(idx, weights=detected, minlength=e.size - 1).astype(np.int64)
    well = np.flatnonzero(n >= cfg.min_count)
    if well.size == 0:
        raise DataError(f"no P_D bin holds {cfg.min_count} pairs; calibrate on more frames or lower pd.min_count")
    last = int(well[-1])
    if cfg.tail == "pool":
        n[last], k[last] = n[last:].sum(), k[last:].sum()
    n, k, e = n[: last + 1], k[: last + 1], e[: last + 2]
    raw = np.where(n > 0, k / np.maximum(n, 1), 0.0)
    pdv = np.where(raw < cfg.zero_below, 0.0, raw)
    lo, hi = wilson(k, n)
    return PdTable(
        covariate="points", edges=e.tolist(), pd=pdv.tolist(), counts=n.tolist(), detections=k.tolist(),
        wilson_low=np.nan_to_num(lo, nan=0.0).tolist(), wilson_high=np.nan_to_num(hi, nan=1.0).tolist(),
        clamping=f"points >= {e[last]:g} uses the last well-populated bin (>= {cfg.min_count} pairs, tail={cfg.tail}); P_D < {cfg.zero_below:g} set to 0",
    )


def fit_grid(pairs: pd.DataFrame, table: PdTable, angle_edges: list[float], min_count: int, zero_below: float = 0.1) -> PdGrid:
    """P_D over (points bins of ``table``) x (incidence angle bins); thin cells take the 1-D table's value, cells of
    their own under ``zero_below`` become 0 (the thesis's clamp, as for the table)."""
    pe = np.asarray(table.edges, dtype=np.float64)
    ae = np.asarray(angle_edges, dtype=np.float64)
    i = np.clip(np.searchsorted(pe, pairs["n_p"].to_numpy(np.float64), side="right") - 1, 0, pe.size - 2)
    a = np.nan_to_num(pairs["incidence_deg"].to_numpy(np.float64), nan=0.0)
    j = np.clip(np.searchsorted(ae, a, side="right") - 1, 0, ae.size - 2)
    shape = (pe.size - 1, ae.size - 1)
    flat = i * shape[1] + j
    n = np.bincount(flat, minlength=shape[0] * shape[1]).reshape(shape)
    k = np.bincount(flat, weights=pairs["detected"].to_numpy(bool), minlength=shape[0] * shape[1]).reshape(shape).astype(np.int64)
    one = np.asarray(table.pd)[:, None] * np.ones(shape)
    filled = n < min_count
    raw = np.where(n > 0, k / np.maximum(n, 1), 0.0)
    pdv = np.where(filled, one, np.where(raw < zero_below, 0.0, raw))
    return PdGrid(points_edges=pe.tolist(), angle_edges_deg=ae.tolist(), pd=pdv.tolist(), counts=n.tolist(), detections=k.tolist(), filled=filled.tolist())


def fit_plane_noise(pairs: pd.DataFrame) -> PlaneNoise | None:
    t = pairs[pairs["detected"]]
    if len(t) < 10:
        return None
    ra = wrap(t["det_azimuth"].to_numpy() - t["true_azimuth"].to_numpy())
    re = t["det_elevation"].to_numpy() - t["true_elevation"].to_numpy()
    ro = t["det_offset"].to_numpy() - t["offset"].to_numpy()

    def robust(x):
        med = float(np.median(x))
        return med, max(float(1.4826 * np.median(np.abs(x - med))), 1e-6)

    _, sa = robust(ra)
    _, se = robust(re)
    bo, so = robust(ro)
    return PlaneNoise(
        azimuth_sigma=sa, elevation_sigma=se, offset_sigma=so, normal_angle_median=float(np.radians(np.median(t["normal_err_deg"]))),
        offset_bias=bo, samples=len(t),
    )


@dataclass
class PlaneCalibration:
    profile: DetectorProfile
    config: PlaneCalibConfig
    labels: PlaneLabels
    clutter: ClutterFit
    summary: dict


def calibrate_planes(
    logs: list[SensorLog], cfg: PlaneCalibConfig, *, name: str, version: str, description: str = "", input_refs: list[InputRef] | None = None, command: str = ""
) -> PlaneCalibration:
    if not logs:
        raise UsageError("no logs to calibrate")
    for lg in logs:
        _need(lg)
    s0 = logs[0].sensor
    for lg in logs[1:]:
        if lg.sensor.lidar != s0.lidar:
            raise UsageError(f"logs {logs[0].name!r} and {lg.name!r} have different lidar geometries; calibrate them separately")
    parts = [label_planes(lg, cfg) for lg in logs]
    dets = pd.concat([p.detections for p in parts], ignore_index=True)
    pairs = pd.concat([p.pairs for p in parts], ignore_index=True)
    table = fit_points_table(pairs["n_p"].to_numpy(), pairs["detected"].to_numpy(), cfg.points_edges, cfg.pd)
    grid = fit_grid(pairs, table, cfg.angle_edges_deg, cfg.pd.min_count, cfg.pd.zero_below)
    # clutter: landmark detections that are no true plane's, per frame (frames with none count)
    fa = dets[dets["landmark"] & (dets["plane"] < 0)]
    counts = np.concatenate(
        [np.bincount(np.searchsorted(np.arange(0, len(lg.clouds), cfg.every), fa.loc[fa["log"] == lg.name, "frame"].to_numpy()), minlength=p.frames)
         for lg, p in zip(logs, parts, strict=True)]
    )
    clut = fit_clutter(counts)
    rmax = float(s0.range_max or 120.0)
    offset_max = cfg.offset_max or rmax
    volume = PlaneDetectionModel.chart_volume(np.radians(cfg.max_elevation_deg), offset_max)
    big = pairs[(pairs["n_p"] >= 50) & pairs["detected"]]
    ratio = float(np.median(big["slab"] / big["n_p"])) if len(big) else None
    noise = fit_plane_noise(pairs)
    seeds = {lg.source.get("seed") for lg in logs if lg.source.get("seed") is not None}
    profile = DetectorProfile(
        name=name,
        version=version,
        description=description,
        detector=DetectorSpec(kind="plane3d", plane=cfg.detector, k_sigma=cfg.slab_k_sigma, association_gate=cfg.gate_offset),
        sensor=s0,
        pd=table,
        clutter=clutter_params(clut, "plane", volume),
        planes=PlaneStats(
            pd_grid=grid, noise=noise, max_elevation_deg=cfg.max_elevation_deg, min_points=cfg.min_points, min_width=cfg.min_width, offset_max=offset_max,
            slab_k_sigma=cfg.slab_k_sigma, slab_ratio=ratio,
        ),
        provenance=Provenance(
            inputs=input_refs or [],
            detcal_version=__version__,
            **build_stamp(),
            command=command,
            parameters=cfg.model_dump(mode="json"),
            created=created_now(),
            seed=seeds.pop() if len(seeds) == 1 else None,
        ),
    )
    true_det = pairs["detected"]
    summary = {
        "logs": [lg.name for lg in logs],
        "frames": int(sum(p.frames for p in parts)),
        "detections": len(dets),
        "landmark_detections": int(dets["landmark"].sum()),
        "true_landmark_detections": int((dets["landmark"] & (dets["plane"] >= 0)).sum()),
        "plane_frame_pairs_in_view": len(pairs),
        "pd_overall": float(true_det.mean()),
        "pd_pairs_over_200_points": float(pairs.loc[pairs["n_p"] >= 200, "detected"].mean()) if (pairs["n_p"] >= 200).any() else float("nan"),
        "normal_error_median_deg": float(pairs.loc[true_det, "normal_err_deg"].median()) if true_det.any() else float("nan"),
        "offset_error_median_m": float((pairs.loc[true_det, "det_offset"] - pairs.loc[true_det, "offset"]).abs().median()) if true_det.any() else float("nan"),
        "slab_ratio": ratio,
        "clutter_rate": clut.rate,
        "clutter_chi2": clut.chi2,
        "clutter_dof": clut.dof,
        "clutter_p_value": clut.p_value,
        "clutter_dispersion": clut.dispersion,
        "clutter_poisson_rejected_at_0.05": bool(np.isfinite(clut.p_value) and clut.p_value < 0.05),
    }
    return PlaneCalibration(profile, cfg, PlaneLabels(dets, pairs, int(sum(p.frames for p in parts))), clut, summary)


def validate_planes(profile: DetectorProfile, log: SensorLog, *, drift=None):
    """Score a lidar3d-planes profile on a held-out log with truth (:mod:`calib.validate`): the reliability of its
    P_D predictions over every (frame, landmark plane) pair in view, and observed against predicted false alarms
    per frame, with the drift verdicts (``drift``: a :class:`calib.drift.DriftConfig`, defaults when None)."""
    from calib.validate import Held, score

    if profile.kind != "lidar3d-planes":
        raise UsageError(f"profile {profile.ref} is a {profile.kind} profile, not lidar3d-planes")
    st = profile.planes
    cfg = PlaneCalibConfig(
        detector=profile.detector.plane, max_elevation_deg=st.max_elevation_deg, min_points=st.min_points, min_width=st.min_width,
        offset_max=st.offset_max, slab_k_sigma=st.slab_k_sigma, gate_offset=profile.detector.association_gate,
    )
    lab = label_planes(log, cfg)
    pairs = lab.pairs
    pts, ang = pairs["n_p"].to_numpy(np.float64), np.radians(np.nan_to_num(pairs["incidence_deg"].to_numpy(np.float64)))
    pred = st.pd_grid.lookup(pts, ang) if st.pd_grid is not None else profile.pd.lookup(pts)
    t = log.clouds.stamp[pairs["frame"].to_numpy()] / 1e9
    pairs = pairs.assign(predicted=pred, observed=pairs["detected"].to_numpy(), landmark=pairs["plane"], block=np.floor((t - t[0]) / 10.0) if len(t) else t)
    dets = lab.detections
    fa = dets[dets["landmark"] & (dets["plane"] < 0)]
    counts = np.bincount(np.searchsorted(np.arange(0, len(log.clouds), cfg.every), fa["frame"].to_numpy()), minlength=lab.frames)
    period = float(np.median(np.diff(log.clouds.stamp)) / 1e9) if len(log.clouds) > 1 else float("nan")
    held = Held(log.name, pairs, counts, np.zeros(0), np.zeros(0), period, extra={"plane_frame_pairs_in_view": len(pairs)})
    return score(profile, [held], drift=drift)


