"""``detcal calibrate``: measure a detector's P_D and clutter on logs with truth and write a profile.

Pipeline (Inostroza 2015, sec. 4.2, 5.3.3, ch. 6):

1. sensor poses per scan: the log's ground truth when it has one, otherwise
   ICP ground truth (:mod:`calib.icp`), composed with the sensor mount;
2. landmark truth: the log's own (simulator, UTIAS) or a user CSV;
3. labelling (:mod:`calib.label`): detect, associate within the gate, n_p;
4. fits (:mod:`calib.fits`): Hotelling ellipsoid of the true detections; every
   detection is then gated by it, as the runtime detector will be; P_D per n_p
   bin from the gated detections; clutter from the gated false alarms per scan
   (Poisson or negative binomial, with the tests) and where they fall (a
   density over range x bearing, chosen against the uniform one by held-out
   likelihood);
5. a profile (:mod:`profiles.profile`) with its provenance, and a run folder
   with the labelled tables, a summary and the report figures.
"""

from __future__ import annotations

import datetime as dt
import os
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from math import gamma as gamma_fn
from math import pi
from pathlib import Path
from typing import Literal

import numpy as np
import pandas as pd

from calib import __version__
from profiles.version import build_stamp
from calib.clutter import density_summary, fit_density, time_folds
from calib.drift import landmark_clusters, with_effective_counts
from calib.fits import (
    ClutterFit,
    HotellingFit,
    clutter_params,
    fit_clutter,
    fit_hotelling,
    fit_pd_table,
    maha2,
    roc_curves,
)
from calib.label import Labelled, label_log
from calib.landmarks import CloudLandmarkConfig
from calib.rangenoise import RangeNoise, RangeNoiseConfig, pool_range_noise, range_residuals
from calib.sufficiency import check_counts
from detectors.circle import descriptor_matrix
from detectors.geometry import compose, interpolate_poses
from detectors.sensor_log import SensorLog
from detectors.model import fov_volume
from profiles.errors import DataError, UsageError
from profiles.parameters import CalibrateConfig
from profiles.profile import DescriptorLikelihoods, DetectorProfile, DetectorSpec, HotellingModel, InputRef, Provenance
from profiles.schema import CircleDetectorParams, SensorModel

@dataclass
class Calibration:
    profile: DetectorProfile
    config: CalibrateConfig
    labelled: Labelled
    hotelling: HotellingFit
    roc: dict
    clutter: ClutterFit
    logs: list[SensorLog]
    poses: list[np.ndarray]  # sensor poses per scan, per log
    landmarks: list[tuple[np.ndarray, np.ndarray, np.ndarray]]
    gated: np.ndarray  # (D,) detection passes the Hotelling gate
    summary: dict = field(default_factory=dict)
    range_noise: RangeNoise | None = None  # when sigma_r was estimated from the scans
    ground_truth: list = field(default_factory=list)  # per log: calib.gtquality.QualityReport of ICP poses, None for reference poses
    data: object | None = None  # calib.checks.Verdict of calib.sufficiency on the counts


def created_now() -> str:
    """UTC now, or SOURCE_DATE_EPOCH when set (reproducible builds: same inputs, same bytes)."""
    epoch = os.environ.get("SOURCE_DATE_EPOCH")
    t = dt.datetime.fromtimestamp(int(epoch), dt.UTC) if epoch else dt.datetime.now(dt.UTC).replace(microsecond=0)
    return t.strftime("%Y-%m-%dT%H:%M:%SZ")


def pose_source(log: SensorLog, source: str) -> str:
    """Where the scan poses of ``log`` will come from: ``reference`` (its ground truth) or ``icp``."""
    use_ref = source in ("auto", "reference") and "ground_truth" in log.reference
    if source == "reference" and not use_ref:
        raise UsageError(f"log {log.name!r} has no ground-truth poses; use --poses icp")
    return "reference" if use_ref else "icp"


def scan_sensor_poses(log: SensorLog, source: str) -> tuple[np.ndarray, str]:
    """(S, 3) sensor poses in the world frame for every scan, and where they came from."""
    sp, src, _ = ground_truth_of(log, source)
    return sp, src


