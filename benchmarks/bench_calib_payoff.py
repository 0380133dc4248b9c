"""Does calibration pay off in SLAM? Calibrated profile against a constant P_D and against the truth statistics.

For planar landmarks on simulated streets (``--kind street``) and circle landmarks in the simulated park
(``--kind park``), every map filter asked for (``--filter``) runs with

* ``calibrated``: the profile calibrated on another log (street 100, every second frame; with
  ``--street-calibration 100-107`` one profile pooled over those streets, every second frame of each, its runs'
  variants ending in ``+cal100-107``; the park: the default
  log's calibration, ``detcal calibrate`` with the default config on park seed 1 -- the bundled ``sim-park-laser``;
  with ``--park-calibration SEED`` the calibration of world SEED of the benchmark's own park configuration, another
  world of the same kind, as the streets' street 100);
* ``constant``: the same profile with a constant P_D (``detection.pd_mode: constant``, 0.9 in view);
* ``truth``: the truth statistics of the log itself -- the same calibration run in-sample on the very log the
  filter sees (every frame, the simulator's true poses and labels): what a perfect calibration of this model
  class would give, so ``calibrated - truth`` is the calibration's error and ``constant - truth`` what calibration
  can win at best;
* ablations (``--variants``): ``truth_pd`` (the calibrated profile with the truth's P_D table, grid and slab
  ratio), ``truth_clutter`` (with the truth's clutter), ``truth_noise`` (with the truth's measurement noise and Hotelling
  gate), ``calibrated_poisson`` / ``truth_poisson`` (the profile's
  clutter count model forced to Poisson, to isolate the negative-binomial clutter term); a ``+ext`` suffix bounds
  the map planes by their detections' outlines (``detection.plane_extents``), ``+dup`` lowers the survival of a
  track an older one lies near (``filter.survival_duplicate: 0.9``; ``+dupwide``: 0.5 within a squared Mahalanobis
  distance of 1000), ``+nobuf`` turns the buffer zone off, ``+ba`` makes births from measurements a track could
  explain rare (``filter.birth_associated: 1e-4``), ``+fc`` takes each frame's clutter rate from the profile's
  negative binomial (``detection.frame_clutter``).

``--detector KEY=VALUE`` (with ``--tag NAME``) changes a plane detector setting in every calibration (the street-100
profile and the truth; the runtime reads the detector from the profile, so calibration and filter count the same
units): ``--detector coplanar_offset=0.25 --tag pieces`` merges the pieces of a plane 5-25 cm apart into one
detection; its rows' variants end in ``+NAME``.

with the poses given (``--poses given``: the map filter alone, every particle on the true path, 1 particle) and in
full SLAM (``--poses slam``: ``--particles``, 20 by default), over ``--streets`` logs x ``--seeds`` filter seeds.
Printed per (poses, filter): each variant's mean map OSPA and trajectory RMSE, and the paired differences
calibrated - constant, calibrated - truth, truth - constant with their standard errors over the (log, seed) pairs
and how many pairs favour the first. Plane runs also print where their extra map features come from: features
within 0.3 of some true steep plane of any visibility (``real``; the OSPA truth counts only planes seen with >= 200
returns) and those near none (``spurious``).

    nice python benchmarks/bench_calib_payoff.py --kind street --streets 1-5 --seeds 3 --frames 120 \
        --filter glmb --filter lmb --filter rbphd --poses given --poses slam --workers 2 --out payoff.jsonl
    python benchmarks/bench_calib_payoff.py --summarise payoff.jsonl

Each run is one JSON line in ``--out`` (appended; a run already there is skipped), so a long measurement can be
resumed and summarised apart. Logs and profiles are cached in ``--cache`` (default ``.bench-cache``). CPU time per
run is recorded (``cpu_s``), not wall time: the machine is shared.
"""

from __future__ import annotations

import os

for var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "NUMBA_NUM_THREADS"):
    os.environ.setdefault(var, "1")

