"""Calibration and validation of detection-level logs with truth (UTIAS MRCLAM's camera).

Such a log carries detections (range, bearing, an identity such as a barcode)
but no raw scans, so P_D cannot go through n_p: it is fitted against range and
bearing (thesis eq. 6.2 with the covariates changed). The steps:

* **camera epochs**: the log only lists frames that detected something, so the
  opportunities to detect are rebuilt as a regular grid at the camera's frame
  period (the median gap between consecutive detection frames when gaps under
  0.5 s are considered), each detection frame snapped to the
  nearest epoch;
* **identity audit**: a landmark identity whose detections almost all fall on
  another landmark's surveyed position (and almost never on its own) marks a
  swapped entry in the truth; its detections are attributed to the landmark
  they fall on, and the summary says so;
* **expected landmarks**: at every epoch the true vehicle pose (Vicon) gives
  each landmark's range and bearing; a landmark is expected when it is inside
  the field of view (|bearing| <= fov / 2, range <= range_max), both estimated
  from the true detections (their 99.5 % quantiles) unless given;
* **labels**: a detection whose identity is a landmark and whose measured
  position is within the gate of that landmark's true position is a true
  detection; every other detection (other robots, unknown barcodes, misplaced
  landmark readings) is a false alarm;
* **occlusion**: each (epoch, landmark in view) pair gets its clearance, the
  smallest distance from its line of sight of a nearer landmark in front of it;
  the occluder radius is the change point of the detection rate against the
  clearance (:func:`occluder_radius`), written to the profile (the filters then
  give P_D 0 to a feature behind a nearer mapped one within that radius), and the
  pairs it hides leave the P_D fit (the table is that of unoccluded landmarks);
* **fits**: the P_D model chosen by held-out likelihood among a range table
  and range x bearing grids (:mod:`calib.pdmodels`); clutter counts per epoch
  (Poisson or negative binomial, with the tests) and the clutter density over
  range x bearing (:mod:`calib.clutter`); with several sensors (robots) the
  spread between them and, on request, one partially pooled profile per sensor.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field

import numpy as np
import pandas as pd

from calib import __version__
from profiles.version import build_stamp
from calib.calibrate import created_now
from calib.clutter import density_summary, fit_density, rate_standard_error, time_folds
from calib.drift import DriftConfig, RowDrift, landmark_clusters, with_effective_counts
from calib.fits import ClutterFit, clutter_params, fit_clutter
from calib.io.common import index_of
from calib.pdmodels import between_sensor_sd, choose_pd_model, pool_sensors, predict, shrink_rates
from calib.validate import BLOCK_S, Held, Validation, score
from detectors.geometry import compose, interpolate_poses
from detectors.sensor_log import SensorLog
from profiles.errors import DataError, UsageError
from profiles.override import updated
from profiles.parameters import DetectionCalibConfig, IdentityAudit
from profiles.profile import DetectorProfile, DetectorSpec, Provenance, SensorSpread
from profiles.schema import PD_COVARIATES, MeasurementNoise, SensorModel


def frame_period(logs: list[SensorLog]) -> float:
    """The camera's frame period [s]: the median gap between detection frames, gaps of 0.05-0.5 s."""
    gaps = np.concatenate([np.diff(lg.detections.frame_stamp) / 1e9 for lg in logs])
    gaps = gaps[(gaps > 0.05) & (gaps < 0.5)]
    if gaps.size < 10:
        raise DataError("too few detection frames to estimate the camera's frame period; set frame_period in the --config file")
    return float(np.median(gaps))


def _need(log: SensorLog) -> None:
    if log.detections is None:
        raise DataError(f"log {log.name!r} has no detections")
    if log.landmarks is None or "ground_truth" not in log.reference:
        raise DataError(f"log {log.name!r} needs landmark truth and ground-truth poses for a detection-level calibration")
    from calib.truth import check_within_truth

    check_within_truth(log)  # a detection outside the truth's time span would get a clamped, wrong pose
    if "subject" not in log.detections.descriptors:
        raise DataError(f"log {log.name!r}: detections carry no identity (descriptor 'subject')")


def sensor_id(log: SensorLog) -> str:
    """A short name for the sensor of a log: ``robot<N>`` for UTIAS, else the log's name (lower case)."""
    robot = log.source.get("robot")
    if robot is not None:
        return f"robot{robot}"
    return re.sub(r"[^a-z0-9._-]+", "-", log.name.lower()).strip("-") or "sensor"