def ground_truth_of(log: SensorLog, source: str):
    """(sensor poses (S, 3) world frame, their source, the quality report of ICP poses or None for reference poses).

    ICP poses are assessed (:func:`calib.gtquality.assess`: fitness, loops, map consistency, and the error
    against the log's reference poses when it has them).
    """
    if pose_source(log, source) == "reference":
        ref = log.reference["ground_truth"]
        if log.scans.stamp[0] < ref.stamp[0] or log.scans.stamp[-1] > ref.stamp[-1]:
            raise DataError(f"log {log.name!r}: scans extend beyond the ground-truth poses")
        veh = interpolate_poses(ref.stamp, ref.poses, log.scans.stamp)
        src, quality = "reference", None
    else:
        from calib.gtquality import assess
        from calib.icp import icp_ground_truth
        from calib.progress import progress

        # ICP poses live in the frame of the first scan; a log with reference poses anchors
        # that frame at its first one so the log's landmark truth applies
        origin = None
        if "ground_truth" in log.reference:
            ref = log.reference["ground_truth"]
            origin = interpolate_poses(ref.stamp, ref.poses, log.scans.stamp[:1])[0]
        res = icp_ground_truth(log, origin=origin, progress=progress)  # bars on a terminal, quiet on workers
        veh, src = res.poses, "icp"
        quality = assess(log, veh, res.details)
    m = log.sensor.mount
    return compose(veh, np.array([m.x, m.y, m.theta])), src, quality


def landmark_source(landmarks_csv: Path | str | None) -> str:
    """``log`` (the log's own truth), ``cloud`` or ``csv`` (the file is one of the inputs)."""
    if landmarks_csv is None:
        return "log"
    return "cloud" if str(landmarks_csv) == "cloud" else "csv"


def range_sigma_source(logs: list[SensorLog], given: bool) -> str:
    """``option`` (--range-sigma), ``log`` (the log states it) or ``estimated`` (from the registered scans)."""
    if given:
        return "option"
    return "log" if all(lg.sensor is not None and lg.sensor.range_sigma is not None for lg in logs) else "estimated"


def parameters(
    logs: list[SensorLog], cfg: CalibrateConfig, landmarks_csv: Path | str | None, range_sigma_given: bool = False, accept_poor: bool = False
) -> dict:
    """The provenance parameters of a laser calibration: the config and every choice the data made.

    Known before the work (the request a rerun is compared by, see ``profiles.store.check_save``).
    ``accept_poor_ground_truth: true`` is recorded only when the quality gate was told to let a poor
    ground truth or thin data through (``--accept-poor-ground-truth``).
    """
    return {
        **cfg.model_dump(mode="json"),
        "pose_source": [pose_source(lg, cfg.poses) for lg in logs],
        "landmarks": landmark_source(landmarks_csv),
        "range_sigma_source": range_sigma_source(logs, range_sigma_given),
        **({"accept_poor_ground_truth": True} if accept_poor else {}),
    }


def with_range_sigma(log: SensorLog, sigma: float) -> SensorLog:
    """``log`` with its sensor's sigma_r set (validated)."""
    import dataclasses

    return dataclasses.replace(log, sensor=type(log.sensor).model_validate({**log.sensor.model_dump(), "range_sigma": sigma}))


def check_landmark_source(logs: list[SensorLog], landmarks_csv: Path | str | None) -> None:
    """Refuse, before any registration, logs whose landmark truth is nowhere: no landmarks of their own and
    neither a CSV nor ``cloud`` (the mistake used to be reported after the whole ICP)."""
    if landmarks_csv is not None:
        return
    for lg in logs:
        if lg.landmarks is None:
            raise UsageError(f"log {lg.name!r} has no landmark truth; pass --landmarks FILE.csv (id, x, y, radius) or --landmarks cloud")
        if np.isnan(lg.landmarks.radius).any():
            raise DataError(f"log {lg.name!r}: landmark radii are unknown; the n_p ray tracer needs them (--landmarks)")


