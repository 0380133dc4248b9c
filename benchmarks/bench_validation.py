"""Held-out figures of detcal's profiles: the numbers in the README's validation section.

Run: ``python benchmarks/bench_validation.py [--utias DIR] [--radish DIR] [--parks N] [--skip-sim]``.

* UTIAS MRCLAM dataset 1 (camera, 5 robots; skipped when the folder is absent):
  leave one robot out (pooled profile), the same with 300 s of the held-out
  robot for its own partially pooled profile, and the time split (first half /
  second half, pooled and per-robot profiles);
* the indoor laser logs of Radish (ACES, Intel; skipped when absent): the time
  split of each log (``--cv time --landmarks cloud``: calibrate on one half,
  validate on the other, both ways), the landmarks taken from each half's own
  registered cloud;
* the simulator: N default parks (seeds 1..N); each park calibrates a profile
  that is validated on the other N - 1 (false alarms per park and pooled over
  them, P_D reliability, Hotelling coverage), with the thesis's chi-square gamma
  and with the empirical one.

Prints tables; takes about 5 minutes on two cores (most of it ray tracing the
held-out parks), and 5 more with the Radish logs.
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
os.environ.setdefault("DETCAL_CACHE", tempfile.mkdtemp(prefix="detcal-bench-"))

import pandas as pd  # noqa: E402

from calib.calibrate import CalibrateConfig, calibrate  # noqa: E402
from calib.crossval import cross_validate  # noqa: E402
from calib.validate import validate  # noqa: E402

pd.set_option("display.width", 200)
pd.set_option("display.max_columns", 20)
COLS = ["fold", "test", "profile", "ece", "ece_if_calibrated_blocks", "brier", "loglik_per_pair", "false_alarm_relative_error",
        "false_alarm_relative_error_ci95_low", "false_alarm_relative_error_ci95_high", "verdict", "pd_p_value", "clutter_p_value",
        "noise_p_value", "coverage_p_value"]


def utias(root: Path) -> None:
    from calib.io.utias import read_utias

    logs = [read_utias(root, robot=r) for r in range(1, 6)]
    for kind, adapt in (("robots", None), ("robots", 300.0), ("time", None)):
        t = time.perf_counter()
        cv = cross_validate(logs, kind, adapt=adapt)
        print(f"\nUTIAS dataset 1, --cv {kind}" + (f" --adapt {adapt:g}" if adapt else "") + f" ({time.perf_counter() - t:.1f} s)")
        print(cv.table[COLS].round(4).to_string(index=False))
        print("  drift: " + " | ".join(f"{r.test} ({r.profile}): {r.drift}" for r in cv.table.itertuples()))
        for prof, s in cv.summary.items():
            if isinstance(s, dict):
                print(
                    f"  {prof:6s}: mean ECE {s['mean_ece']:.4f} (a calibrated model: {s['mean_ece_if_calibrated_blocks']:.4f}), "
                    f"mean Brier {s['mean_brier']:.4f}, mean |FA error| {100 * s['mean_abs_false_alarm_error']:.1f} %, "
                    f"FA error over all held-out frames {100 * s['pooled_false_alarm_error']:+.1f} %"
                )


def radish(root: Path) -> None:
    from calib.io.registry import read_log

    for name in ("aces", "intel"):
        path = root / f"{name}.clf.bz2"
        if not path.is_file():
            print(f"{path} not found: skipped")
            continue
        t = time.perf_counter()
        cv = cross_validate([read_log(path)], "time", landmarks_csv=Path("cloud"))
        print(f"\nRadish {name}, --cv time --landmarks cloud ({time.perf_counter() - t:.1f} s)")
        print(cv.table[COLS + ["pairs_informative", "ece_if_calibrated", "true_detections", "hotelling_coverage"]].round(4).to_string(index=False))
        s = cv.summary["pooled"]
        print(
            f"  mean ECE {s['mean_ece']:.4f} (a calibrated model: {s['mean_ece_if_calibrated_blocks']:.4f} in blocks, "
            f"{s['mean_ece_if_calibrated']:.4f} independent), mean |FA error| {100 * s['mean_abs_false_alarm_error']:.1f} %, "
            f"FA error over all held-out frames {100 * s['pooled_false_alarm_error']:+.1f} %, "
            f"mean coverage {s.get('mean_hotelling_coverage', float('nan')):.4f}"
        )


def parks(n: int) -> None:
    from calib.sim.park import ParkConfig, simulate_park

    t = time.perf_counter()
    logs = [simulate_park(ParkConfig(), seed=s).log for s in range(1, n + 1)]
    print(f"\nsimulated {n} default parks in {time.perf_counter() - t:.0f} s")
    for gamma in ("chi2", "empirical"):
        rows = []
        for k in range(n):
            t = time.perf_counter()
            cal = calibrate([logs[k]], CalibrateConfig(gamma=gamma), name="p", version="1.0.0")
            v = validate(cal.profile, [lg for j, lg in enumerate(logs) if j != k])
            pl = v.per_log.assign(calibrated_on=logs[k].name)
            rows.append(pl)
            s = v.summary
            print(
                f"  verdicts: {v.drift.verdict}; " + "; ".join(f"{r.name}: {r.headline}" for r in v.drift.rows), flush=True
            )
            print(
                f"gamma {gamma:9s} calibrated on {logs[k].name}: gamma {cal.profile.hotelling.gamma:.2f}, in-sample coverage "
                f"{cal.profile.hotelling.coverage:.4f}, rate {cal.profile.clutter.rate:.3f} ({cal.profile.clutter.count_model}); "
                f"held out: FA error {100 * s['false_alarm_relative_error']:+.1f} % "
                f"[{100 * s['false_alarm_relative_error_ci95'][0]:+.1f}, {100 * s['false_alarm_relative_error_ci95'][1]:+.1f}], "
                f"ECE {s['ece']:.5f}, coverage {s['hotelling_coverage']:.4f} "
                f"[{s['hotelling_coverage_ci95'][0]:.4f}, {s['hotelling_coverage_ci95'][1]:.4f}] ({time.perf_counter() - t:.0f} s)"
            )
        t = pd.concat(rows, ignore_index=True)
        per = t[t["log"] != "all"]
        allrows = t[t["log"] == "all"]
        print(
            f"  gamma {gamma}: per held-out park |FA error| mean {100 * per['false_alarm_relative_error'].abs().mean():.1f} %, "
            f"max {100 * per['false_alarm_relative_error'].abs().max():.1f} %; pooled over the other parks: "
            + ", ".join(f"{100 * x:+.1f} %" for x in allrows["false_alarm_relative_error"])
            + f"; coverage {per['hotelling_coverage'].min():.4f}-{per['hotelling_coverage'].max():.4f}; "
            f"ECE {per['ece'].min():.5f}-{per['ece'].max():.5f}"
        )


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--utias", type=Path, default=Path(__file__).resolve().parents[2] / "shared/data/utias_mrclam/dataset1")
    ap.add_argument("--radish", type=Path, default=Path(__file__).resolve().parents[2] / "shared/data/radish")
    ap.add_argument("--parks", type=int, default=4)
    ap.add_argument("--skip-sim", action="store_true")
    a = ap.parse_args()
    if a.utias.is_dir():
        utias(a.utias)
    else:
        print(f"UTIAS dataset 1 not found at {a.utias}: skipped")
    if a.radish.is_dir():
        radish(a.radish)
    else:
        print(f"Radish logs not found at {a.radish}: skipped")
    if not a.skip_sim:
        parks(a.parks)


if __name__ == "__main__":
    main()