import argparse  # noqa: E402
import json  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from concurrent.futures import ProcessPoolExecutor  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from benchmarks.common import ints, parse_set  # noqa: E402
from profiles.override import updated  # noqa: E402
from profiles.store import dump_profile, load_profile_file  # noqa: E402
from slam_runtime.config import SlamConfig, with_filter, with_settings  # noqa: E402
from slam_runtime.run import evaluate, run_slam  # noqa: E402

BASE = ("calibrated", "constant", "truth")
PAIRS = (("calibrated", "constant"), ("calibrated", "truth"), ("truth", "constant"))


# ------------------------------------------------------------------ logs (simulated where used) and profiles (cached)
def _write_text(path: Path, text: str) -> None:
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    tmp.write_text(text)
    tmp.replace(path)


def simulated(kind: str, seed: int, frames: int | None, cache: Path | None = None):
    """The log of a street or park seed, kept in ``cache`` as a pickle (the native format's compression of
    hundreds of MB of clouds costs more than the simulation; same seed, same log)."""
    import pickle

    path = cache / f"{kind}{seed}_f{frames or 'all'}.pkl" if cache is not None else None
    if path is not None and path.is_file():
        with path.open("rb") as fh:
            return pickle.load(fh)
    if kind == "street":
        from calib.sim.street import StreetConfig, simulate_street

        log = simulate_street(StreetConfig(frames=frames), seed).log
    else:
        from calib.config import load_yaml_model
        from calib.sim.park import ParkConfig, simulate_park

        log = simulate_park(load_yaml_model(ParkConfig, ROOT / "benchmarks/configs/small_park.yaml"), seed).log
    if path is not None:
        tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
        with tmp.open("wb") as fh:
            pickle.dump(log, fh, protocol=5)
        tmp.replace(path)
    return log


def calibrated(kind: str, log, out: Path, name: str, every: int = 1, detector: dict | None = None) -> Path:
    """The calibration of one log (streets: or a list of logs, pooled), cached as YAML: the plane calibration (every
    ``every``-th frame; ``detector``: plane detector settings changed from the defaults, which the profile then
    carries to the runtime) of a street, the laser calibration (default config) of a park; ``log`` None for the park:
    the bundled sim-park-laser."""
    if out.is_file():
        return out
    if kind == "street":
        from calib.planes import PlaneCalibConfig, calibrate_planes
        from profiles.planes import PlaneDetectorParams

        cfg = PlaneCalibConfig(every=every, detector=PlaneDetectorParams(**(detector or {})))
        prof = calibrate_planes(log if isinstance(log, list) else [log], cfg, name=name, version="1.0.0").profile
    elif log is None:
        from profiles.store import bundled

        _write_text(out, bundled("sim-park-laser", "1.0.0").read_text())
        return out
    else:
        from calib.calibrate import calibrate
        from profiles.parameters import CalibrateConfig

        prof = calibrate([log], CalibrateConfig(), name=name, version="1.0.0").profile
    _write_text(out, dump_profile(prof))
    return out


#: settings a variant adds with ``+name`` (``calibrated+ext``: the calibrated profile with bounded map planes)
MODIFIERS = {
    "ext": {"detection.plane_extents": True},
    "fc": {"detection.frame_clutter": True},
    "fc20": {"detection.frame_clutter": True, "detection.clutter_memory": 20.0},
    "fc100": {"detection.frame_clutter": True, "detection.clutter_memory": 100.0},
    "dup": {"filter.survival_duplicate": 0.9},
    "nobuf": {"detection.buffer_zone": False},
    "ba": {"filter.birth_associated": 1e-4},
    "dupwide": {"filter.survival_duplicate": 0.5, "filter.duplicate_gate": 1000.0},
    "nodup": {"filter.survival_duplicate": 1.0},
    "dupk2": {"filter.duplicate_sigmas": 2.0},
    "dupk5": {"filter.duplicate_sigmas": 5.0},
    "dupk8": {"filter.duplicate_sigmas": 8.0},
    "dup01": {"filter.survival_duplicate": 0.1},
    "dup001": {"filter.survival_duplicate": 0.01},
}


