"""Calibration throughput and ICP throughput (scans/s) on the default simulated park log.

Run: ``python benchmarks/bench_calibration.py``. Prints each stage's time so it
is clear where a calibration spends it.
"""

from __future__ import annotations

import os
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
os.environ.setdefault("DETCAL_CACHE", tempfile.mkdtemp(prefix="detcal-bench-"))

import numpy as np  # noqa: E402

from calib.calibrate import CalibrateConfig, calibrate, scan_sensor_poses  # noqa: E402
from detcal.default_log import default_log  # noqa: E402
from calib.icp import icp_ground_truth  # noqa: E402
from calib.label import label_log  # noqa: E402
from detcal.reports.calibration import write_report  # noqa: E402


def timed(fn):
    t = time.perf_counter()
    out = fn()
    return out, time.perf_counter() - t


def main() -> None:
    (log, path), t_sim = timed(default_log)
    n = len(log.scans)
    print(f"default park log: {n} scans x {log.scans.n_beams} beams (simulated and cached in {t_sim:.1f} s)")
    cfg = CalibrateConfig()
    sp, _ = scan_sensor_poses(log, "reference")
    lm = log.landmarks
    _, t_label = timed(lambda: label_log(log, sp, lm.ids, lm.xy, lm.radius, cfg.detector, gate=cfg.gate, k_sigma=cfg.k_sigma))
    cal, t_cal = timed(lambda: calibrate([log], cfg, name="bench", version="1.0.0"))
    with tempfile.TemporaryDirectory() as d:
        _, t_rep = timed(lambda: write_report(cal, Path(d)))
    print(f"labelling (detect + associate + n_p)   : {t_label:6.2f} s  {n / t_label:8.0f} scans/s")
    print(f"calibration (labelling + fits)          : {t_cal:6.2f} s  {n / t_cal:8.0f} scans/s")
    print(f"report figures                          : {t_rep:6.2f} s")
    res, t_icp = timed(lambda: icp_ground_truth(log))
    print(f"ICP ground truth (sequential+loops+graph): {t_icp:6.2f} s  {n / t_icp:8.0f} scans/s "
          f"({res.keyframes.size} keyframes, {len(res.loops)} loop closures)")
    ref = log.reference["ground_truth"]
    from calib.icp import rigid_align
    from detectors.geometry import interpolate_poses

    truth = interpolate_poses(ref.stamp, ref.poses, log.scans.stamp)
    ate = np.sqrt(np.mean(np.sum((rigid_align(res.poses, truth)[:, :2] - truth[:, :2]) ** 2, axis=1)))
    print(f"ICP ATE against the simulator's truth (rigid fit): {ate * 100:.1f} cm")


if __name__ == "__main__":
    main()
