"""RB-PHD, LMB and delta-GLMB side by side on the real logs: Victoria Park (pose RMSE vs GPS) and
UTIAS MRCLAM dataset 1 (pose RMSE vs Vicon, map OSPA vs the surveyed landmarks), ms per step.

Run: ``python benchmarks/bench_real_filters.py [--logs utias,vp] [--robots 1,2,3,4,5] [--seeds 0,1,2]
[--vp-seeds 0] [--filters rbphd,lmb,glmb] [--frames N] [--data DIR] [--profiles DIR] [--csv FILE]
[--set key=value ...]``. One SLAM run at a time, in this process, BLAS pinned to one thread; run it
under ``nice`` on a shared machine. Each run prints one row as it ends (and appends it to ``--csv``),
then a table of the mean (min-max) per log, robot and filter.

Settings are the RB-PHD runs' (``benchmarks/configs/victoria_park.yaml`` with
``benchmarks/profiles/victoria-park-selfcal@1.0.0.yaml``; ``benchmarks/configs/utias_mrclam/robotK.yaml``
with the camera profile calibrated on the other four robots); ``--filter`` swaps the map filter with
``slam_runtime.config.with_filter`` (the labelled filters take their defaults), ``--set`` overrides
any setting (``filter.survival=0.95``; values parsed as YAML). UTIAS profiles: ``--profiles DIR``
holding ``notK/profile.yaml`` (or ``cal_notK/profile.yaml``, ``notK.yaml``) for each held-out robot K; without it they are made
here (``detcal calibrate DATASET --robot ... --name utias-notK``, a few minutes each) into
``--work``. Logs whose folder is absent are skipped with a message. The machine's load is printed
before and after: compare rows of one run with each other.
"""

from __future__ import annotations

import os

for var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "NUMBA_NUM_THREADS"):
    os.environ.setdefault(var, "1")

import argparse  # noqa: E402
import csv  # noqa: E402
import subprocess  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402
import yaml  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from calib.config import load_yaml_model  # noqa: E402
from calib.io.registry import ReadOptions, read_log  # noqa: E402
from profiles.store import load_profile_file  # noqa: E402
from slam_runtime.config import SlamConfig, override, with_filter  # noqa: E402
from slam_runtime.run import LogEvidence, evaluate, run_slam  # noqa: E402

CONFIGS = ROOT / "benchmarks/configs"
VP_PROFILE = ROOT / "benchmarks/profiles/victoria-park-selfcal@1.0.0.yaml"
FIELDS = ("log", "robot", "filter", "seed", "particles", "frames", "rmse_m", "dead_reckoning_m", "map_ospa", "map_features",
          "landmarks_mapped", "ms_step_wall", "ms_step_cpu", "log_evidence", "settings", "wall_s", "load")  # fmt: skip


def load() -> str:
    return " ".join(f"{x:.2f}" for x in os.getloadavg())


def parse_sets(items: list[str]) -> dict:
    out = {}
    for item in items:
        key, sep, value = item.partition("=")
        if not sep:
            raise SystemExit(f"--set {item!r}: expected key=value")
        out[key] = yaml.safe_load(value)
    return out


def utias_profile(data: Path, robot: int, profiles: Path | None, work: Path) -> Path:
    """The camera profile calibrated on the four robots other than ``robot`` (made with ``detcal calibrate`` if absent)."""
    if profiles is not None:
        for cand in (profiles / f"not{robot}" / "profile.yaml", profiles / f"cal_not{robot}" / "profile.yaml", profiles / f"not{robot}.yaml"):
            if cand.is_file():
                return cand
        raise SystemExit(f"--profiles {profiles}: no not{robot}/profile.yaml or not{robot}.yaml")
    made = work / f"profiles/utias-not{robot}@1.0.0.yaml"
    if not made.is_file():
        others = [f"--robot={k}" for k in range(1, 6) if k != robot]
        cmd = [sys.executable, "-c", "import sys; from calib.cli import main; sys.exit(main())", "calibrate", str(data), *others, f"--name=utias-not{robot}",
               f"--profiles-dir={work / 'profiles'}", f"--out={work / f'calibrate_not{robot}'}", "--workers=0", "--force"]  # fmt: skip
        print(f"calibrating the leave-robot-{robot}-out camera profile ...", flush=True)
        subprocess.run(cmd, check=True, cwd=ROOT)
    return made


def one(log, prof, cfg: SlamConfig, seed: int, name: str, robot: int | str, frames: int | None) -> dict:
    t0 = time.perf_counter()
    res = run_slam(log, prof, cfg, seed, max_frames=frames, hooks=(LogEvidence(),))
    wall = time.perf_counter() - t0
    m = evaluate(log, res, cfg=cfg)
    ref = "ground_truth" if "trajectory_rmse_vs_ground_truth_m" in m else "gps"
    step, cpu = res.step_ms[1:], res.step_cpu_ms[1:]
    return {
        "log": name, "robot": robot, "filter": cfg.filter.kind, "seed": seed, "particles": cfg.particles, "frames": m["frames"],
        "rmse_m": m[f"trajectory_rmse_vs_{ref}_m"], "dead_reckoning_m": m[f"odometry_rmse_vs_{ref}_m"],
        "map_ospa": m.get("map_ospa", float("nan")), "map_features": m.get("map_features", int(res.map_xy.shape[0])),
        "landmarks_mapped": m.get("landmarks_mapped", ""), "ms_step_wall": float(step.mean()), "ms_step_cpu": float(cpu.mean()),
        "log_evidence": float(res.per_step["log_evidence"][-1]), "wall_s": wall, "load": load(),
    }  # fmt: skip