def sensor_names(logs: list[SensorLog]) -> list[str]:
    """One distinct name per log's sensor (numbered when two logs share one)."""
    names = [sensor_id(lg) for lg in logs]
    if len(set(names)) != len(names):
        names = [f"{n}-{k + 1}" for k, n in enumerate(names)]
    return names


def _sensor_poses(log: SensorLog, stamp: np.ndarray) -> np.ndarray:
    ref = log.reference["ground_truth"]
    pose = interpolate_poses(ref.stamp, ref.poses, stamp)
    m = log.sensor.mount if log.sensor is not None else None
    return pose if m is None else compose(pose, np.array([m.x, m.y, m.theta]))


def _detections_world(log: SensorLog) -> tuple[np.ndarray, np.ndarray]:
    d = log.detections
    sp = _sensor_poses(log, d.frame_stamp[d.frame])
    world = compose(sp, np.column_stack([d.range * np.cos(d.bearing), d.range * np.sin(d.bearing), np.zeros(len(d))]))
    return sp, world[:, :2]


def audit_identities(logs: list[SensorLog], gate: float, cfg: IdentityAudit) -> tuple[dict[int, int], dict[str, list[int]]]:
    """({identity -> landmark id its detections fall on}, evidence {"a->b": [on b, of all, on a]}).

    For each landmark identity, over all logs: how many of its detections lie
    within the gate of its own surveyed position and how many within the gate of
    each other landmark. An identity is re-attributed when at least ``share`` of
    its detections (and at least ``min_detections``) fall on one other landmark
    and at most 1 - share on its own.
    """
    if not cfg.enabled:
        return {}, {}
    ids = logs[0].landmarks.ids
    n_l = ids.size
    hits = np.zeros((n_l, n_l), dtype=np.int64)  # [identity, landmark it falls on]
    total = np.zeros(n_l, dtype=np.int64)
    for lg in logs:
        subj = np.asarray(lg.detections.descriptors["subject"], dtype=np.int64)
        lm = index_of(subj, lg.landmarks.ids)
        use = lm >= 0
        if not use.any():
            continue
        _, w = _detections_world(lg)
        dist = np.hypot(w[use, None, 0] - lg.landmarks.xy[None, :, 0], w[use, None, 1] - lg.landmarks.xy[None, :, 1])  # (D, L)
        near = dist.argmin(axis=1)
        ok = dist[np.arange(near.size), near] <= gate
        np.add.at(hits, (lm[use][ok], near[ok]), 1)
        total += np.bincount(lm[use], minlength=n_l)
    remap, evidence = {}, {}
    for a in range(n_l):
        if total[a] < cfg.min_detections:
            continue
        other = hits[a].copy()
        other[a] = -1
        b = int(other.argmax())
        if hits[a, b] >= cfg.share * total[a] and hits[a, a] <= (1 - cfg.share) * total[a]:
            remap[int(ids[a])] = int(ids[b])
            evidence[f"{int(ids[a])}->{int(ids[b])}"] = [int(hits[a, b]), int(total[a]), int(hits[a, a])]
    return remap, evidence


def identities(log: SensorLog, remap: dict[int, int] | None = None) -> np.ndarray:
    """(detections,) the identity each detection reads (its ``subject``), with those the identity audit re-attributed
    (``remap``: identity -> landmark id) replaced."""
    subj = np.asarray(log.detections.descriptors["subject"], dtype=np.int64)
    if remap:
        keys = np.array(list(remap), dtype=np.int64)
        vals = np.array(list(remap.values()), dtype=np.int64)
        pos = index_of(subj, keys)
        subj = np.where(pos >= 0, vals[np.maximum(pos, 0)], subj)
    return subj


