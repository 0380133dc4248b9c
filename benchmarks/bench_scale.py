"""Scaling out on Dask: speed-up of a SLAM sweep and of a multi-log calibration at 1 and 2 workers, and the overhead per task.

Run: ``python benchmarks/bench_scale.py [--seeds 8] [--rounds 3] [--logs 4] [--work runs/bench_scale]``.

* Sweep: one simulated park (``benchmarks/configs/small_park.yaml``, seed 71) x
  P_D mode (profile, constant) x ``--seeds`` filter seeds at 20 particles: 16 runs
  of 2-6 s each. In this process (the reference), on a local cluster of 1 and
  of 2 workers, ``--rounds`` times with the order turned each round: the speed of
  this shared machine drifts by 10-20 % over minutes (the same in-process sweep
  took 62 and 76 s of CPU twenty minutes apart), so each round's speed-ups are
  against that round's in-process run, and the median over rounds is reported.
* Calibration: ``--logs`` default parks (seeds 1..N, 1,573 scans each; simulated
  once into ``--work``), per-log detection, ground truth and labelling (about 8 s
  a log) in this process, then on 1 and 2 workers; the fits always run here.
* Overhead: Dask's own round trip per task (200 empty tasks on one worker), the
  cluster's start, and per sweep run the difference between one worker and this
  process (reading the log on the worker, shipping the run folder back).

Every figure comes with the load average before and after, the wall time, this
process's CPU time and the workers' CPU time (the cluster's processes, counted
when they exit), so a run on a busy machine can be read for what it is: the
speed-up in wall time is depressed when other jobs hold the cores, the CPU
times are not. Every distributed result is checked byte for byte against the
in-process one (the sweep's runs.csv and summary.csv, the calibration's profile).
"""

from __future__ import annotations

import argparse
import os
import resource
import shutil
import statistics
import sys
import time
from contextlib import contextmanager
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


def load() -> str:
    return "/".join(f"{x:.2f}" for x in os.getloadavg())


def cpu_self() -> float:
    r = resource.getrusage(resource.RUSAGE_SELF)
    return r.ru_utime + r.ru_stime


def cpu_children() -> float:
    r = resource.getrusage(resource.RUSAGE_CHILDREN)
    return r.ru_utime + r.ru_stime


@contextmanager
def measured(label: str, out: dict):
    """Wall, own CPU and children's CPU (workers that have exited) of the block; load average before and after."""
    before = load()
    w0, s0, c0 = time.perf_counter(), cpu_self(), cpu_children()
    yield
    out.update(wall=time.perf_counter() - w0, cpu_self=cpu_self() - s0, cpu_workers=cpu_children() - c0, load_before=before, load_after=load())
    peak = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 1024
    print(
        f"  {label:<26} wall {out['wall']:7.1f} s   CPU here {out['cpu_self']:6.1f} s   CPU workers {out['cpu_workers']:6.1f} s"
        f"   load {out['load_before']} -> {out['load_after']}   (largest worker so far {peak:.0f} MB)",
        flush=True,
    )


