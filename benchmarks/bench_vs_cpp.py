"""detcal's RB-PHD-SLAM beside the C++ RB-PHD-SLAM of the open RFS-SLAM library, on the same simulated data.

The C++ simulator (``rbphdslam2dSim``, built separately from the library's source; pass its path with ``--cpp``)
generates each world (``--trajectory W``) and runs its filter with its own configuration (``cfg/rbphdslam2dSim.xml``
with the time steps and particles set here); its export folder is read by detcal's ``rfsslam`` reader
(:mod:`calib.io.rfsslam`) and detcal runs with no settings file (the profile of the simulator's true statistics and
the settings derived from the log), or with ``--config``. Both on one thread (OMP_NUM_THREADS=1), CPU time:

* per step: the C++'s own timer (predict, update, weighting, merge, prune, resample: user + system CPU) over its steps;
  detcal's step CPU (``step_cpu_ms``, the loop body: motion, proposal, P_D, update, weighting, merge, resample);
* whole process: user + system CPU of the process from start to exit (``os.wait4``): the C++ simulating, filtering
  and writing nothing (its logging off); ``detcal slam run`` reading the log, filtering, evaluating and writing its
  run folder.

Run: ``python benchmarks/bench_vs_cpp.py --cpp PATH/rbphdslam2dSim --cfg PATH/cfg/rbphdslam2dSim.xml
[--worlds 1-3] [--seeds 0-2] [--particles 10,50,200] [--steps 1000] [--whole 50]``. Prints one row per run and the
medians per particle count.
"""

from __future__ import annotations

import os

for var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "NUMBA_NUM_THREADS"):
    os.environ[var] = "1"

import argparse  # noqa: E402
import re  # noqa: E402
import subprocess  # noqa: E402
import sys  # noqa: E402
import tempfile  # noqa: E402
import xml.etree.ElementTree as ET  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
from benchmarks.common import ints  # noqa: E402

from calib.io.rfsslam import read_rfsslam, scenario  # noqa: E402
from calib.sim.rfs import truth_profile  # noqa: E402
from detcal.pipelines.slam_run import SettingsRequest  # noqa: E402
from profiles.store import dump_profile  # noqa: E402
from slam_runtime.run import evaluate, run_slam  # noqa: E402

DETCAL = [sys.executable, "-m", "detcal"]


def cpp_config(template: Path, out: Path, steps: int, particles: int, export: bool, folder: Path) -> None:
    """The library's simulator configuration with the steps, the particles and the logging set."""
    tree = ET.parse(template)
    root = tree.getroot()
    root.find("timesteps").text = str(steps)
    root.find("filter/nParticles").text = str(particles)
    # its resampling threshold is a particle count (100 of 200 in the shipped file): half the particles, as detcal's
    root.find("filter/resampling/effNParticle").text = str(particles / 2)
    root.find("logging/logResultsToFile").text = "1" if export else "0"
    root.find("logging/logTimingToFile").text = "0"
    root.find("logging/logDirPrefix").text = str(folder) + "/"
    tree.write(out)


def timed(cmd: list[str], cwd: Path) -> tuple[float, str]:
    """(user + system CPU seconds of the process, its standard output)."""
    with tempfile.TemporaryFile() as fout:
        p = subprocess.Popen(cmd, cwd=cwd, stdout=fout, stderr=subprocess.STDOUT, env=os.environ.copy())
        _, status, ru = os.wait4(p.pid, 0)
        p.returncode = os.waitstatus_to_exitcode(status)
        fout.seek(0)
        text = fout.read().decode(errors="replace")
    if p.returncode != 0:
        raise SystemExit(f"{' '.join(cmd)} failed ({p.returncode}):\n{text[-2000:]}")
    return ru.ru_utime + ru.ru_stime, text


