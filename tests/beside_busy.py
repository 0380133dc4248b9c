"""Run the test suite beside CPU-burning neighbours: the suite must pass on a busy machine (CI shares its cores).

``python -m tests.beside_busy [--busy N] [--repeat K] [-- PYTEST ARGS]`` starts N
processes that spin on the CPU (default 2), runs pytest K times (default 1)
with the given arguments (default ``-n 2 -q``), stops the neighbours and
prints, per run, pytest's exit code, wall time and the CPU time of pytest and
its workers (user + system, the neighbours' excluded). The exit code is the
first failing run's, else 0. ``make test-busy`` runs it.
"""

from __future__ import annotations

import argparse
import os
import resource
import signal
import subprocess
import sys
import time

SPIN = "while True:\n    pass\n"


def children_cpu() -> float:
    ru = resource.getrusage(resource.RUSAGE_CHILDREN)
    return ru.ru_utime + ru.ru_stime


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--busy", type=int, default=2, help="CPU-burning neighbour processes")
    ap.add_argument("--repeat", type=int, default=1, help="runs of the suite in a row")
    ap.add_argument("pytest_args", nargs="*", default=["-n", "2", "-q"])
    args = ap.parse_args(argv)
    busy = [subprocess.Popen([sys.executable, "-c", SPIN]) for _ in range(args.busy)]  # noqa: S603
    first_failure = 0
    try:
        for k in range(args.repeat):
            c0, t0 = children_cpu(), time.perf_counter()  # the neighbours are reaped only at the end: not counted here
            code = subprocess.call([sys.executable, "-m", "pytest", *args.pytest_args])  # noqa: S603
            wall, cpu = time.perf_counter() - t0, children_cpu() - c0
            print(f"beside {args.busy} busy processes, run {k + 1}/{args.repeat}: exit {code}, wall {wall:.0f} s, CPU {cpu:.0f} s (pytest and its workers)", flush=True)
            first_failure = first_failure or code
    finally:
        for p in busy:
            p.send_signal(signal.SIGKILL)
        for p in busy:
            p.wait()
    return first_failure


if __name__ == "__main__":
    os.environ.setdefault("PYTHONUNBUFFERED", "1")
    sys.exit(main())