def show(r: dict) -> None:
    print(
        f"{r['log']:<6} {str(r['robot']):>2} {r['filter']:<6} seed {r['seed']}  RMSE {r['rmse_m']:7.3f} m (DR {r['dead_reckoning_m']:6.2f})"
        f"  OSPA {r['map_ospa']:6.3f}  features {r['map_features']:>4}  {r['ms_step_wall']:7.2f} ms/step wall {r['ms_step_cpu']:7.2f} CPU"
        f"  log evidence {r['log_evidence']:.1f}  ({r['wall_s']:.0f} s, load {r['load']})",
        flush=True,
    )


def summary(rows: list[dict]) -> None:
    print("\nlog    robot filter  seeds  RMSE mean (min-max) m        OSPA mean (min-max)     features  ms/step wall / CPU")
    keys = sorted({(r["log"], str(r["robot"]), r["filter"]) for r in rows}, key=lambda k: (k[0], k[1], ("rbphd", "lmb", "glmb").index(k[2])))
    for key in keys:
        sel = [r for r in rows if (r["log"], str(r["robot"]), r["filter"]) == key]
        rm, os_ = np.array([r["rmse_m"] for r in sel]), np.array([r["map_ospa"] for r in sel])
        ft = [r["map_features"] for r in sel]
        osp = "        -" if np.isnan(os_).all() else f"{os_.mean():.3f} ({os_.min():.3f}-{os_.max():.3f})"
        print(
            f"{key[0]:<6} {key[1]:>5} {key[2]:<6} {len(sel):>5}  {rm.mean():7.2f} ({rm.min():.2f}-{rm.max():.2f})   {osp:>22}  "
            f"{min(ft)}-{max(ft):<5}  {np.mean([r['ms_step_wall'] for r in sel]):6.1f} / {np.mean([r['ms_step_cpu'] for r in sel]):6.1f}"
        )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--logs", default="utias,vp", help="comma list of utias, vp")
    ap.add_argument("--robots", default="1,2,3,4,5", help="UTIAS robots")
    ap.add_argument("--seeds", default="0,1,2", help="UTIAS filter seeds")
    ap.add_argument("--vp-seeds", default="0", help="Victoria Park filter seeds")
    ap.add_argument("--filters", default="rbphd,lmb,glmb")
    ap.add_argument("--frames", type=int, default=None, help="only the first N frames of every log")
    ap.add_argument("--data", type=Path, default=ROOT.parent / "shared/data", help="the data folder (victoria_park/, utias_mrclam/dataset1)")
    ap.add_argument("--profiles", type=Path, default=None, help="UTIAS leave-one-out profiles: notK/profile.yaml, cal_notK/profile.yaml or notK.yaml")
    ap.add_argument("--work", type=Path, default=ROOT / "runs/bench_real_filters", help="where profiles made here are kept")
    ap.add_argument("--set", dest="sets", action="append", default=[], help="setting override key=value (repeatable)")
    ap.add_argument("--csv", type=Path, default=None, help="append every run's row to this CSV")
    a = ap.parse_args()
    sets, filters = parse_sets(a.sets), a.filters.split(",")
    print(f"load before: {load()}  (cores: {os.cpu_count()})  settings: {sets or 'as configured'}", flush=True)
    rows: list[dict] = []
    writer = None
    if a.csv is not None:
        old = list(csv.DictReader(a.csv.open(newline=""))) if a.csv.exists() else None
        if old is not None and (not old or list(old[0]) != list(FIELDS)):  # an older layout: rewrite it in this one
            with a.csv.open("w", newline="") as f:
                w = csv.DictWriter(f, FIELDS, extrasaction="ignore")
                w.writeheader()
                w.writerows(old)
            old = []
        fh = a.csv.open("a", newline="")
        writer = csv.DictWriter(fh, FIELDS)
        if old is None:
            writer.writeheader()

    def run(log, prof, base, seed, name, robot):
        for kind in filters:
            cfg = with_filter(base, kind)
            if sets:
                cfg = override(cfg, **sets)
            r = one(log, prof, cfg, seed, name, robot, a.frames)
            r["settings"] = " ".join(a.sets)
            show(r)
            rows.append(r)
            if writer is not None:
                writer.writerow({k: (round(v, 4) if isinstance(v, float) else v) for k, v in r.items()})
                fh.flush()

    logs = a.logs.split(",")
    if "utias" in logs:
        ds = a.data / "utias_mrclam/dataset1"
        if not ds.is_dir():
            print(f"UTIAS skipped: {ds} is absent")
        else:
            robots = [int(k) for k in a.robots.split(",")]
            todo = {k: (read_log(ds, None, ReadOptions(robot=k)), load_profile_file(utias_profile(ds, k, a.profiles, a.work))) for k in robots}
            for seed in (int(s) for s in a.seeds.split(",")):
                for k, (log, prof) in todo.items():
                    run(log, prof, load_yaml_model(SlamConfig, CONFIGS / f"utias_mrclam/robot{k}.yaml"), seed, "utias", k)
    if "vp" in logs:
        vp = a.data / "victoria_park"
        if not vp.is_dir():
            print(f"Victoria Park skipped: {vp} is absent")
        else:
            log, prof = read_log(vp, None, ReadOptions()), load_profile_file(VP_PROFILE)
            for seed in (int(s) for s in a.vp_seeds.split(",")):
                run(log, prof, load_yaml_model(SlamConfig, CONFIGS / "victoria_park.yaml"), seed, "vp", "-")
    print(f"load after: {load()}")
    if rows:
        summary(rows)


if __name__ == "__main__":
    main()