def sweep_bench(work: Path, seeds: int, rounds: int) -> None:
    from detcal.engine import InProcess, LogSource, open_engine
    from calib.io.registry import ReadOptions, read_log
    from calib.config import load_yaml_model
    from calib.sim.park import ParkConfig
    from detcal.reports.simulation import write_simulation_run
    from profiles.store import resolve
    from slam_runtime.config import SlamConfig, override
    from detcal.pipelines.sweep import SweepJob, run_sweep
    from detcal.reports.sweep import make_plan

    log_path = work / "sweep_park/log.dlog"
    if not log_path.is_file():
        write_simulation_run("park", load_yaml_model(ParkConfig, ROOT / "benchmarks/configs/small_park.yaml"), 71, log_path.parent)
    log = read_log(log_path)
    prof = resolve("sim-park-laser")
    src = LogSource.of(log, log_path, None, ReadOptions())
    base = SlamConfig()
    jobs = []
    for mode in ("profile", "constant"):
        cfg = override(base, particles=20, **{"detection.pd_mode": mode})
        for sd in range(seeds):
            labels = {"log": log.name, "profile": prof.ref, "pd_mode": mode, "particles": 20, "seed": sd}
            jobs.append(SweepJob(f"{mode}_s{sd}", src, prof, cfg, sd, labels))
    plan = make_plan(jobs, base.model_dump(mode="json"), [{"name": log.name, "fingerprint": src.fingerprint}])
    print(f"\nsweep: {len(jobs)} runs ({log.name}, {len(log.scans)} frames, 20 particles, P_D profile/constant x {seeds} seeds),"
          f" {rounds} rounds of in this process / 1 worker / 2 workers, the order turned each round")
    settings = [("in this process", 0), ("1 worker", 1), ("2 workers", 2)]
    reference: dict[str, bytes] = {}
    speed: dict[str, list[float]] = {"1 worker": [], "2 workers": []}
    speed_all: dict[str, list[float]] = {"1 worker": [], "2 workers": []}
    cpu_run: dict[str, list[float]] = {label: [] for label, _ in settings}
    overhead: list[tuple[float, float, float]] = []
    for r in range(rounds):
        print(f"round {r + 1}:")
        order = settings[r % 3:] + settings[: r % 3]
        res: dict[str, dict] = {}
        for label, workers in order:
            out = work / f"sweep_{workers}"
            shutil.rmtree(out, ignore_errors=True)
            m: dict = {}
            if workers == 0:
                with measured(label, m):
                    outcome = run_sweep(jobs, out, InProcess(), plan=plan)
                m["sweep_wall"] = m["wall"]
            else:
                start: dict = {}
                with measured(f"{label}: idle start+close", start), open_engine(workers, None, len(jobs)):
                    pass
                with measured(label + " (start..close)", m), open_engine(workers, None, len(jobs)) as engine:
                    t0 = time.perf_counter()
                    outcome = run_sweep(jobs, out, engine, plan=plan)
                    m["sweep_wall"] = time.perf_counter() - t0
                m["start"] = start["wall"]
            assert outcome.complete and len(outcome.rows) == len(jobs)
            task_wall = sum(t["task_wall_s"] for t in outcome.timings)
            task_cpu = sum(t["task_cpu_s"] for t in outcome.timings)
            rss = max(t["task_max_rss_mb"] for t in outcome.timings)
            m.update(task_wall=task_wall, task_cpu=task_cpu)
            cpu_run[label].append(task_cpu / len(jobs))
            print(f"    runs: {task_wall:6.1f} s wall, {task_cpu:6.1f} s CPU in all; worker peak memory {rss:.0f} MB"
                  + (f"; sweep alone {m['sweep_wall']:.1f} s" if workers else ""))
            for f in ("runs.csv", "summary.csv"):
                data = (out / f).read_bytes()
                if f not in reference:
                    reference[f] = data
                elif data != reference[f]:
                    print(f"  {label}: {f} DIFFERS from the first run's")
                    raise SystemExit(1)
            res[label] = m
        s0 = res["in this process"]["wall"]
        for label in ("1 worker", "2 workers"):
            speed[label].append(s0 / res[label]["sweep_wall"])
            speed_all[label].append(s0 / res[label]["wall"])
        one, here = res["1 worker"], res["in this process"]
        overhead.append(((one["sweep_wall"] - s0) / len(jobs), (one["cpu_workers"] + one["cpu_self"] - here["cpu_self"]) / len(jobs), one["start"]))
        print(f"  round {r + 1}: speed-up on 1 worker {speed['1 worker'][-1]:.2f}x, on 2 workers {speed['2 workers'][-1]:.2f}x (sweep alone, against this round's in-process run)")
    print(f"  runs.csv and summary.csv identical in all {3 * rounds} sweeps")

    def rng(xs: list[float], fmt: str = "{:.2f}") -> str:
        xs = sorted(xs)
        return f"{fmt.format(statistics.median(xs))} (rounds {', '.join(fmt.format(x) for x in xs)})"

    for label in ("1 worker", "2 workers"):
        print(f"  speed-up on {label}: median {rng(speed[label])} sweep alone; {rng(speed_all[label])} with the cluster's start and close")
    for label, _ in settings:
        print(f"  CPU per run {label}: {rng(cpu_run[label])} s")
    w = [o[0] * 1e3 for o in overhead]
    c = [o[1] * 1e3 for o in overhead]
    print(
        f"  overhead per run on 1 worker vs this process: {rng(w, '{:.0f}')} ms wall, {rng(c, '{:.0f}')} ms CPU"
        f" (the worker's start, imports and first compilations included; an idle cluster starts and closes in {statistics.median(o[2] for o in overhead):.1f} s)"
    )


