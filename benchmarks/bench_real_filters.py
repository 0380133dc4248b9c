"""RB-PHD, LMB and delta-GLMB side by side on real logs: UTIAS MRCLAM dataset 1 (robots 1-5) and Victoria Park.

Run: ``python benchmarks/bench_real_filters.py [--data ../shared/data] [--filters rbphd,lmb,glmb] [--seeds 0-2]
[--robots 1-5] [--skip utias|vp] [--survival 0.95] [--set filter.noise_inflation=2 ...] [--vp-profiles own|shared]
[--oracle]``; ``--filters ''`` runs none (with ``--oracle``: the floor alone). About 30 s per UTIAS run and 1.5-2 minutes per Victoria Park run on one core.

* UTIAS: robot K is held out. Its camera profile is calibrated here on the other four robots (``calibrate_detections`` with
  the default settings, as ``detcal calibrate dataset1 --robot ... --name utias-notK``), and its settings are
  ``benchmarks/configs/utias_mrclam/robotK.yaml`` (unicycle noise and biases measured on the other four robots'
  ground truth, 20 particles, the optimal proposal). The filters read the barcodes' identities
  (``detection.identities: auto``); ``--set detection.identities=off`` runs them without. Scored against Vicon: trajectory RMSE, map OSPA (c = 1 m, p = 1)
  against the 15 surveyed landmarks, the map's features, the landmarks with a feature within 0.3 m (GOSPA, c = 0.3 m)
  and how far the RMSE lies below dead reckoning; then the RMSE and the landmarks within 0.3 m after the best rigid
  fit of the path onto Vicon (the map moved with it; ``slam_runtime.run.evaluate``), and the fit's angle. With
  ``--oracle`` each robot's floor first: the full-SLAM mode with the barcodes as the associations
  (``slam_runtime.oracle.log_oracle``), smoothed and forward only.
* Victoria Park: ``benchmarks/configs/victoria_park.yaml`` (10 particles, optimal proposal) and, per filter, the
  profile self-calibrated with that filter's own map, the measurements of several runs averaged
  (``benchmarks.common.VP_PROFILES``); with
  ``--vp-profiles shared`` every filter takes RB-PHD's. Scored against GPS after a rigid fit
  (there is no landmark truth), at the laser's position, the point the data set's GPS locates (``calib.io.victoria``).

The labelled filters take their default settings (``slam_runtime.labelled.LabelledSettings``, those of the
glmb-paper scenario): only the filter kind changes (``slam_runtime.config.with_filter``), and with
``--survival`` their P_S in the field of view (the paper's 0.95; 1 by default); ``--set key=value``
overrides any setting of every filter run (values parsed as YAML). Each row also prints the runs' log
marginal likelihood of the measurements (``slam_runtime.run.LogEvidence``, in nats, mean over the seeds):
settings of one filter on one log compare by it without ground truth. Every figure is one process on one
core (BLAS pinned to one thread); the load average is printed with each row.
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import time
from pathlib import Path

for _v in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_v, "1")

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from benchmarks.common import SHARED_DATA, VP_PROFILES, ints, parse_set  # noqa: E402


def load() -> str:
    return "/".join(f"{x:.1f}" for x in os.getloadavg())


def run(log, profile, cfg, seed: int) -> dict:
    from slam_runtime.run import LogEvidence, evaluate, run_slam

    t0 = time.perf_counter()
    res = run_slam(log, profile, cfg, seed, hooks=(LogEvidence(),))
    m = evaluate(log, res, cfg=cfg)
    m["wall_s"] = time.perf_counter() - t0
    m["log_evidence"] = float(res.per_step["log_evidence"][-1])
    m.setdefault("map_features", int(res.map_xy.shape[0]))  # evaluate counts them only against landmark truth
    return m


def row(label: str, ms: list[dict], key: str, extra: str = "") -> None:
    rmse = [m[key] for m in ms]
    print(
        f"  {label:<22} RMSE {' / '.join(f'{x:.2f}' for x in rmse)} m (mean {statistics.mean(rmse):.2f}){extra}"
        f"  ms/step wall {statistics.mean(m['ms_per_step_mean'] for m in ms):.1f}, CPU {statistics.mean(m['cpu_ms_per_step_mean'] for m in ms):.1f}"
        f"  log evidence {' / '.join(format(m['log_evidence'], '.0f') for m in ms)}"
        f"  (load {load()})",
        flush=True,
    )


SETS: dict = {}  # --set overrides, applied to every run


def labelled(cfg, kind: str, survival: float | None):
    """``cfg`` with the filter ``kind``; the labelled filters' survival in view set when given; the ``--set`` overrides."""
    from slam_runtime.config import with_filter, with_settings

    cfg = with_filter(cfg, kind)
    cfg = with_settings(cfg, {"filter.survival": survival}) if survival is not None and kind in ("lmb", "glmb") else cfg
    return with_settings(cfg, SETS) if SETS else cfg