def true_detections(log: SensorLog, gate: float, remap: dict[int, int] | None = None) -> pd.DataFrame:
    """One row per detection: range, bearing, frame stamp, landmark index or -1, and whether it is true.

    ``remap``: identity -> landmark id for identities the audit re-attributed.
    """
    d = log.detections
    sp, world = _detections_world(log)
    lm = index_of(identities(log, remap), log.landmarks.ids)
    dist = np.where(lm >= 0, np.hypot(*(world - log.landmarks.xy[np.maximum(lm, 0)]).T), np.inf)
    rel = log.landmarks.xy[np.maximum(lm, 0)] - sp[:, :2]
    r_hat = np.hypot(rel[:, 0], rel[:, 1])
    b_hat = np.arctan2(rel[:, 1], rel[:, 0]) - sp[:, 2]
    true = dist <= gate
    return pd.DataFrame(
        {
            "stamp": d.frame_stamp[d.frame],
            "range": d.range,
            "bearing": d.bearing,
            "landmark_index": lm,
            "true": true,
            "range_residual": np.where(true, d.range - r_hat, np.nan),
            "bearing_residual": np.where(true, np.mod(d.bearing - b_hat + np.pi, 2 * np.pi) - np.pi, np.nan),
        }
    )


def fit_noise(dets: pd.DataFrame, true: pd.Series | None = None) -> MeasurementNoise | None:
    """Robust spread (1.4826 MAD) and median bias of the true detections' range and bearing residuals.

    true: which rows are true detections (default: the ``true`` column).
    """
    t = dets[dets["true"] if true is None else true]
    if len(t) < 10:
        return None
    out = {}
    for col, key in (("range_residual", "range"), ("bearing_residual", "bearing")):
        x = t[col].to_numpy()
        med = float(np.median(x))
        out[f"{key}_bias"] = med
        out[f"{key}_sigma"] = max(float(1.4826 * np.median(np.abs(x - med))), 1e-6)
    return MeasurementNoise(**out, samples=len(t))


def _epochs(log: SensorLog, period: float) -> tuple[np.ndarray, np.ndarray]:
    fs = log.detections.frame_stamp
    p = int(round(period * 1e9))
    epochs = np.arange(fs[0], fs[-1] + p, p, dtype=np.int64)
    idx = np.clip(np.rint((fs - fs[0]) / p).astype(np.int64), 0, epochs.size - 1)
    return epochs, idx


@dataclass
class Labelled:
    """One log labelled at its epochs: pairs in view, false alarms per epoch and the false alarms themselves."""

    pairs: pd.DataFrame  # epoch, landmark, range, bearing, detected
    counts: np.ndarray  # false alarms per epoch (E,)
    false_alarms: pd.DataFrame  # epoch, range, bearing
    detections: pd.DataFrame  # :func:`true_detections`
    outside: int  # true detections outside the field of view / range