def noop(x):
    return x


def overhead_bench() -> None:
    from detcal.engine import open_engine

    print("\nDask's own round trip (200 empty tasks on 1 worker, after a warm-up):")
    with open_engine(1, None, 1) as engine:
        list(engine.map_unordered(noop, [(0,)], ["warm"]))
        t0 = time.perf_counter()
        list(engine.map_unordered(noop, [(i,) for i in range(200)], [f"n{i}" for i in range(200)]))
        dt = time.perf_counter() - t0
    print(f"  {dt / 200 * 1e3:.1f} ms per task (load {load()})")


def calibration_bench(work: Path, n_logs: int) -> None:
    from calib.calibrate import CalibrateConfig  # noqa: F401  (imported here, not in the timed blocks)
    from calib.io.native import write_native
    from calib.io.registry import ReadOptions, input_refs, read_log
    from detcal.pipelines.calibrate import CalibrationJob, ProfileTarget, run_calibration
    from calib.sim.park import ParkConfig, simulate_park

    paths = []
    for seed in range(1, n_logs + 1):
        p = work / f"park_{seed}.dlog"
        if not p.is_file():
            write_native(simulate_park(ParkConfig(), seed).log, p)
        paths.append(p)
    logs = [read_log(p) for p in paths]
    refs = [r for p, lg in zip(paths, logs, strict=True) for r in input_refs(p, lg)]
    print(f"\ncalibration: {n_logs} default parks ({len(logs[0].scans)} scans each), per-log work on workers, fits here")
    walls, profiles = {}, {}
    for label, workers in (("in this process", 0), ("1 worker", 1), ("2 workers", 2)):
        out = work / f"calib_{workers}"
        shutil.rmtree(out, ignore_errors=True)
        job = CalibrationJob(
            logs=logs, inputs=refs, target=ProfileTarget(name="bench-parks", version="1.0.0", out=out / "run", profiles_dir=out / "profiles"),
            command="bench", sources=[(p, None, ReadOptions()) for p in paths], workers=workers,
        )  # fmt: skip
        m: dict = {}
        with measured(label, m):
            done = run_calibration(job)
        walls[label] = m["wall"]
        profiles[label] = done.profile_path.read_bytes()
    for label in ("1 worker", "2 workers"):
        print(
            f"  {label}: profile {'identical to' if profiles[label] == profiles['in this process'] else 'DIFFERS from'} the in-process one;"
            f" speed-up {walls['in this process'] / walls[label]:.2f}x (cluster start and close included)"
        )


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--seeds", type=int, default=8, help="filter seeds per P_D mode (2 modes: 2 x seeds runs)")
    ap.add_argument("--rounds", type=int, default=3, help="sweep rounds (each: in this process, 1 worker, 2 workers): the machine's speed drifts, so each round is compared within itself")
    ap.add_argument("--logs", type=int, default=4, help="parks to calibrate")
    ap.add_argument("--work", type=Path, default=ROOT / "runs/bench_scale", help="logs and outputs (the parks are simulated once)")
    ap.add_argument("--skip", choices=("sweep", "calibration", "overhead"), action="append", default=[])
    a = ap.parse_args()
    os.environ.setdefault("SOURCE_DATE_EPOCH", "1700000000")
    a.work.mkdir(parents=True, exist_ok=True)
    print(f"CPUs {os.cpu_count()}, load average (1/5/15 min) {load()}")
    if "overhead" not in a.skip:
        overhead_bench()
    if "sweep" not in a.skip:
        sweep_bench(a.work, a.seeds, a.rounds)
    if "calibration" not in a.skip:
        calibration_bench(a.work, a.logs)
    print(f"\nload average at the end {load()}")


if __name__ == "__main__":
    main()