def variant_profile(variant: str, cal, truth):
    """(profile, pd_mode) of a variant (module docstring); ``+modifier`` suffixes are settings (:data:`MODIFIERS`)."""
    variant = variant.split("+")[0]
    if variant == "calibrated":
        return cal, "profile"
    if variant == "constant":
        return cal, "constant"
    if variant == "truth":
        return truth, "profile"
    if variant == "truth_pd":
        ch = {"pd": truth.pd.model_dump()}
        if truth.planes is not None:
            ch["planes"] = {**cal.planes.model_dump(), "pd_grid": truth.planes.model_dump()["pd_grid"], "slab_ratio": truth.planes.slab_ratio}
        return updated(cal, ch), "profile"
    if variant == "truth_clutter":
        return updated(cal, {"clutter": truth.clutter.model_dump()}), "profile"
    if variant == "truth_noise":
        return updated(cal, {k: getattr(truth, k).model_dump() for k in ("noise", "hotelling") if getattr(truth, k) is not None}), "profile"
    if variant in ("calibrated_poisson", "truth_poisson"):
        p = cal if variant.startswith("calibrated") else truth
        return updated(p, {"clutter.count_model": "poisson", "clutter.size": None}), "profile"
    raise SystemExit(f"unknown variant {variant!r}")


# ------------------------------------------------------------------ one task: one log x poses x filter, every variant and seed
_NEED_OUTLINES = False


def _cached_detector() -> dict:
    """Plane detections of every frame computed once per log in this process and shared by its runs (the street
    benchmark's cached source); returns its store, {id(log): {frame rows: Measurements}}."""
    from benchmarks.bench_street_slam import Cached, CachedPlanes
    from detectors.kinds import DETECTORS

    DETECTORS.add("plane3d", CachedPlanes(), replace=True)
    return Cached.store


def _feature_origin(log, est: np.ndarray, length: float) -> dict:
    """Where a plane map's features (K, 4) come from: each feature goes to its nearest steep true plane (of any
    visibility) within 0.3 of the plane metric, one feature per true plane (the nearest; ``duplicate`` the others);
    ``in_truth`` those whose plane is in the OSPA truth (seen with >= 200 returns; coplanar truth merged), ``other_real``
    true planes outside it, ``spurious`` features near no true plane."""
    from slam_runtime.plane_features import embed, plane_distance
    from slam_runtime.plane_metrics import landmark_truth

    pl = log.planes
    steep = np.flatnonzero(np.abs(pl.normal[:, 2]) <= np.sin(np.radians(45.0)))
    out = {"features_in_truth": 0, "features_other_real": 0, "features_duplicate": 0, "features_spurious": 0}
    if est.shape[0] == 0:
        return out
    tr = embed(pl.normal[steep], pl.offset[steep], length)
    d = plane_distance(est, tr)
    near = d.argmin(axis=1)
    ok = d[np.arange(est.shape[0]), near] < 0.3
    truth, _ = landmark_truth(log, length=length)
    in_truth = plane_distance(tr, truth).min(axis=1) < 0.05 if truth.shape[0] else np.zeros(tr.shape[0], bool)
    # coplanar true planes are one map landmark: a feature's plane is the class of true planes within 0.05 of its nearest
    cls = np.array([int(np.flatnonzero(plane_distance(tr[i : i + 1], tr)[0] < 0.05)[0]) for i in range(tr.shape[0])])
    taken: set = set()
    for k in np.argsort(d[np.arange(est.shape[0]), near]):
        if not ok[k]:
            out["features_spurious"] += 1
        elif cls[near[k]] in taken:
            out["features_duplicate"] += 1
        else:
            taken.add(cls[near[k]])
            out["features_in_truth" if in_truth[near[k]] else "features_other_real"] += 1
    return out


