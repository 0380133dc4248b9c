"""Self-calibration: detection statistics measured against a SLAM run's own map and trajectory.

A detection-level log without landmark truth (Victoria Park: tree detections,
odometry and GPS) cannot be calibrated against truth. Instead a SLAM run's
trajectory and map are taken as the truth, and the detector's statistics are
measured against them exactly as a calibration would (thesis ch. 4 and 6):

* **association**: at every frame, the map features inside the sensor's field
  of view (seen from the run's sensor pose) and the frame's detections, placed
  in the world frame, are matched by an optimal assignment (Euclidean cost,
  ``gate`` metres at most); a matched detection is true, the rest are false
  alarms;
* **P_D against range** (eq. 6.2 with range as the covariate): one pair per
  (frame, feature in view) with its range, detected or not; features hidden
  behind a nearer mapped tree (the n_p idea applied to the map: the nearer
  trunk's angular extent covers the farther one's centre) are counted apart,
  so the table is that of unoccluded trees and the occluded share is reported;
* **clutter**: the unmatched detections per frame, a Poisson rate with
  Pearson's test and its dispersion, kappa over range x bearing;
* **noise**: robust spread (1.4826 MAD) and median bias of the matched
  detections' range and bearing residuals.

The profile it writes says in its description and provenance that it was
measured against a SLAM run, which run, and which iteration. Iterating (run
SLAM with the profile, measure again) is driven by ``detcal selfcal``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pandas as pd
from scipy.optimize import linear_sum_assignment

from calib import __version__
from calib.calibrate import created_now
from calib.detlevel import fit_noise
from calib.fits import ClutterFit, clutter_params, fit_clutter, fit_pd_table
from calib.progress import progress
from detectors.geometry import compose
from detectors.sensor_log import SensorLog
from profiles.errors import DataError
from profiles.override import updated
from profiles.parameters import SelfCalConfig
from profiles.profile import DetectorProfile, DetectorSpec, InputRef, Provenance
from profiles.schema import MeasurementNoise, SensorModel


@dataclass
class SelfCalibration:
    profile: DetectorProfile
    pairs: pd.DataFrame  # frame, feature, range, bearing, occluded, detected
    detections: pd.DataFrame  # frame, range, bearing, feature or -1, range/bearing residuals
    clutter: ClutterFit
    summary: dict


def _wrap(a: np.ndarray) -> np.ndarray:
    return np.mod(a + np.pi, 2 * np.pi) - np.pi


def measure(log: SensorLog, trajectory: np.ndarray, map_xy: np.ndarray, sensor: SensorModel, cfg: SelfCalConfig):
    """Pairs and labelled detections of every frame against the map.

    trajectory (T, 3): vehicle poses at the log's frames (world frame); map_xy (K, 2).
    """
    d = log.detections
    if d is None:
        raise DataError(f"log {log.name!r} has no detections to self-calibrate")
    n_frames = d.n_frames
    if trajectory.shape[0] != n_frames:
        raise DataError(f"the trajectory has {trajectory.shape[0]} poses for the log's {n_frames} frames")
    if map_xy.shape[0] == 0:
        raise DataError("the SLAM map is empty: nothing to measure the detector against")
    m = sensor.mount
    sp = compose(trajectory, np.array([m.x, m.y, m.theta]))
    fov, rmax = sensor.field_of_view, sensor.range_max
    if fov is None or rmax is None:
        raise DataError("the sensor model needs a field of view and range_max")
    # trunk radius per feature: half the median diameter of its matched detections (filled after matching)
    diam = np.asarray(d.descriptors["diameter"], dtype=np.float64) if "diameter" in d.descriptors else None
    off = d.frame_slices()
    rows = {"frame": [], "feature": [], "range": [], "bearing": []}
    det_feat = np.full(len(d), -1, dtype=np.int64)
    for f in progress(range(n_frames), n_frames, "matching detections to the map"):
        rel = map_xy - sp[f, :2]
        rr = np.hypot(rel[:, 0], rel[:, 1])
        bb = _wrap(np.arctan2(rel[:, 1], rel[:, 0]) - sp[f, 2])
        view = np.flatnonzero((rr <= rmax) & (rr >= sensor.range_min) & (np.abs(bb) <= fov / 2))
        rows["frame"].append(np.full(view.size, f))
        rows["feature"].append(view)
        rows["range"].append(rr[view])
        rows["bearing"].append(bb[view])
        a, b = int(off[f]), int(off[f + 1])
        if b == a or view.size == 0:
            continue
        zr, zb = d.range[a:b], d.bearing[a:b]
        ang = sp[f, 2] + zb
        world = np.column_stack([sp[f, 0] + zr * np.cos(ang), sp[f, 1] + zr * np.sin(ang)])
        cost = np.hypot(*(world[:, None, :] - map_xy[view][None, :, :]).transpose(2, 0, 1))
        big = cfg.gate * 10.0
        r, c = linear_sum_assignment(np.where(cost <= cfg.gate, cost, big))
        ok = cost[r, c] <= cfg.gate
        det_feat[a + r[ok]] = view[c[ok]]
    pairs = pd.DataFrame({k: np.concatenate(v) for k, v in rows.items()})
    frame_of = d.frame
    matched = det_feat >= 0
    key = pd.MultiIndex.from_arrays([frame_of[matched], det_feat[matched]])
    pairs["detected"] = pd.MultiIndex.from_arrays([pairs["frame"], pairs["feature"]]).isin(key)
    # occlusion by the map's own trees: a nearer feature whose angular half-width covers this one's bearing
    radius = np.full(map_xy.shape[0], cfg.radius if cfg.radius is not None else 0.0)
    if diam is not None and matched.any():
        med = pd.Series(diam[matched]).groupby(det_feat[matched]).median()
        radius[med.index.to_numpy()] = np.clip(med.to_numpy() / 2, 0.05, 2.0)
    occluded = np.zeros(len(pairs), dtype=bool)
    fr = pairs["frame"].to_numpy()
    starts = np.searchsorted(fr, np.arange(n_frames + 1))
    rng_all, brg_all, feat_all = pairs["range"].to_numpy(), pairs["bearing"].to_numpy(), pairs["feature"].to_numpy()
    traced = n_frames if (diam is not None or cfg.radius is not None) else 0  # point landmarks occlude nothing
    for f in progress(range(traced), traced, "occlusion by the map's trees"):
        a, b = starts[f], starts[f + 1]
        if b - a < 2:
            continue
        r, br, rad = rng_all[a:b], brg_all[a:b], radius[feat_all[a:b]]
        half = np.arcsin(np.clip(rad / np.maximum(r, 1e-6), 0.0, 1.0))  # angular half-width of each trunk
        ahead = r[None, :] < r[:, None] - 2 * rad[None, :]  # [i, j]: j is nearer than i by more than its trunk
        cover = np.abs(_wrap(br[:, None] - br[None, :])) < half[None, :]
        occluded[a:b] = (ahead & cover).any(axis=1)
    pairs["occluded"] = occluded
    zr_hat = np.full(len(d), np.nan)
    zb_hat = np.full(len(d), np.nan)
    if matched.any():
        rel = map_xy[det_feat[matched]] - sp[frame_of[matched], :2]
        zr_hat[matched] = np.hypot(rel[:, 0], rel[:, 1])
        zb_hat[matched] = _wrap(np.arctan2(rel[:, 1], rel[:, 0]) - sp[frame_of[matched], 2])
    dets = pd.DataFrame(
        {
            "frame": frame_of,
            "range": d.range,
            "bearing": d.bearing,
            "feature": det_feat,
            "range_residual": d.range - zr_hat,
            "bearing_residual": _wrap(d.bearing - zb_hat),
        }
    )
    return pairs, dets


def noise_of(dets: pd.DataFrame) -> MeasurementNoise | None:
    """Range and bearing noise of the detections associated with a map feature."""
    return fit_noise(dets, dets["feature"] >= 0)


def self_calibrate(
    log: SensorLog,
    trajectory: np.ndarray,
    map_xy: np.ndarray,
    map_w: np.ndarray | None,
    prior: DetectorProfile,
    cfg: SelfCalConfig,
    *,
    name: str,
    version: str,
    run: str = "",
    iteration: int = 0,
    input_refs: list[InputRef] | None = None,
    command: str = "",
    mount_yaw: float = 0.0,
) -> SelfCalibration:
    """The profile measured against a SLAM run (its trajectory at the log's frames and its map).

    map_w (K,): the components' weights (None: every row of map_xy is a feature); the
    components of weight >= ``cfg.map_weight`` are the features. The sensor model (field of
    view, range limit, mount) is the prior profile's: what is not seen cannot be measured;
    ``mount_yaw`` [rad] turns the mount as the SLAM run did (``SlamConfig.mount_yaw``), so the
    detections are placed from the sensor pose the run used.
    """
    if map_w is not None:
        map_xy = np.asarray(map_xy)[np.asarray(map_w) >= cfg.map_weight]
    sensor = prior.sensor  # the profile keeps the prior's sensor; the correction belongs to the run's settings
    pairs, dets = measure(log, trajectory, map_xy, sensor.turned(mount_yaw), cfg)
    free = pairs[~pairs["occluded"]]
    table = fit_pd_table(free["range"].to_numpy(), free["detected"].to_numpy(), "range", cfg.pd)
    table = updated(table, {"clamping": table.clamping + "; unoccluded (frame, map feature) pairs of a SLAM run"})
    counts = np.bincount(dets["frame"].to_numpy()[dets["feature"].to_numpy() < 0], minlength=log.detections.n_frames)
    clut = fit_clutter(counts)
    volume = sensor.field_of_view * (sensor.range_max - sensor.range_min)
    noise = noise_of(dets)
    desc = (
        f"Self-calibrated against SLAM run {run or '(in memory)'} (iteration {iteration}): P_D of unoccluded map features "
        "against range, clutter and noise measured with the run's map and trajectory as the truth; no landmark truth was used."
    )
    matched = dets["feature"].to_numpy() >= 0
    diam = log.detections.descriptors.get("diameter")
    occ_r = float(np.median(np.asarray(diam)[matched]) / 2) if diam is not None and matched.any() else cfg.radius
    occ_r = None if occ_r is None else float(np.clip(occ_r, 0.05, 2.0))
    profile = DetectorProfile(
        name=name,
        version=version,
        description=desc,
        detector=DetectorSpec(kind="external", association_gate=cfg.gate, occluder_radius=occ_r),
        sensor=sensor,
        pd=table,
        clutter=clutter_params(clut, "range_bearing", volume),
        noise=noise,
        provenance=Provenance(
            inputs=input_refs or [],
            detcal_version=__version__,
            command=command,
            parameters={**cfg.model_dump(mode="json"), "slam_run": run, "iteration": iteration, "prior": prior.ref},
            created=created_now(),
        ),
    )
    matched = dets["feature"] >= 0
    summary = {
        "occluder_radius_m": profile.detector.occluder_radius,
        "log": log.name,
        "frames": int(log.detections.n_frames),
        "map_features": int(map_xy.shape[0]),
        "detections": len(dets),
        "matched_detections": int(matched.sum()),
        "false_alarms_per_frame": clut.rate,
        "clutter_p_value": clut.p_value,
        "clutter_dispersion": clut.dispersion,
        "pairs_in_view": len(pairs),
        "occluded_share": float(pairs["occluded"].mean()),
        "pd_unoccluded": float(free["detected"].mean()) if len(free) else float("nan"),
        "pd_occluded": float(pairs.loc[pairs["occluded"], "detected"].mean()) if pairs["occluded"].any() else float("nan"),
        "range_sigma_m": noise.range_sigma if noise else float("nan"),
        "bearing_sigma_rad": noise.bearing_sigma if noise else float("nan"),
    }
    return SelfCalibration(profile, pairs, dets, clut, summary)


def pool_self_calibrations(cals: list[SelfCalibration], cfg: SelfCalConfig, *, iterations: list[int]) -> DetectorProfile:
    """One profile from the measurements of several SLAM runs of one log (Polyak-Ruppert averaging of
    the self-calibration's iterates).

    Each run's map is one random draw of the truth, so each measurement scatters about the fixed point
    by the run-to-run spread and the
    iteration does not settle; their average does. The runs measure the *same* detections against
    different maps, so their pairs are not new data: P_D per bin is the pooled rate of the runs'
    unoccluded pairs (bins of ``cfg.pd`` with ``min_count`` per run), but the counts, detections and
    Wilson intervals written are per run (the pooled counts / n), not sqrt(n) times narrower; the noise is
    the robust spread of the pooled residuals with ``samples`` per run; the clutter rate is the mean of
    the runs' rates, its count model and tests those of the last run (its shape, which moves little;
    the provenance says which run); the occluder radius is the mean. ``iterations``: the iteration
    numbers of ``cals`` (provenance).
    """
    if not cals or len(iterations) != len(cals):
        raise ValueError(f"{len(cals)} measurements to pool with {len(iterations)} iteration numbers")
    n = len(cals)
    last = cals[-1]
    if n == 1:
        return last.profile
    free = pd.concat([c.pairs[~c.pairs["occluded"]] for c in cals], ignore_index=True)
    t = fit_pd_table(free["range"].to_numpy(), free["detected"].to_numpy(), "range", cfg.pd, runs=n)
    table = updated(t, {"clamping": t.clamping + "; unoccluded (frame, map feature) pairs of SLAM runs"})
    dets = pd.concat([c.detections for c in cals], ignore_index=True)
    noise = noise_of(dets)
    if noise is not None:
        noise = updated(noise, {"samples": round(noise.samples / n)})
    rate = float(np.mean([c.clutter.rate for c in cals]))
    clutter = updated(last.profile.clutter, {"rate": rate, "kappa": None})  # kappa filled in again from the rate
    radii = [c.profile.detector.occluder_radius for c in cals]
    occ_r = None if any(r is None for r in radii) else float(np.mean(radii))
    prov = last.profile.provenance
    pooled = updated(
        last.profile,
        {
            "description": (
                f"Self-calibrated against the SLAM runs of iterations {iterations[0]}-{iterations[-1]} of this self-calibration, their measurements averaged: "
                "P_D of unoccluded map features against range, clutter and noise measured with each run's map and trajectory as the "
                "truth; no landmark truth was used."
            ),
            "detector.occluder_radius": occ_r,
            "pd": table,
            "clutter": clutter,
            "noise": noise,
            "provenance.parameters": {
                **prov.parameters,
                "averaged_iterations": list(iterations),
                "clutter_count_model_of_iteration": iterations[-1],
                "clutter_rate_per_run": [c.clutter.rate for c in cals],
                "range_sigma_per_run": [c.profile.noise.range_sigma if c.profile.noise else None for c in cals],
            },
        },
    )
    return DetectorProfile.model_validate(pooled.model_dump())


def profile_change(a: DetectorProfile, b: DetectorProfile) -> float:
    """Largest change between two self-calibrated profiles: in P_D over the common range bins, and in
    the noise sigmas and clutter rate relative to their size."""
    ra, rb = np.asarray(a.pd.edges[:-1]), np.asarray(b.pd.edges[:-1])
    grid = np.union1d(ra, rb) + 1e-9
    d = float(np.max(np.abs(a.pd.lookup(grid) - b.pd.lookup(grid)))) if grid.size else 0.0
    rel = []
    if a.noise is not None and b.noise is not None:
        rel += [abs(a.noise.range_sigma - b.noise.range_sigma) / b.noise.range_sigma, abs(a.noise.bearing_sigma - b.noise.bearing_sigma) / b.noise.bearing_sigma]
    if b.clutter.rate > 0:
        rel.append(abs(a.clutter.rate - b.clutter.rate) / b.clutter.rate)
    return max([d, *rel])