def label_epochs(log: SensorLog, gate: float, period: float, fov: float, range_max: float, remap: dict[int, int] | None = None) -> Labelled:
    """One pair per (epoch, landmark in view) with range, bearing [sensor frame] and whether it was detected."""
    dets = true_detections(log, gate, remap)
    epochs, f_epoch = _epochs(log, period)
    d_epoch = f_epoch[log.detections.frame]
    sp = _sensor_poses(log, epochs)
    rel = log.landmarks.xy[None, :, :] - sp[:, None, :2]
    rng = np.hypot(rel[..., 0], rel[..., 1])
    brg = np.mod(np.arctan2(rel[..., 1], rel[..., 0]) - sp[:, None, 2] + np.pi, 2 * np.pi) - np.pi
    view = (np.abs(brg) <= fov / 2) & (rng <= range_max)
    seen = np.zeros(rng.shape, dtype=bool)
    t = dets["true"].to_numpy()
    lm_t = dets["landmark_index"].to_numpy()[t]
    seen[d_epoch[t], lm_t] = True
    outside = int((~view[d_epoch[t], lm_t]).sum())
    e, lm = np.nonzero(view)
    block = (e * period // BLOCK_S).astype(np.int64)
    pairs = pd.DataFrame(
        {
            "epoch": e, "landmark": log.landmarks.ids[lm], "range": rng[e, lm], "bearing": brg[e, lm], "detected": seen[e, lm], "block": block,
            "clearance": clearance(rng, brg)[e, lm],
        }
    )  # fmt: skip
    fa = pd.DataFrame({"epoch": d_epoch[~t], "range": log.detections.range[~t], "bearing": log.detections.bearing[~t]})
    return Labelled(pairs, np.bincount(d_epoch[~t], minlength=epochs.size), fa, dets, outside)


def clearance(rng: np.ndarray, brg: np.ndarray) -> np.ndarray:
    """(E, N) for every epoch and landmark, the smallest distance [m] from its line of sight of another landmark nearer
    to the sensor and in front of it (inf: none), from their ranges and bearings (E, N): r_c |sin(b_c - b_a)|, the
    occlusion test of :meth:`detectors.model.DetectionModel._occlude` read as a distance."""
    out = np.full(rng.shape, np.inf)
    for c in range(rng.shape[1]):
        d = brg[:, c : c + 1] - brg
        lat = rng[:, c : c + 1] * np.abs(np.sin(d))
        front = (rng[:, c : c + 1] < rng) & (np.cos(d) > 0)
        front[:, c] = False
        out = np.where(front, np.minimum(out, lat), out)
    return out


def occluder_radius(clear: np.ndarray, detected: np.ndarray, *, reach: float = 0.5, step: float = 0.005, min_pairs: int = 20) -> tuple[float | None, dict]:
    """The occluder radius [m] of landmarks from their detections against their clearance (pairs (n,), :func:`clearance`):
    the change point rho of a two-rate Bernoulli model over the pairs with clearance below ``reach`` (rate p0 below
    rho, p1 from rho to reach), rho on a grid of ``step`` among the splits where the rate drops (p0 < p1), by maximum
    likelihood. Taken when the hidden side is rarely detected (p0 < p1 / 2), holds ``min_pairs`` pairs or more, and
    the change point beats one rate by a likelihood ratio above 13.8 (a nominal threshold: chi-square with 2 degrees
    of freedom at p = 0.001, were the pairs independent and the change point fixed; they are neither, so it only
    screens out logs with little sign of occlusion); else None. The rule differs from the filters' (detectors.model
    ``_occlude``) in two ways the calibration cannot know before it has the radius: the filters need the occluder
    nearer by more than twice the radius, and only features in view occlude. Returns the radius and what it was
    chosen from."""
    m = clear < reach
    c, y = clear[m], detected[m].astype(np.float64)
    info: dict = {"pairs_within_reach": int(m.sum()), "reach_m": reach}
    if c.size < 2 * min_pairs:
        return None, info | {"reason": "too few pairs near a line of sight"}

    order = np.argsort(c, kind="stable")
    cs, ys = c[order], np.cumsum(y[order])
    grid = np.round(np.arange(1, int(round(reach / step))) * step, 9)  # decimal grid values: the radius written is the one applied
    n0 = np.searchsorted(cs, grid, side="left")
    k0 = np.where(n0 > 0, ys[np.maximum(n0 - 1, 0)], 0.0)
    n, k = float(c.size), float(ys[-1])
    b = n0.astype(np.float64)
    ok = (b >= min_pairs) & (b <= n - min_pairs)
    with np.errstate(divide="ignore", invalid="ignore"):
        p0, p1 = k0 / b, (k - k0) / (n - b)
        lls = np.where(ok & (p0 < p1), _bernoulli_ll(k0, b) + _bernoulli_ll(k - k0, n - b), -np.inf)
    if not np.isfinite(lls).any():
        return None, info | {"reason": "too few pairs near a line of sight, or no drop of the detection rate behind a nearer landmark"}
    i = int(np.argmax(lls))
    rho, p0, p1 = float(grid[i]), float(p0[i]), float(p1[i])
    lr = 2.0 * (lls[i] - float(_bernoulli_ll(k, n)))
    info |= {"change_point_m": rho, "pd_hidden": round(p0, 4), "pd_beside": round(p1, 4), "pairs_hidden": int(n0[i]), "likelihood_ratio": round(float(lr), 2)}
    if p0 < p1 / 2 and lr > 13.8:
        return rho, info
    return None, info | {"reason": "no drop of the detection rate behind a nearer landmark"}


def _bernoulli_ll(k, n):
    """The maximised log-likelihood of k successes in n Bernoulli trials (elementwise; 0 where n is 0)."""
    from scipy.special import xlogy

    with np.errstate(divide="ignore", invalid="ignore"):
        p = np.where(n > 0, k / np.where(n > 0, n, 1.0), 0.0)
        return xlogy(k, p) + xlogy(n - k, 1.0 - p)


@dataclass
class DetectionCalibration:
    profile: DetectorProfile
    pairs: pd.DataFrame
    clutter: ClutterFit
    summary: dict
    members: list[DetectorProfile] = field(default_factory=list)
    labelled: list[Labelled] = field(default_factory=list)
    names: list[str] = field(default_factory=list)
    config: DetectionCalibConfig | None = None
    motion: dict | None = None  # the odometry's noise and biases (calib.odometry), when the logs allow it
    exchange: Exchangeability | None = None  # which sensors the pooled model does not describe (several sensors, on request)


def calibrate_detections(
    logs: list[SensorLog],
    cfg: DetectionCalibConfig,
    *,
    name: str,
    version: str,
    description: str = "",
    input_refs=None,
    command: str = "",
    per_sensor: bool = False,
    exchange: DriftConfig | None = None,
) -> DetectionCalibration:
    """A pooled profile of detection-level logs (one sensor each), and with ``per_sensor`` one profile per sensor.

    ``exchange`` (several sensors): which sensors the pooled model does not describe
    (:func:`exchangeability` with these drift settings), in the summary and in
    :attr:`DetectionCalibration.exchange`.

    Folds for the held-out model choices: the sensors when there are several
    (a model must transfer to a sensor it was not fitted to), else
    ``cfg.pd.folds`` contiguous time blocks.
    """
    if not logs:
        raise UsageError("no logs to calibrate")
    for lg in logs:
        _need(lg)
    names = sensor_names(logs)
    period = cfg.frame_period or frame_period(logs)
    remap, evidence = audit_identities(logs, cfg.gate, cfg.audit)
    truths = pd.concat([true_detections(lg, cfg.gate, remap) for lg in logs], ignore_index=True)
    tt = truths[truths["true"]]
    if len(tt) < 20:
        raise DataError("fewer than 20 true detections: cannot estimate the field of view")
    fov = cfg.fov or float(2 * np.quantile(np.abs(tt["bearing"]), cfg.quantile))
    rmax = cfg.range_max or float(np.quantile(tt["range"], cfg.quantile))
    parts = [label_epochs(lg, cfg.gate, period, fov, rmax, remap) for lg in logs]
    pairs = pd.concat([p.pairs.assign(log=k) for k, p in enumerate(parts)], ignore_index=True)
    occ_r, occ_info = occluder_radius(pairs["clearance"].to_numpy(), pairs["detected"].to_numpy(bool)) if cfg.occlusion else (None, {})
    if occ_r is not None:  # the P_D table is that of unoccluded landmarks: the pairs the radius hides leave the fit
        occ_info["pairs_removed"] = int((pairs["clearance"] < occ_r).sum())
        pairs = pairs[pairs["clearance"].to_numpy() >= occ_r].reset_index(drop=True)
    fas = pd.concat([p.false_alarms.assign(log=k) for k, p in enumerate(parts)], ignore_index=True)
    counts = np.concatenate([p.counts for p in parts])
    if len(logs) > 1:
        pd_fold, fa_fold, label = pairs["log"].to_numpy(), fas["log"].to_numpy(), f"sensors ({len(logs)})"
    else:
        n_ep = parts[0].counts.size
        blocks = time_folds(n_ep, cfg.pd.folds)
        pd_fold, fa_fold = blocks[pairs["epoch"].to_numpy()], blocks[fas["epoch"].to_numpy()]
        label = f"time blocks ({cfg.pd.folds})"
    table = choose_pd_model(pairs, pd_fold, label, fov, cfg.pd)
    clut = fit_clutter(counts, cfg.clutter.dispersion_level)
    density = None
    if cfg.clutter.use_density(len(logs)):
        re_ = np.linspace(0.0, rmax, cfg.clutter.range_bins + 1)
        be = np.linspace(-fov / 2, fov / 2, cfg.clutter.bearing_bins + 1)
        density = fit_density(fas["range"].to_numpy(), fas["bearing"].to_numpy(), fa_fold, re_, be, cfg.clutter, label)
    table = with_effective_counts(table, pairs, pairs["detected"].to_numpy(bool), landmark_clusters(pairs))
    sensor = SensorModel(kind="camera", fov=fov, range_max=rmax, mount=logs[0].sensor.mount if logs[0].sensor else SensorModel().mount)
    clutter = clutter_params(clut, "range_bearing", fov * rmax, density)
    spread = pooling = None
    member_rates: list[float] = []
    weights: list[float] = []
    if len(logs) > 1:
        cluster = pairs.groupby(["log", "landmark", "block"], sort=False).ngroup().to_numpy()
        pooling = pool_sensors(table, pairs, pairs["log"].to_numpy(), names, cluster)
        _, tau, weights, member_rates = shrink_rates([p.counts for p in parts])
        table = updated(table, {"between_sensor_sd": between_sensor_sd(table, pooling)})
        spread = dict(
            names=names,
            pairs=pooling.pairs,
            pd_observed=pooling.pd_observed,
            pd_predicted=pooling.pd_predicted,
            frames=[int(p.counts.size) for p in parts],
            clutter_rate=[float(p.counts.mean()) for p in parts],
            pd_logit_offset=pooling.offsets,
            pd_logit_sd=pooling.offset_sd,
            pd_concentration=pooling.concentration,
            pd_between_sd=pooling.between_sd,
            clutter_between_sd=tau,
        )
    params = {**cfg.model_dump(mode="json"), "frame_period": period, "identity_remap": {str(k): v for k, v in remap.items()}}
    prov = Provenance(inputs=input_refs or [], detcal_version=__version__, **build_stamp(), command=command, parameters=params, created=created_now())
    base = dict(
        version=version,
        description=description,
        detector=DetectorSpec(kind="external", association_gate=cfg.gate, occluder_radius=occ_r),
        sensor=sensor,
        noise=fit_noise(truths),
        provenance=prov,
    )
    profile = DetectorProfile(name=name, pd=table, clutter=clutter, sensors=SensorSpread(**spread) if spread else None, **base)
    members = []
    if per_sensor and pooling is not None:
        for k, lg in enumerate(logs):
            own = fit_clutter(parts[k].counts, cfg.clutter.dispersion_level)
            # the member's rate is w own + (1 - w) pooled: its standard error from both (taken as independent)
            se_own, se_pool = rate_standard_error(parts[k].counts), clutter.rate_se
            mine = pairs["log"].to_numpy() == k
            mc = updated(
                clutter,
                {
                    "rate": member_rates[k],
                    "frames": int(parts[k].counts.size),
                    "rate_se": None if se_own is None or se_pool is None else float(np.hypot(weights[k] * se_own, (1 - weights[k]) * se_pool)),
                    "kappa": None,
                    "chi2": own.chi2 if np.isfinite(own.chi2) else None,
                    "dof": own.dof if np.isfinite(own.chi2) else None,
                    "p_value": own.p_value if np.isfinite(own.chi2) else None,
                    "dispersion": own.dispersion if np.isfinite(own.dispersion) else None,
                    "dispersion_test": own.dispersion_test,
                    "nb_gof": None,
                }
            )
            sp = SensorSpread(**{**spread, "member": names[k], "clutter_weight": weights[k]})
            members.append(
                DetectorProfile(
                    name=f"{name}-{names[k]}", clutter=mc, sensors=sp,
                    pd=with_effective_counts(pooling.tables[k], pairs[mine], pairs["detected"].to_numpy(bool)[mine], landmark_clusters(pairs[mine])),
                    **{**base, "noise": fit_noise(parts[k].detections)},
                )
            )
    sel = table.selection
    summary = {
        "logs": [lg.name for lg in logs],
        "frame_period_s": period,
        "epochs": int(counts.size),
        "fov_deg": float(np.degrees(fov)),
        "range_max_m": rmax,
        "identity_remap": {k: v for k, v in evidence.items()} or "none",
        "true_detections": int(sum(int(p.detections["true"].sum()) for p in parts)),
        "false_detections": int(counts.sum()),
        "landmark_epoch_pairs": len(pairs),
        "pd_overall": float(pairs["detected"].mean()),
        "occluder_radius_m": occ_r,
        "occlusion": occ_info if cfg.occlusion else "not estimated (occlusion: false)",
        "pd_model": table.model if table.two_d else "range",
        "pd_model_loglik": {c: round(v, 6) for c, v in zip(sel.candidates, sel.loglik, strict=True)} if sel else "no choice (one fold)",
        "clutter_rate_per_epoch": clut.rate,
        "clutter_count_model": clut.count_model,
        "clutter_nb_size": clut.size,
        "clutter_poisson_p_value": clut.p_value,
        "clutter_dispersion": clut.dispersion,
        "clutter_dispersion_test_p_value": clut.dispersion_test.p_value if clut.dispersion_test else None,
        "clutter_density": density_summary(density),
    }
    if pooling is not None:
        summary.update(
            {
                "sensors": names,
                "pd_observed_per_sensor": [round(x, 4) for x in pooling.pd_observed],
                "pd_predicted_per_sensor": [round(x, 4) for x in pooling.pd_predicted],
                "pd_between_sensor_sd": pooling.between_sd,
                "pd_logit_offset_per_sensor": [round(x, 4) for x in pooling.offsets],
                "pd_logit_offset_sd": pooling.offset_sd,
                "pd_pooling_concentration": pooling.concentration,
                "pd_design_effect_per_sensor": [round(x, 2) for x in pooling.design_effects],
                "clutter_rate_per_sensor": [round(float(p.counts.mean()), 4) for p in parts],
                "clutter_between_sensor_sd": spread["clutter_between_sd"],
            }
        )
    motion = odometry_of(logs)
    if motion is not None:
        v = motion["velocity"]
        summary["odometry"] = {k: round(float(x), 4) for k, x in v.items()} | {"windows": motion["windows"]}
    ex = exchangeability(logs, cfg, exchange) if exchange is not None and len(logs) > 1 else None
    if ex is not None:
        summary["exchangeability"] = ex.summary()
    return DetectionCalibration(profile, pairs, clut, summary, members, parts, names, cfg, motion, ex)


def odometry_of(logs: list[SensorLog]) -> dict | None:
    """The velocity odometry's noise and biases against the logs' ground truth (calib.odometry), or None
    when a log has no velocity odometry or no ground-truth poses, or too little of both overlaps."""
    from calib.odometry import fit_velocity_odometry

    if not all(lg.odometry is not None and lg.odometry.kind == "velocity" and "ground_truth" in lg.reference for lg in logs):
        return None
    try:
        return fit_velocity_odometry(logs)
    except DataError:
        return None


def held_out_detections(profile: DetectorProfile, log: SensorLog, *, remap: dict[int, int], period: float) -> Held:
    """Label a detection-level log at its own frame period and score what the profile predicts for it."""
    fov, rmax = profile.sensor.fov, profile.sensor.range_max
    lab = label_epochs(log, profile.detector.association_gate, period, fov, rmax, remap)
    pairs = lab.pairs.assign(log=log.name)
    occ_r = profile.detector.occluder_radius
    if occ_r is not None:  # the profile's P_D is that of unoccluded landmarks; the radius says which are hidden
        pairs = pairs[pairs["clearance"].to_numpy() >= occ_r].reset_index(drop=True)
    pairs["predicted"] = predict(profile.pd, pairs)
    pairs["observed"] = pairs["detected"]
    fa = lab.false_alarms
    t = lab.detections[lab.detections["true"]]
    truth = pd.DataFrame(
        {
            "cluster": log.name + "/" + t["landmark_index"].astype(str).to_numpy(),
            "range_residual": t["range_residual"].to_numpy(np.float64),
            "bearing_residual": t["bearing_residual"].to_numpy(np.float64),
        }
    )
    return Held(
        log.name, pairs, lab.counts, fa["range"].to_numpy(np.float64), fa["bearing"].to_numpy(np.float64), period,
        extra={"true_detections_outside_fov": lab.outside}, truth=truth,
    )


def _own_period(profile: DetectorProfile, log: SensorLog) -> float:
    """A held-out log's own frame period, or the profile's when the log has too few frames to tell."""
    try:
        return frame_period([log])
    except DataError:
        period = float(profile.provenance.parameters.get("frame_period") or np.nan)
        if not np.isfinite(period):
            raise
        return period


def validate_detections(
    profile: DetectorProfile, logs: list[SensorLog], *, audit: IdentityAudit | None = None, drift: DriftConfig | None = None
) -> Validation:
    """Score a detection-level profile on held-out logs, each at its own frame period.

    The identity audit runs on the held-out logs themselves (it corrects the
    truth, not the detector); its findings are in the summary.
    """
    if PD_COVARIATES.get(profile.pd.covariate).from_measurement is None:
        raise UsageError(f"profile {profile.ref} has an {profile.pd.covariate} P_D table; a detection-level log needs a range or range_bearing table")
    if profile.sensor.fov is None or profile.sensor.range_max is None:
        raise DataError(f"profile {profile.ref}: the sensor has no fov or range_max")
    for lg in logs:
        _need(lg)
    remap, evidence = audit_identities(logs, profile.detector.association_gate, audit or IdentityAudit())
    held = [held_out_detections(profile, lg, remap=remap, period=_own_period(profile, lg)) for lg in logs]
    return score(profile, held, {"identity_remap": evidence or "none"}, drift=drift)


def _loo_rows(logs, left: list[int], cfg: DetectionCalibConfig, drift: DriftConfig, names: list[str], remap) -> list[RowDrift]:
    """The raw drift tests of each sensor in ``left`` against the pooled profile of the others in ``left``."""
    from calib.validate import drift_row

    rows = []
    for k in left:  # one calibration of the others per sensor: a handful
        others = calibrate_detections([logs[j] for j in left if j != k], cfg, name="loo", version="0.0.0")
        held = held_out_detections(others.profile, logs[k], remap=remap, period=_own_period(others.profile, logs[k]))
        rows.append(drift_row(others.profile, [held], names[k], k + 1, drift))
    return rows


def leave_one_out(logs: list[SensorLog], cfg: DetectionCalibConfig, drift: DriftConfig | None = None):
    """Each sensor's log against the pooled profile of all the others, one Holm family (a :class:`DriftReport`)."""
    from calib.drift import decide

    if len(logs) < 2:
        raise UsageError("leave one out needs logs of at least two sensors")
    drift = drift or DriftConfig()
    remap, _ = audit_identities(logs, cfg.gate, cfg.audit)
    return decide(_loo_rows(logs, list(range(len(logs))), cfg, drift, sensor_names(logs), remap), drift)


@dataclass
class Exchangeability:
    """Which sensors the pooled model describes (:func:`exchangeability`).

    rows: one per sensor, the drift tests that decided it (for a sensor set
    apart, those of the round that set it apart; a sensor left alone at the end
    has none); odd: the sensors set apart, in the order they were, and when no
    two sensors agree the last one too; steps: rounds of leave-one-out tests.
    """

    rows: list
    odd: list[str]
    steps: int
    round_of: dict[str, int] = field(default_factory=dict)  # the round whose tests decided each row (its Holm family)
    none_agree: bool = False  # set apart down to the last one

    def summary(self) -> dict:
        return {
            "not_exchangeable": ("all: no two sensors agree" if self.none_agree else self.odd) if self.odd else "none",
            "rounds": self.steps,
            "per_sensor": {r.name: f"{r.headline} (round {self.round_of.get(r.name)})" for r in self.rows},
        }


def exchangeability(logs: list[SensorLog], cfg: DetectionCalibConfig, drift: DriftConfig | None = None) -> Exchangeability:
    """Is each sensor exchangeable with the others? Each one's log against the pooled profile of all the others
    (leave one out: the profile knows nothing of the sensor it is tested on), every part of every sensor one
    Holm family (:mod:`calib.drift`). One odd sensor pulls every pooled profile it joins, so the others can
    look drifted too: the sensor with the strongest evidence (smallest adjusted p-value, then largest statistic) is set apart and the
    rest tested again without it, until no sensor left is drifted (or one is left). When the fleet is
    exchangeable, the first round names none with probability at least 1 - alpha.
    """
    from calib.drift import decide

    if len(logs) < 2:
        raise UsageError("exchangeability needs logs of at least two sensors")
    drift = drift or DriftConfig()
    names = sensor_names(logs)
    remap, _ = audit_identities(logs, cfg.gate, cfg.audit)
    left = list(range(len(logs)))
    decided: dict[int, RowDrift] = {}
    odd: list[str] = []
    round_of: dict[str, int] = {}
    steps = 0
    while len(left) >= 2:
        steps += 1
        rows = _loo_rows(logs, left, cfg, drift, names, remap)
        decide(rows, drift)
        # strongest evidence first: the smallest adjusted p-value, ties (at the bootstrap's floor) broken by the
        # largest standardised statistic
        bad = [
            (min(p.p_adjusted for p in r.parts.values()), -max(abs(p.statistic) for p in r.parts.values()), i)
            for i, r in enumerate(rows) if r.verdict == "drifted"
        ]
        if not bad:
            decided.update(dict(zip(left, rows, strict=True)))
            round_of.update({names[k]: steps for k in left})
            break
        i = min(bad)[2]
        decided[left[i]] = rows[i]
        round_of[names[left[i]]] = steps
        odd.append(names[left[i]])
        del left[i]
    none_agree = len(left) == 1 and bool(odd)
    if none_agree:  # no two sensors agree: the last one left is no reference, it needs its own profile too
        odd.append(names[left[0]])
    return Exchangeability([decided[k] for k in sorted(decided)], odd, steps, round_of, none_agree)