def oracle_row(log, others, prof, cfg) -> None:
    """The floor: the full-SLAM mode with the barcodes as the associations (``slam_runtime.oracle.log_oracle``), the
    robot's own motion model (its config's) and the profile's measurement noise; identities re-attributed as the
    other robots' identity audit says; scored as the filters are."""
    import numpy as np

    from calib.detlevel import DetectionCalibConfig, audit_identities, identities
    from detectors.geometry import interpolate_poses
    from detectors.sensor_log import wrap_angle
    from slam_runtime.metrics import trajectory_rmse
    from slam_runtime.oracle import as_slam_result, log_oracle
    from slam_runtime.run import build, evaluate

    t0 = time.process_time()
    dc = DetectionCalibConfig()
    ident = identities(log, audit_identities(others, dc.gate, dc.audit)[0])
    labels = np.where(np.isin(ident, log.landmarks.ids), ident, -1)  # other robots and unknown barcodes: no landmark
    b = build(log, prof, cfg)
    sr, sb = np.sqrt(np.diag(b.mapfilter.feature.r))[:2]
    res = log_oracle(log, b.vehicle, labels, range_sigma=float(sr), bearing_sigma=float(sb))
    m = evaluate(log, as_slam_result(res), cfg=cfg)
    ref = log.reference["ground_truth"]
    truth = interpolate_poses(ref.stamp, ref.poses, res.forward_stamps)
    fwd_rmse = trajectory_rmse(res.forward_poses, truth)
    fwd_heading = float(np.degrees(np.abs(wrap_angle(res.forward_poses[:, 2] - truth[:, 2])).max()))
    print(
        f"  {'oracle (barcodes)':<22} RMSE {m['trajectory_rmse_vs_ground_truth_m']:.2f} m, odometry {m['odometry_rmse_vs_ground_truth_m']:.2f};"
        f" OSPA {m['map_ospa']:.3f}, landmarks {int(res.detected.sum())} (within 0.3 m: {m['landmarks_within_03_m']});"
        f" RMSE below odometry {100 * (1 - m['trajectory_rmse_vs_ground_truth_m'] / m['odometry_rmse_vs_ground_truth_m']):.0f} %;"
        f" after the path's rigid fit: RMSE {m['trajectory_rmse_vs_ground_truth_path_aligned_m']:.2f} m (turned {m['path_alignment_deg']:.1f} deg),"
        f" within 0.3 m {m['landmarks_within_03_m_path_aligned']}; forward only (the mode given the data so far, every 30 s):"
        f" RMSE {fwd_rmse:.2f} m, heading error at most {fwd_heading:.1f} deg; Huber-downweighted {100 * res.downweighted:.1f} %,"
        f" converged {res.converged}  CPU {time.process_time() - t0:.0f} s  (load {load()})",
        flush=True,
    )