def run_task(task: dict) -> list[dict]:
    """Every (poses, filter, variant, seed) run of one log: the log simulated once, its truth profile calibrated
    in-sample (cached)."""
    kind = task["kind"]
    store = _cached_detector() if kind == "street" else {}
    log = simulated(kind, task["street"], task["frames"], Path(task["cache"]))
    tag = task["tag"]
    det_path = Path(task["cache"]) / f"det2-{kind}{task['street']}_f{task['frames']}{tag}.pkl"
    if kind == "street":
        global _NEED_OUTLINES
        _NEED_OUTLINES = any("+ext" in r[2] for r in task["runs"])
        _load_detections(log, det_path, store)
    tname = f"truth-{kind}{task['street']}" + (f"-f{task['frames']}" if kind == "street" else "") + tag
    truth = load_profile_file(calibrated(kind, log, Path(task["cache"]) / f"{tname}.yaml", tname, detector=task["detector"]))
    cal = load_profile_file(task["calibrated"])
    rows = []
    for poses, filt, variant, seed in task["runs"]:
        prof, mode = variant_profile(variant, cal, truth)
        given = poses == "given"
        cfg = with_settings(
            with_filter(SlamConfig(), filt),
            {
                **({"features": "planes"} if kind == "street" else {}),
                "particles": 1 if given else task["particles"],
                "poses": "ground_truth" if given else "estimated",
                "detection.pd_mode": mode,
                **task["sets"],
                **{k: v for m in variant.split("+")[1:] for k, v in MODIFIERS[m].items()},
            },
        )
        c0 = time.process_time()
        res = run_slam(log, prof, cfg, seed)
        m = evaluate(log, res, 1.0, 1.0, cfg)
        row = {"kind": kind, "street": task["street"], "poses": poses, "filter": filt, "variant": variant + task["vsuffix"], "seed": seed}
        row |= {k: (float(v) if isinstance(v, (int, float, np.floating, np.integer)) else v) for k, v in m.items() if np.isscalar(v)}
        row["filter_key"] = filt  # the metrics name the filter ("delta-GLMB"); the key (glmb) is what a resumed run asks for
        if kind == "street":
            row |= _feature_origin(log, np.asarray(res.map_xy).reshape(-1, 4), cfg.metric.plane_length)
            row["map"] = np.round(np.asarray(res.map_xy, dtype=np.float64).reshape(-1, 4), 4).tolist()
        row["cpu_s"] = time.process_time() - c0
        rows.append(row)
        if task["out"]:  # one line per run, appended as it ends (O_APPEND: the workers' lines do not interleave)
            with open(task["out"], "a") as fh:
                fh.write(json.dumps(row, sort_keys=True) + "\n")
        print(
            f"{kind} {task['street']} {poses} {filt} {variant} seed {seed}: map OSPA {m['map_ospa']:.3f}, "
            f"RMSE {m['trajectory_rmse_vs_ground_truth_m']:.3f} m, features {m.get('map_features', float('nan'))}, {row['cpu_s']:.0f} s CPU",
            flush=True,
        )
    if kind == "street":
        _save_detections(log, det_path, store)
    return rows


def _load_detections(log, path: Path, store: dict) -> None:
    """Restore a log's cached plane measurements (charts and covariances per frame; the cloud re-attached)."""
    import pickle

    from detectors.kinds import Measurements

    old = path.with_name(path.name.replace("det2-", "det-"))  # an earlier cache without outlines (enough without +ext)
    src = path if path.is_file() else old if old.is_file() and not _NEED_OUTLINES else None
    if src is not None and id(log) not in store:
        with src.open("rb") as fh:
            stored = pickle.load(fh)
        store[id(log)] = {r: Measurements(v[0], v[1], cloud=log.clouds.frame(r), outlines=v[2] if len(v) > 2 else None) for r, v in stored.items()}


def _save_detections(log, path: Path, store: dict) -> None:
    import pickle

    d = store.get(id(log), {})
    if not d or any(m.outlines is None for m in d.values()):
        return
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    with tmp.open("wb") as fh:
        pickle.dump({r: (m.z, m.cov, m.outlines) for r, m in d.items()}, fh, protocol=5)
    tmp.replace(path)