def log_landmarks(
    log: SensorLog,
    landmarks_csv: Path | str | None,
    sensor_poses: np.ndarray | None = None,
    params: CircleDetectorParams | None = None,
    cloud: CloudLandmarkConfig | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(ids (L,), xy (L, 2), radius (L,)) from a CSV (columns id, x, y, radius), the log, or
    ``"cloud"``: circles that recur in the registered scans (:mod:`calib.landmarks`)."""
    if landmarks_csv is not None and str(landmarks_csv) == "cloud":
        from calib.landmarks import landmarks_from_cloud

        if sensor_poses is None:
            raise UsageError("landmarks from the cloud need the scan poses")
        return landmarks_from_cloud(log, sensor_poses, params or CircleDetectorParams(), cloud)
    if landmarks_csv is not None:
        return read_landmarks_csv(Path(landmarks_csv))
    if log.landmarks is None:
        raise UsageError(f"log {log.name!r} has no landmark truth; pass --landmarks FILE.csv (id, x, y, radius) or --landmarks cloud")
    lm = log.landmarks
    if np.isnan(lm.radius).any():
        raise DataError(f"log {log.name!r}: landmark radii are unknown; the n_p ray tracer needs them (--landmarks)")
    return lm.ids, lm.xy, lm.radius


def read_landmarks_csv(path: Path) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(ids (L,), xy (L, 2), radius (L,)) from a CSV with columns id, x, y, radius (world frame, metres)."""
    try:
        t = pd.read_csv(path)
    except (OSError, ValueError) as exc:
        raise DataError(f"{path}: cannot read landmarks ({' '.join(str(exc).split())})") from None
    missing = {"id", "x", "y", "radius"} - set(t.columns)
    if missing:
        raise DataError(f"{path}: missing columns {sorted(missing)} (need id, x, y, radius)")
    if len(t) == 0:
        raise DataError(f"{path}: holds no landmarks (a header line only)")
    num = t[["id", "x", "y", "radius"]].apply(pd.to_numeric, errors="coerce")
    bad = (
        ~np.isfinite(num.to_numpy(np.float64)).all(axis=1)
        | (num["radius"] <= 0).to_numpy()
        | (num["id"] % 1 != 0).to_numpy()
        | (num["id"].abs() > 2**53).to_numpy()  # past this a float id is not one integer
    )
    if bad.any():
        raise DataError(f"{path}:{int(np.flatnonzero(bad)[0]) + 2}: id must be an integer, x, y numbers and radius > 0 (ids up to 2^53)")
    ids = num["id"].to_numpy(np.int64)
    if np.unique(ids).size != ids.size:
        raise DataError(f"{path}: landmark ids are not unique")
    return ids, num[["x", "y"]].to_numpy(np.float64), num["radius"].to_numpy(np.float64)


def _check_same_sensor(logs: list[SensorLog]) -> SensorModel:
    s0 = logs[0].sensor
    for lg in logs[1:]:
        if lg.sensor.layouts() != s0.layouts():
            raise UsageError(f"logs {logs[0].name!r} and {lg.name!r} have different beam geometries; calibrate them separately")
    return s0


def _log_digest(log: SensorLog) -> list[InputRef]:
    src = log.source
    if "sha256" in src:
        return [InputRef(name=str(src.get("file", log.name)), sha256=str(src["sha256"]))]
    files = src.get("files")
    if isinstance(files, dict):
        return [InputRef(name=str(k), sha256=str(v)) for k, v in files.items()]
    return []


PerLog = Callable[[Callable, list[tuple]], list]


def _in_turn(fn: Callable, args: list[tuple]) -> list:
    return [fn(*a) for a in args]


def place_log(log: SensorLog, poses: str, noise: RangeNoiseConfig | None = None) -> tuple:
    """Per-log step 1: (sensor poses (S, 3) world frame, their source, range residuals for sigma_r or None,
    the ground truth's quality report or None)."""
    sp, src, quality = ground_truth_of(log, poses)
    return sp, src, (range_residuals(log, sp, noise) if noise is not None else None), quality


def label_placed(
    log: SensorLog, sensor_poses: np.ndarray, cfg: CalibrateConfig, landmarks_csv: Path | str | None, range_sigma: float | None = None
) -> tuple[tuple[np.ndarray, np.ndarray, np.ndarray], Labelled]:
    """Per-log step 2: the landmarks ((ids, xy, radius)) and the labelled tables; ``range_sigma`` replaces the log's sigma_r."""
    if range_sigma is not None:
        log = with_range_sigma(log, range_sigma)
    ids, xy, r = log_landmarks(log, landmarks_csv, sensor_poses, cfg.detector, cfg.cloud_landmarks)
    return (ids, xy, r), label_log(log, sensor_poses, ids, xy, r, cfg.detector, gate=cfg.gate, k_sigma=cfg.k_sigma)


def place_and_label(log: SensorLog, cfg: CalibrateConfig, landmarks_csv: Path | str | None) -> tuple:
    """Both per-log steps in one (when sigma_r is known and nothing is pooled between them):
    (poses, source, quality report or None, landmarks, labelled)."""
    sp, src, _, quality = place_log(log, cfg.poses)
    return (sp, src, quality, *label_placed(log, sp, cfg, landmarks_csv))


def calibrate(
    logs: list[SensorLog],
    cfg: CalibrateConfig,
    *,
    name: str,
    version: str,
    description: str = "",
    landmarks_csv: Path | None = None,
    input_refs: list[InputRef] | None = None,
    command: str = "",
    range_sigma_given: bool = False,
    per_log: PerLog | None = None,
    quality_gate: Literal["off", "refuse", "accept"] = "off",
) -> Calibration:
    """Calibrate the circle detector on laser logs with truth (steps in the module docstring).

    quality_gate: what a poor ground truth (:mod:`calib.gtquality`, ICP poses only) or data too thin for
    the fits (:mod:`calib.sufficiency`) do. ``refuse``: a ``DataError`` naming the log, the failed figure
    and its threshold, raised as soon as it is known (the ground truth before labelling when sigma_r is
    estimated, after it otherwise; the counts after the fits), so no profile is made; ``accept``: the
    calibration goes on, the failures are listed in the summary (``accepted_poor``) and the profile's
    parameters record ``accept_poor_ground_truth: true``; ``off``: verdicts in the summary only.

    sigma_r: the logs' own (or ``--range-sigma``, set on the logs by the reader,
    ``range_sigma_given``); when they state none it is estimated from the
    registered scans (:mod:`calib.rangenoise`).

    per_log: how the per-log steps (poses, range residuals, landmarks and
    labelling) run, ``per_log(fn, [(log, *args), ...]) -> [fn(log, *args), ...]``
    in the order of the logs; default: one after the other in this process.
    :mod:`detcal.engine` runs them on Dask workers, each reading its log where it
    lives. The fits always run here, on the gathered tables, so the result does
    not depend on where or in which order the logs were done.
    """
    if not logs:
        raise UsageError("no logs to calibrate")
    for lg in logs:
        if lg.scans is None or lg.sensor is None:
            raise UsageError(f"log {lg.name!r} has no laser scans; calibrate detection-level logs apart from laser logs")
    sensor = _check_same_sensor(logs)
    if sensor.range_max is None:
        raise DataError("the sensor model has no range_max")
    check_landmark_source(logs, landmarks_csv)
    params = parameters(logs, cfg, landmarks_csv, range_sigma_given, accept_poor=quality_gate == "accept")
    each = per_log or _in_turn
    noise = None
    accepted: list[str] = []
    if params["range_sigma_source"] == "estimated":
        # sigma_r pools every log's residuals, and labelling needs it: two rounds over the logs
        placed = each(place_log, [(lg, cfg.poses, cfg.range_noise) for lg in logs])
        accepted += _gate([(lg.name, q.verdict) for lg, (_, _, _, q) in zip(logs, placed, strict=True) if q is not None], quality_gate)
        noise = pool_range_noise([part for _, _, part, _ in placed], cfg.range_noise)
        labelled = each(label_placed, [(lg, sp, cfg, landmarks_csv, noise.range_sigma) for lg, (sp, _, _, _) in zip(logs, placed, strict=True)])
        done = [(sp, src, q, *lab) for (sp, src, _, q), lab in zip(placed, labelled, strict=True)]
        logs = [with_range_sigma(lg, noise.range_sigma) for lg in logs]
        sensor = logs[0].sensor
    else:
        done = each(place_and_label, [(lg, cfg, landmarks_csv) for lg in logs])
        accepted += _gate([(lg.name, d[2].verdict) for lg, d in zip(logs, done, strict=True) if d[2] is not None], quality_gate)
    qualities = [d[2] for d in done]
    det_tables, pair_tables, poses, lms, sources = [], [], [], [], []
    offset = 0
    for k, (sp, src, _, lm, lab) in enumerate(done):
        d = lab.detections.assign(log=k)
        p = lab.pairs.assign(log=k)
        p["det"] = np.where(p["det"] >= 0, p["det"] + offset, -1)
        offset += len(d)
        det_tables.append(d)
        pair_tables.append(p)
        poses.append(sp)
        lms.append(lm)
        sources.append(src)
    dets = pd.concat(det_tables, ignore_index=True)
    pairs = pd.concat(pair_tables, ignore_index=True)
    names = tuple(cfg.descriptors)
    desc = descriptor_matrix(dets["fit_error"], dets["radius"], dets["convexity"], dets["points"], names)
    true = dets["landmark"].to_numpy() >= 0
    finite = np.isfinite(desc).all(axis=1)
    hot = fit_hotelling(desc[true & finite], names, cfg.confidence)
    m2 = maha2(desc, hot.mean, hot.cov)  # inf where a descriptor is not finite
    if cfg.gamma == "empirical":
        hot = replace(hot, gamma=float(np.quantile(m2[true & finite], cfg.confidence, method="higher")))
    dets["maha2"] = m2
    gated = m2 <= hot.gamma
    dets["gated"] = gated
    rc = roc_curves(desc[true & finite], desc[~true & finite], hot)
    # P_D from the gated detector (what the filter will see), eq. 6.2
    det_idx = pairs["det"].to_numpy()
    detected = (det_idx >= 0) & gated[np.maximum(det_idx, 0)]
    pairs["detected"] = detected
    pd_table = fit_pd_table(pairs["n_p"].to_numpy(), detected, "n_p", cfg.pd)
    pd_table = with_effective_counts(pd_table, pairs, detected, landmark_clusters(pairs))
    # clutter: gated false alarms per scan, over every scan of every log (scans with none count)
    fa = dets[gated & ~true]
    counts = np.concatenate(
        [np.bincount(fa.loc[fa["log"] == k, "scan"].to_numpy(np.int64), minlength=len(lg.scans)) for k, lg in enumerate(logs)]
    )
    clut = fit_clutter(counts, cfg.clutter.dispersion_level)
    volume = fov_volume(sensor, cfg.clutter_space)
    density = _clutter_density(fa, logs, sensor, cfg)
    d = len(names)
    ell_vol = pi ** (d / 2) / gamma_fn(d / 2 + 1) * hot.gamma ** (d / 2) * float(np.sqrt(np.linalg.det(hot.cov)))
    seeds = {lg.source.get("seed") for lg in logs if lg.source.get("seed") is not None}
    profile = DetectorProfile(
        name=name,
        version=version,
        description=description,
        detector=DetectorSpec(
            kind="circle2d", circle=cfg.detector, k_sigma=cfg.k_sigma, buffer_samples=cfg.buffer_samples, association_gate=cfg.gate
        ),
        sensor=sensor,
        hotelling=HotellingModel(
            names=list(names),
            mean=hot.mean.tolist(),
            covariance=hot.cov.tolist(),
            confidence=cfg.confidence,
            gamma=hot.gamma,
            auc_hotelling=rc["auc_hotelling"],
            auc_fisher=rc["auc_fisher"] if np.isfinite(rc["auc_fisher"]) else None,
            samples=hot.samples,
            gamma_method=cfg.gamma,
            coverage=float(gated[true].mean()) if true.any() else None,
        ),
        pd=pd_table,
        clutter=clutter_params(clut, cfg.clutter_space, volume, density),
        descriptor_likelihoods=DescriptorLikelihoods(gaussian_mass=cfg.confidence, ellipsoid_volume=ell_vol),
        provenance=Provenance(
            inputs=input_refs if input_refs is not None else [r for lg in logs for r in _log_digest(lg)],
            detcal_version=__version__,
            **build_stamp(),
            command=command,
            parameters=params,
            created=created_now(),
            seed=seeds.pop() if len(seeds) == 1 else None,
        ),
    )
    summary = _summary(logs, sources, lms, sensor, params, dets, true, gated, fa, pairs, rc, clut, density, hot, cfg)
    if noise is not None:
        summary["range_noise"] = noise.summary()
    if any(q is not None for q in qualities):
        summary["ground_truth"] = {lg.name: _verdict_line(q.verdict) for lg, q in zip(logs, qualities, strict=True) if q is not None}
    data = check_counts(summary["landmarks"], summary["true_detections"], pd_table.counts, pd_table.detections, cfg.pd.min_count)
    summary["data_sufficiency"] = _verdict_line(data)
    accepted += _gate([(", ".join(lg.name for lg in logs), data)], quality_gate)
    if accepted:
        summary["accepted_poor"] = accepted
    return Calibration(profile, cfg, Labelled(dets, pairs), hot, rc, clut, logs, poses, lms, gated, summary, noise, qualities, data)


def _clutter_density(fa: pd.DataFrame, logs: list[SensorLog], sensor: SensorModel, cfg: CalibrateConfig):
    """The false alarms' density over range x bearing, chosen against the uniform one by held-out likelihood (folds:
    the sensors, or time blocks of one log); None when the config or the clutter space leaves it out."""
    if not (cfg.clutter.use_density(len(logs)) and cfg.clutter_space == "range_bearing"):
        return None
    lo = min(sensor.angle_min, sensor.angle_min + sensor.angle_increment * (sensor.n_beams - 1))
    re_ = np.linspace(sensor.range_min, sensor.range_max, cfg.clutter.range_bins + 1)
    be = np.linspace(lo, lo + sensor.field_of_view, cfg.clutter.bearing_bins + 1)
    if len(logs) > 1:
        fold, label = fa["log"].to_numpy(), f"sensors ({len(logs)})"
    else:
        fold, label = time_folds(len(logs[0].scans), cfg.clutter.folds)[fa["scan"].to_numpy(np.int64)], f"time blocks ({cfg.clutter.folds})"
    return fit_density(fa["range"].to_numpy(), fa["bearing"].to_numpy(), fold, re_, be, cfg.clutter, label)


def _summary(logs, sources, lms, sensor, params, dets, true, gated, fa, pairs, rc, clut, density, hot, cfg) -> dict:
    """What a laser calibration reports (summary.yaml)."""
    n_true = int(true.sum())
    return {
        "logs": [lg.name for lg in logs],
        "scans": int(sum(len(lg.scans) for lg in logs)),
        "pose_source": sources,
        "landmarks": int(sum(len(ids) for ids, _, _ in lms)),
        "range_sigma_m": float(sensor.range_sigma),
        "range_sigma_source": params["range_sigma_source"],
        "detections": len(dets),
        "true_detections": n_true,
        "true_inside_ellipsoid": float(gated[true].mean()) if n_true else float("nan"),
        "false_detections_before_gate": int((~true).sum()),
        "false_alarms_after_gate": int(len(fa)),
        "landmark_scan_pairs": len(pairs),
        "auc_hotelling": rc["auc_hotelling"],
        "auc_fisher": rc["auc_fisher"],
        "clutter_rate": clut.rate,
        "clutter_chi2": clut.chi2,
        "clutter_dof": clut.dof,
        "clutter_p_value": clut.p_value,
        "clutter_dispersion": clut.dispersion,
        "clutter_poisson_rejected_at_0.05": bool(np.isfinite(clut.p_value) and clut.p_value < 0.05),
        "clutter_count_model": clut.count_model,
        "clutter_nb_size": clut.size,
        "clutter_dispersion_test_p_value": clut.dispersion_test.p_value if clut.dispersion_test else None,
        "clutter_density": density_summary(density),
        "hotelling_gamma": hot.gamma,
        "hotelling_gamma_method": cfg.gamma,
    }


def _verdict_line(v) -> str:
    """'passes: <every figure and its threshold>' or 'fails: <the failed ones>' (calib.checks.Check.describe)."""
    return ("passes: " if v.passed else "fails: ") + "; ".join(c.describe() for c in (v.checks if v.passed else v.failures))


def _gate(verdicts: list[tuple[str, object]], policy: str) -> list[str]:
    """The failed verdicts' one-line messages; under ``refuse`` the first one is raised (a ``DataError``)."""
    failed = [v.message(subject) for subject, v in verdicts if not v.passed]
    if failed and policy == "refuse":
        raise DataError(f"{failed[0]}; no profile written (--accept-poor-ground-truth writes it anyway and records that it did)")
    return failed if policy == "accept" else []