def utias(root: Path, robots: list[int], filters: list[str], seeds: list[int], survival: float | None, oracle: bool = False) -> None:
    from calib.config import load_yaml_model
    from calib.detlevel import DetectionCalibConfig, calibrate_detections
    from calib.io.utias import read_utias
    from slam_runtime.config import SlamConfig, with_settings

    logs = {r: read_utias(root, robot=r) for r in range(1, 6)}
    print(f"\nUTIAS dataset 1, leave one robot out; seeds {seeds}; map OSPA c = 1 m, p = 1 against 15 landmarks")
    for k in robots:
        t0 = time.perf_counter()
        others = [logs[r] for r in range(1, 6) if r != k]
        prof = calibrate_detections(others, DetectionCalibConfig(), name=f"utias-not{k}", version="1.0.0").profile
        base = load_yaml_model(SlamConfig, ROOT / f"benchmarks/configs/utias_mrclam/robot{k}.yaml")
        print(f"robot {k} (profile calibrated on the other four in {time.perf_counter() - t0:.0f} s)")
        key, odo = "trajectory_rmse_vs_ground_truth_m", "odometry_rmse_vs_ground_truth_m"
        if oracle:
            oracle_row(logs[k], others, prof, with_settings(base, SETS) if SETS else base)
        for f in filters:
            cfg = labelled(base, f, survival)
            ms = [run(logs[k], prof, cfg, s) for s in seeds]
            extra = (
                f", odometry {ms[0]['odometry_rmse_vs_ground_truth_m']:.2f}; OSPA {statistics.mean(m['map_ospa'] for m in ms):.3f}"
                f", features {statistics.mean(m['map_features'] for m in ms):.0f}, landmarks mapped {statistics.mean(m['landmarks_mapped'] for m in ms):.1f}"
                f" (within 0.3 m: {' / '.join(str(m['landmarks_within_03_m']) for m in ms)})"
                f"; RMSE below odometry {' / '.join(f'{100 * (1 - m[key] / m[odo]):.0f}' for m in ms)} %"
                f"; after the path's rigid fit: RMSE {' / '.join(format(m['trajectory_rmse_vs_ground_truth_path_aligned_m'], '.2f') for m in ms)} m"
                f" (turned {' / '.join(format(m['path_alignment_deg'], '.1f') for m in ms)} deg), within 0.3 m"
                f" {' / '.join(str(m['landmarks_within_03_m_path_aligned']) for m in ms)}"
            )
            row(f, ms, "trajectory_rmse_vs_ground_truth_m", extra)


def victoria(root: Path, filters: list[str], seeds: list[int], survival: float | None, profiles: str = "own") -> None:
    from calib.config import load_yaml_model
    from calib.io.registry import read_log
    from profiles.store import load_profile_file
    from slam_runtime.config import SlamConfig

    log = read_log(root)
    base = load_yaml_model(SlamConfig, ROOT / "benchmarks/configs/victoria_park.yaml")
    print(f"\nVictoria Park, full run ({len(list(log.frames()))} frames), 10 particles; seeds {seeds}; RMSE vs GPS at the laser after a rigid fit")
    for f in filters:
        path = VP_PROFILES[f if profiles == "own" else "rbphd"]
        name = path.name
        prof = load_profile_file(path)
        ms = [run(log, prof, labelled(base, f, survival), s) for s in seeds]
        row(f, ms, "trajectory_rmse_vs_gps_m", f", odometry {ms[0]['odometry_rmse_vs_gps_m']:.1f}; features {statistics.mean(m['map_features'] for m in ms):.0f}; profile {name}")


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--data", type=Path, default=SHARED_DATA, help="folder holding utias_mrclam/ and victoria_park/")
    ap.add_argument("--filters", default="rbphd,lmb,glmb")
    ap.add_argument("--seeds", default="0-2", help="filter seeds: 0-2, or 0,3")
    ap.add_argument("--robots", default="1-5", help="UTIAS robots held out in turn")
    ap.add_argument("--skip", choices=("utias", "vp"), action="append", default=[])
    ap.add_argument("--survival", type=float, default=None, help="LMB and delta-GLMB: P_S in view (default theirs, 1; the paper: 0.95)")
    ap.add_argument("--oracle", action="store_true", help="UTIAS: also the full-SLAM mode with the barcodes as associations (the floor)")
    ap.add_argument("--set", dest="sets", action="append", default=[], help="override a setting of every run: key=value (repeatable)")
    ap.add_argument(
        "--vp-profiles", choices=("own", "shared"), default="own",
        help="Victoria Park: each filter with the profile self-calibrated with its own map (own), or every filter with RB-PHD's (shared)",
    )
    a = ap.parse_args()
    SETS.update(parse_set(x) for x in a.sets)
    os.environ.setdefault("SOURCE_DATE_EPOCH", "1700000000")
    filters = [f for f in a.filters.split(",") if f]
    seeds = ints(a.seeds)
    print(f"CPUs {os.cpu_count()}, load average {load()}" + (f"; settings {SETS}" if SETS else ""))
    ut, vp = a.data / "utias_mrclam/dataset1", a.data / "victoria_park"
    if "utias" not in a.skip:
        if ut.is_dir():
            utias(ut, ints(a.robots), filters, seeds, a.survival, a.oracle)
        else:
            print(f"UTIAS dataset 1 not found at {ut}: skipped")
    if "vp" not in a.skip:
        if vp.is_dir():
            victoria(vp, filters, seeds, a.survival, a.vp_profiles)
        else:
            print(f"Victoria Park not found at {vp}: skipped")


if __name__ == "__main__":
    main()