# ------------------------------------------------------------------ the tables
def summarise(rows: list[dict], variants: list[str] | None = None) -> None:
    import pandas as pd

    df = pd.DataFrame(rows)
    # a run measured twice (a results file resumed before runs recorded their filter key) counts once: same inputs, same bytes
    df = df.drop_duplicates(subset=["kind", "street", "poses", "filter", "variant", "seed"], keep="last")
    for (kind, poses, filt), g in df.groupby(["kind", "poses", "filter"], sort=False):
        have = [v for v in (variants or list(dict.fromkeys(g["variant"]))) if v in set(g["variant"])]
        print(f"\n## {kind}, poses {poses}, {filt}: {g['street'].nunique()} logs x {g['seed'].nunique()} seeds")
        cols = [("map OSPA", "map_ospa"), ("pose RMSE [m]", "trajectory_rmse_vs_ground_truth_m"), ("map features", "map_features"), ("mapped", "landmarks_mapped")]
        if "features_duplicate" in g:
            cols += [("in truth", "features_in_truth"), ("other real", "features_other_real"), ("duplicate", "features_duplicate"), ("spurious", "features_spurious")]
        cols += [("CPU s", "cpu_s")]
        print("| variant | " + " | ".join(c for c, _ in cols) + " |")
        print("|---" * (len(cols) + 1) + "|")
        for v in have:
            s = g[g["variant"] == v]
            print(f"| {v} | " + " | ".join(f"{s[k].mean():.3f}" if k in s else "-" for _, k in cols) + " |")
        print("\n| paired difference | map OSPA (SE; pairs first lower) | pose RMSE [m] (SE; pairs first lower) |")
        print("|---|---|---|")
        pairs = list(PAIRS) + [(v, "calibrated") for v in have if v not in BASE and "+" not in v]
        for mod in dict.fromkeys(v.split("+", 1)[1] for v in have if "+" in v):  # the same pairs with a modifier on both sides
            pairs += [(f"{a}+{mod}", f"{b}+{mod}") for a, b in PAIRS] + [(f"calibrated+{mod}", "constant"), (f"calibrated+{mod}", "calibrated"), (f"calibrated+{mod}", "truth")]
        for a, b in pairs:
            if a not in have or b not in have:
                continue
            A = g[g["variant"] == a].set_index(["street", "seed"])
            B = g[g["variant"] == b].set_index(["street", "seed"])
            idx = A.index.intersection(B.index)
            cells = []
            for key in ("map_ospa", "trajectory_rmse_vs_ground_truth_m"):
                d = (A.loc[idx, key] - B.loc[idx, key]).to_numpy(np.float64)
                if poses == "given" and key != "map_ospa":
                    cells.append("(poses given)")
                    continue
                se = d.std(ddof=1) / np.sqrt(d.size) if d.size > 1 else float("nan")
                cells.append(f"{d.mean():+.4f} ± {se:.4f} ({int((d < 0).sum())}/{d.size})")
            print(f"| {a} - {b} | " + " | ".join(cells) + " |")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--kind", choices=("street", "park"), default="street")
    ap.add_argument("--streets", type=ints, default=ints("1-5"), help="log seeds, e.g. 1-5")
    ap.add_argument("--seeds", type=int, default=3)
    ap.add_argument("--frames", type=int, default=120, help="street frames (the park runs its whole log)")
    ap.add_argument("--filter", action="append", dest="filters", default=None)
    ap.add_argument("--poses", action="append", choices=("given", "slam"), default=None)
    ap.add_argument("--variants", default=",".join(BASE))
    ap.add_argument("--particles", type=int, default=20)
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE")
    ap.add_argument(
        "--detector", action="append", default=[], metavar="KEY=VALUE",
        help="streets: a plane detector setting for every calibration (the street-100 profile, the truth) and so the runtime, "
        "which reads it from the profile; the runs' variants get the suffix +NAME of --tag",
    )
    ap.add_argument(
        "--park-calibration", type=int, default=None, metavar="SEED",
        help="park: the calibrated profile from world SEED of the same configuration (default: the bundled sim-park-laser, calibrated on the default park)",
    )
    ap.add_argument(
        "--street-calibration", default="100", metavar="SEEDS",
        help="streets: the calibrated profile pooled over these streets (every second frame of each); other than 100 the runs' variants end in +calSEEDS",
    )
    ap.add_argument("--tag", default="", help="with --detector: the suffix of the variants and the cache files")
    ap.add_argument("--workers", type=int, default=1)
    ap.add_argument("--cache", type=Path, default=ROOT / ".bench-cache")
    ap.add_argument("--out", type=Path, default=None)
    ap.add_argument("--summarise", type=Path, default=None, help="print the tables of a results file and stop")
    args = ap.parse_args()
    if args.summarise:
        summarise([json.loads(x) for x in args.summarise.read_text().splitlines() if x.strip()])
        return
    print(f"load average: {os.getloadavg()[0]:.2f} on {os.cpu_count()} cores", flush=True)
    cache = args.cache
    cache.mkdir(parents=True, exist_ok=True)
    variants = args.variants.split(",")
    detector = dict(parse_set(x) for x in args.detector)
    if detector and not args.tag:
        raise SystemExit("--detector needs --tag (the variants' suffix and the cache files')")
    tag = f"-{args.tag}" if args.tag else ""
    cal_streets = ints(args.street_calibration)
    ctag = f"cal{args.street_calibration}" if args.kind == "street" and cal_streets != [100] else ""
    if args.kind == "street":
        cname = ("street100" if not ctag else f"streets{args.street_calibration}") + "-every2" + tag
        cal = cache / f"{cname}.yaml"
        if not cal.is_file():  # not kept: used once
            calibrated("street", [simulated("street", s, None) for s in cal_streets], cal, cname, 2, detector)
    elif args.park_calibration is not None:  # calibrated on another world of the benchmark's own park configuration
        k = args.park_calibration
        cal = calibrated("park", simulated("park", k, args.frames, cache), cache / f"park{k}-cal.yaml", f"park{k}-cal")
    else:
        cal = calibrated("park", None, cache / "sim-park-laser.yaml", "sim-park-laser")
    done: list[dict] = []
    if args.out and args.out.is_file():
        done = [json.loads(x) for x in args.out.read_text().splitlines() if x.strip()]
    names = {"delta-GLMB": "glmb", "LMB": "lmb", "RB-PHD": "rbphd"}  # rows written before they carried filter_key
    have = {(r["kind"], r["street"], r["poses"], r.get("filter_key", names.get(r["filter"], r["filter"])), r["variant"], r["seed"]) for r in done}
    suffix = "".join(f"+{t}" for t in (args.tag, ctag) if t)
    def applies(f: str, v: str) -> bool:  # a modifier of the labelled filters' settings does not apply to RB-PHD
        from profiles.errors import DetcalError

        try:
            with_settings(with_filter(SlamConfig(), f), {k: x for m in v.split("+")[1:] for k, x in MODIFIERS[m].items()})
        except DetcalError:
            return False
        return True

    tasks = []
    for poses in args.poses or ["given", "slam"]:  # every log's map-only runs first: they are the quick ones
        for s in args.streets:
            runs = [
                (poses, f, v, sd)
                for f in args.filters or ["glmb", "lmb", "rbphd"]
                for v in variants
                for sd in range(args.seeds)
                if (args.kind, s, poses, f, v + suffix, sd) not in have and applies(f, v)
            ]
            if runs:
                tasks.append({"kind": args.kind, "street": s, "frames": args.frames, "cache": str(cache), "calibrated": str(cal), "runs": runs,
                              "particles": args.particles, "sets": dict(parse_set(x) for x in args.set), "out": str(args.out) if args.out else None,
                              "detector": detector, "tag": tag, "vsuffix": suffix})
    rows = list(done)
    with ProcessPoolExecutor(max_workers=args.workers) if args.workers > 1 else _Serial() as ex:
        for res in ex.map(run_task, tasks):
            rows += res
    summarise([r for r in rows if r["kind"] == args.kind], [v + suffix for v in variants])


class _Serial:
    """``map`` in this process (``--workers 1``)."""

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        return False

    def map(self, fn, items):
        return map(fn, items)


if __name__ == "__main__":
    main()