def cpp_step_cpu(text: str, steps: int) -> float:
    """ms of CPU per step from the C++ simulator's 'Total ... cpu: <ns>' line."""
    m = re.search(r"^Total\s+wall:\s*([0-9.e+]+)\s+cpu:\s*([0-9.e+]+)", text, re.M)
    if m is None:
        raise SystemExit("the C++ simulator printed no 'Total ... cpu:' line")
    return float(m.group(2)) / 1e6 / (steps - 1)


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--cpp", type=Path, required=True, help="the built rbphdslam2dSim")
    ap.add_argument("--cfg", type=Path, required=True, help="the library's cfg/rbphdslam2dSim.xml")
    ap.add_argument("--worlds", default="1-3")
    ap.add_argument("--seeds", default="0-2")
    ap.add_argument("--particles", default="10,50,200")
    ap.add_argument("--steps", type=int, default=1000)
    ap.add_argument("--whole", default="50", help="particle counts whose whole-process CPU is measured (comma-separated; '' none)")
    ap.add_argument("--config", type=Path, default=None, help="detcal settings file (default: none, the derived settings)")
    ap.add_argument("--work", type=Path, default=None, help="folder for the exports and run folders (default: a temporary one)")
    a = ap.parse_args()
    work = a.work or Path(tempfile.mkdtemp(prefix="bench_vs_cpp_"))
    work.mkdir(parents=True, exist_ok=True)
    counts, worlds, seeds = ints(a.particles), ints(a.worlds), ints(a.seeds)
    whole = set(ints(a.whole)) if a.whole else set()
    print("load average:", " ".join(f"{x:.2f}" for x in os.getloadavg()), "| settings:", a.config or "none (derived)", flush=True)
    rows = []
    for w in worlds:
        export = work / f"world{w}"
        xml = work / f"world{w}.xml"
        cpp_config(a.cfg, xml, a.steps, 10, True, export)
        timed([str(a.cpp.resolve()), "--cfg", str(xml), "--trajectory", str(w), "--seed", "0"], work)  # the data
        log = read_rfsslam(export)
        prof = truth_profile(scenario(export))
        pfile = work / f"world{w}_profile.yaml"
        pfile.write_text(dump_profile(prof))
        for n in counts:
            xml_n = work / f"world{w}_{n}.xml"
            cpp_config(a.cfg, xml_n, a.steps, n, False, work / f"world{w}_{n}_out")
            for s in seeds:
                c_proc, text = timed([str(a.cpp.resolve()), "--cfg", str(xml_n), "--trajectory", str(w), "--seed", str(s)], work)
                c_step = cpp_step_cpu(text, a.steps)
                req = SettingsRequest(config=a.config, particles=n)
                cfg, _, _ = req.derived(log, prof)
                res = run_slam(log, prof, cfg, seed=s)
                m = evaluate(log, res, cfg=cfg)
                d_step = float(res.step_cpu_ms[1:].mean())
                d_proc = float("nan")
                if n in whole:
                    cmd = [*DETCAL, "slam", "run", str(export), "--profile", str(pfile), "--particles", str(n), "--seed", str(s),
                           "--out", str(work / f"run_{w}_{n}_{s}"), "--force"]  # fmt: skip
                    if a.config is not None:
                        cmd += ["--config", str(a.config.resolve())]
                    d_proc, _ = timed(cmd, ROOT)
                rows.append((w, n, s, c_step, d_step, c_proc, d_proc, m))
                print(
                    f"world {w} {n:>4} p seed {s}: CPU ms/step C++ {c_step:6.2f} detcal {d_step:6.2f} (ratio {d_step / c_step:4.2f}) | "
                    f"process s C++ {c_proc:6.2f} detcal {d_proc:6.2f} | detcal mapped {m['landmarks_mapped']}/{m['landmarks_true']}, "
                    f"final err {m['final_position_error_vs_ground_truth_m']:.3f} m, OSPA {m['map_ospa']:.3f}",
                    flush=True,
                )
    print("\nparticles | CPU ms/step C++ (median) | detcal (median) | ratio of medians | process s C++ | detcal | ratio")
    for n in counts:
        r = [x for x in rows if x[1] == n]
        c, d = np.median([x[3] for x in r]), np.median([x[4] for x in r])
        cp, dp = np.median([x[5] for x in r]), np.median([x[6] for x in r])
        print(f"{n:>9} | {c:24.2f} | {d:15.2f} | {d / c:16.2f} | {cp:13.2f} | {dp:6.2f} | {dp / cp:5.2f}")


if __name__ == "__main__":
    main()
