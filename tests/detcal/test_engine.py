"""Sweeps and multi-log calibrations on Dask: the same bytes as in one process, lost workers, resumed sweeps.

The truth here is the serial run (``--workers 0``: every task in this process,
one after another): a run on Dask workers must give the same bytes, whatever
the number of workers or the order in which tasks complete. Only the timings
differ (timings.csv, task.yaml, timing.png, the ``ms`` column of steps.csv and
the ``*ms_per_step*`` metrics), and they are left out of the comparison.

Workers are killed from inside a chosen run (the run's function is wrapped in
the worker processes only, through ``Client.run``), so which run is lost is
known; a restarted worker is not armed again. Timeouts are Dask's own and
generous; nothing here is timed.
"""

from __future__ import annotations

import csv
import io
import os
import sys
from pathlib import Path

import pytest
import yaml

from detcal.cli import main
from detcal.reports.simulation import write_simulation_run
from profiles.atomic import MARKER
from tests.detcal.cli.test_cli import assert_one_line_error, run
from tests.conftest import small_park_config
from profiles.override import updated

SWEEP = ["--profile", "sim-park-laser", "--seeds", "3", "--frames", "25", "--particles", "5"]
TIMED_FILES = {"timing.png", "task.yaml", "timings.csv", MARKER}
TIMED_METRICS = {"ms_per_step_mean", "ms_per_step_median", "cpu_ms_per_step_mean", "stage_ms_per_step"}


def results(folder: Path) -> dict[str, object]:
    """Every file of a sweep or calibration folder but the timings: bytes, or the table/metrics without their timing parts."""
    out: dict[str, object] = {}
    for p in sorted(folder.rglob("*")):
        if p.is_dir() or p.name in TIMED_FILES:
            continue
        rel = p.relative_to(folder).as_posix()
        if p.name == "steps.csv":
            rows = list(csv.DictReader(p.read_text().splitlines()))
            out[rel] = [{k: v for k, v in r.items() if k != "ms"} for r in rows]
        elif p.name == "metrics.yaml":
            out[rel] = {k: v for k, v in yaml.safe_load(p.read_text()).items() if k not in TIMED_METRICS}
        else:
            out[rel] = p.read_bytes()
    return out


def run_names(folder: Path) -> set[str]:
    return {p.name for p in folder.iterdir() if p.is_dir()}


@pytest.fixture(scope="module")
def park_log(tmp_path_factory) -> Path:
    cfg = small_park_config()
    cfg.bushes.count = 30
    folder = tmp_path_factory.mktemp("scale") / "park"
    write_simulation_run("park", cfg, 71, folder)
    return folder / "log.dlog"


@pytest.fixture(scope="module")
def serial(park_log, tmp_path_factory) -> Path:
    """The reference: the tiny sweep in this process (6 runs: 2 P_D modes x 3 seeds)."""
    out = tmp_path_factory.mktemp("serial") / "sw"
    assert main(["slam", "sweep", str(park_log), *SWEEP, "--workers", "0", "--out", str(out)]) == 0
    return out


@pytest.fixture
def cluster():
    """A 2-worker local Dask cluster of the test's own (commands reach it with --scheduler), loopback only.

    One per test: a test that kills a worker leaves its cluster a worker short until the nanny has started another,
    which on a busy machine may take longer than the next test waits; a fresh cluster has both workers when it is
    handed over (LocalCluster waits for them)."""
    import dask
    from distributed import Client

    from detcal.engine import LOCAL_CONFIG, local_cluster

    with dask.config.set(LOCAL_CONFIG):
        c = local_cluster(2)
        try:
            with Client(c, set_as_default=False) as client:
                yield c, client
        finally:
            c.close()


def arm_kill(client, run_name: str, flag: Path) -> None:
    """In every worker process, present or yet to start: the first attempt at ``run_name`` (anywhere: ``flag`` says)
    SIGKILLs its worker.

    A worker plugin rather than a one-off ``Client.run``: a worker that starts later (a nanny's restart) is armed as
    it comes up, whenever that is on a busy machine, so the armed run cannot slip onto an unarmed worker. Both
    workers are there first (Dask's own wait; a fresh cluster has them already).
    """
    from distributed.diagnostics.plugin import WorkerPlugin

    class Arm(WorkerPlugin):  # defined here: pickled by value, the workers need not import the tests
        def setup(self, worker, run_name=run_name, flag=str(flag)):
            import os
            import signal

            import detcal.pipelines.sweep as sw

            original = sw.run_job

            def run_job(job):
                if job.name == run_name:
                    try:
                        os.close(os.open(flag, os.O_CREAT | os.O_EXCL))
                    except FileExistsError:
                        return original(job)
                    os.kill(os.getpid(), signal.SIGKILL)
                return original(job)

            sw.run_job = run_job

    client.wait_for_workers(2, timeout=600)
    client.register_plugin(Arm(), name=f"arm-{run_name}")


def refusing_address() -> tuple[str, object]:
    """A loopback address where nothing listens, held by this test: a socket bound to a port the system chose but
    never listening, so a connection is refused at once and no other program can take the port meanwhile."""
    import socket

    s = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
    s.bind(("127.0.0.1", 0))
    return f"tcp://127.0.0.1:{s.getsockname()[1]}", s


@pytest.mark.slow  # a local Dask cluster of two worker processes
def test_sweep_on_two_local_workers_gives_the_serial_bytes(tmp_path, capsys, park_log, serial):
    code, out, err = run(capsys, "slam", "sweep", str(park_log), *SWEEP, "--workers", "2", "--out", str(tmp_path / "sw"))
    assert code == 0, err
    assert "6 run on 2 local workers" in out
    got, want = results(tmp_path / "sw"), results(serial)
    assert sorted(got) == sorted(want)
    assert got == want
    # the timings are apart, one row per run, and say where each ran
    timings = list(csv.DictReader((tmp_path / "sw/timings.csv").read_text().splitlines()))
    assert [t["run"] for t in timings] == [r["name"] for r in yaml.safe_load((serial / "config.yaml").read_text())["runs"]]
    assert len({t["task_pid"] for t in timings}) >= 1 and all(float(t["task_wall_s"]) > 0 for t in timings)
    assert "ms_per_step_mean" not in (tmp_path / "sw/runs.csv").read_text()


@pytest.mark.slow  # a local Dask cluster, one worker killed
def test_a_killed_worker_is_retried_and_the_sweep_finishes(tmp_path, capsys, park_log, serial, cluster):
    c, client = cluster
    victim = "00_park_seed71_sim-park-laser@1.0.0_rbphd_profile_p5_s1"
    arm_kill(client, victim, tmp_path / "killed")
    code, _, err = run(capsys, "slam", "sweep", str(park_log), *SWEEP, "--scheduler", c.scheduler_address, "--out", str(tmp_path / "sw"))
    assert (tmp_path / "killed").exists(), "the armed run never ran"
    assert code == 0, err
    assert results(tmp_path / "sw") == results(serial)
    assert not (tmp_path / "sw/failed.yaml").exists()


@pytest.mark.slow  # a local Dask cluster, one worker killed
def test_without_retries_the_lost_run_is_named_and_a_rerun_does_only_it(tmp_path, capsys, park_log, serial, cluster):
    c, client = cluster
    victim = "00_park_seed71_sim-park-laser@1.0.0_rbphd_constant_p5_s2"
    arm_kill(client, victim, tmp_path / "killed")
    saved, c.scheduler.allowed_failures = c.scheduler.allowed_failures, 0  # a task whose worker dies fails at once
    try:
        code, _, err = run(capsys, "slam", "sweep", str(park_log), *SWEEP, "--scheduler", c.scheduler_address, "--out", str(tmp_path / "sw"))
    finally:
        c.scheduler.allowed_failures = saved
    sw = tmp_path / "sw"
    assert code == 1
    assert "Traceback" not in err
    lines = err.splitlines()
    # one warning per failed run naming its log and seed, then the one-line error naming the missing runs
    assert lines[0].startswith(f"detcal: warning: run {victim} (log park_seed71, profile sim-park-laser@1.0.0, rbphd, constant, 5 particles, seed 2):")
    assert "worker process died" in lines[0]
    assert_one_line_error("\n".join(lines[1:]), f"1 of 6 runs failed ({victim};")
    failed = yaml.safe_load((sw / "failed.yaml").read_text())["failed"]
    assert list(failed) == [victim] and failed[victim]["seed"] == 2 and failed[victim]["log"] == "park_seed71"
    all_runs = run_names(serial)
    assert run_names(sw) == all_runs - {victim}  # the others' results are kept
    assert not (sw / "runs.csv").exists()  # the tables wait for every run
    before = {n: (sw / n / "trajectory.csv").stat().st_ino for n in all_runs - {victim}}
    # the same command (here in this process) completes only the missing run
    code, out, err = run(capsys, "slam", "sweep", str(park_log), *SWEEP, "--workers", "0", "--out", str(sw))
    assert code == 0, err
    assert "1 run in this process, 5 done before" in out
    assert {n: (sw / n / "trajectory.csv").stat().st_ino for n in before} == before
    assert not (sw / "failed.yaml").exists()
    assert results(sw) == results(serial)


def test_a_sweep_resumes_only_the_same_plan(tmp_path, capsys, park_log, serial):
    import shutil

    sw = tmp_path / "sw"
    shutil.copytree(serial, sw)
    for n in list(run_names(sw))[:2]:
        shutil.rmtree(sw / n)
    (sw / "runs.csv").unlink()
    # another seed list is another sweep: refused, nothing touched
    other_seeds = ["--profile", "sim-park-laser", "--seeds", "4", "--frames", "25", "--particles", "5"]
    code, _, err = run(capsys, "slam", "sweep", str(park_log), *other_seeds, "--out", str(sw))
    assert code == 2
    assert_one_line_error(err, "holds a sweep with other runs (the same command resumes a sweep; use --force")
    assert len(run_names(sw)) == 4
    # a sweep of an older format (before the label variant) is named as such, not blamed on the command
    plan = (sw / "config.yaml").read_text()
    (sw / "config.yaml").write_text(plan.replace("version: 2", "version: 1"))
    code, _, err = run(capsys, "slam", "sweep", str(park_log), *SWEEP, "--workers", "0", "--out", str(sw))
    assert code == 2
    assert_one_line_error(err, "holds a sweep of another version of detcal's sweep format (1, this detcal writes 2)")
    (sw / "config.yaml").write_text(plan)
    # a folder that is not a sweep is not resumed
    (tmp_path / "other").mkdir()
    code, _, err = run(capsys, "slam", "sweep", str(park_log), *SWEEP, "--workers", "0", "--out", str(tmp_path / "other"))
    assert code == 2
    assert_one_line_error(err, "other: already exists (use --force to replace it)")
    code, out, err = run(capsys, "slam", "sweep", str(park_log), *SWEEP, "--workers", "0", "--out", str(sw))
    assert code == 0, err
    assert "2 run in this process, 4 done before" in out
    assert results(sw) == results(serial)


def test_execution_options_are_checked_before_any_work(tmp_path, capsys, park_log):
    import dask
    import distributed  # noqa: F401  (before dask.config.set: see below)

    base = ["slam", "sweep", str(park_log), *SWEEP, "--out", str(tmp_path / "sw")]
    nobody, held = refusing_address()
    code, _, err = run(capsys, *base, "--workers", "-1")
    assert code == 2
    assert_one_line_error(err, "--workers: expected 0 (this process) or a positive number of worker processes, got -1")
    code, _, err = run(capsys, *base, "--workers", "2", "--scheduler", nobody)
    assert code == 2
    assert_one_line_error(err, "--workers: the cluster at --scheduler has its own workers")
    assert not (tmp_path / "sw").exists()
    # distributed writes its defaults into dask's config when first imported. Had the command below imported it
    # inside this block, leaving the block would delete the whole "distributed" key that the block created, defaults
    # and all, and every later cluster in this test process would fail (KeyError: 'require-encryption').
    with dask.config.set({"distributed.comm.timeouts.connect": "2s"}):
        code, _, err = run(capsys, *base, "--scheduler", nobody)
    held.close()
    assert code == 2
    assert_one_line_error(err, f"--scheduler {nobody}: no Dask scheduler answered")
    code, _, err = run(capsys, *base, "--scheduler", "notanaddress")
    assert code == 2
    assert_one_line_error(err, "--scheduler notanaddress: not a scheduler address (missing port number")
    assert not (tmp_path / "sw").exists()  # refused before the sweep folder is made


def test_a_listener_that_is_not_a_scheduler_is_refused_before_any_work(tmp_path, capsys, park_log):
    """A port that accepts connections but never speaks Dask (a dashboard's, say): refused after the probe's timeout,
    nothing written, no Client left to hang at exit."""
    import socket
    import threading

    server = socket.create_server(("127.0.0.1", 0))
    held: list[socket.socket] = []
    threading.Thread(target=lambda: held.append(server.accept()[0]), daemon=True).start()
    address = f"tcp://127.0.0.1:{server.getsockname()[1]}"
    try:
        code, _, err = run(capsys, "slam", "sweep", str(park_log), *SWEEP, "--scheduler", address, "--out", str(tmp_path / "sw"))
    finally:
        server.close()
        for s in held:
            s.close()
    assert code == 2
    assert_one_line_error(err, f"--scheduler {address}: something listens there but it is not a Dask scheduler")
    assert not (tmp_path / "sw").exists()


def test_a_worker_refuses_a_log_with_other_content_at_the_same_path(tmp_path, park_log):
    import shutil

    from detcal import engine
    from calib.io.registry import ReadOptions, read_log
    from profiles.errors import DataError

    p = tmp_path / "log.dlog"
    shutil.copy(park_log, p)
    src = engine.LogSource.of(read_log(p), p, None, ReadOptions())
    engine._CACHE.clear()  # noqa: SLF001  (as in a fresh worker process)
    assert engine.log_fingerprint(src.load()) == src.fingerprint
    engine._CACHE.clear()  # noqa: SLF001
    write_simulation_run("park", small_park_config(), 72, tmp_path / "o")
    shutil.copy(tmp_path / "o/log.dlog", p)
    with pytest.raises(DataError, match=r"log 'park_seed71': .*log.dlog on .* holds other content than the client read"):
        src.load()


@pytest.fixture(scope="module")
def unstated_sigma_logs(tmp_path_factory) -> list[Path]:
    """Two small parks whose logs state no sigma_r: calibrate estimates it (range residuals per log, pooled, then labelling)."""
    import dataclasses

    from calib.io.native import read_native, write_native

    out = []
    base = tmp_path_factory.mktemp("calib")
    for seed in (5, 6):
        write_simulation_run("park", small_park_config(), seed, base / f"p{seed}")
        lg = read_native(base / f"p{seed}/log.dlog")
        lg = dataclasses.replace(lg, sensor=updated(lg.sensor, {"range_sigma": None}))
        out.append(write_native(lg, base / f"park{seed}.dlog"))
    return out


@pytest.mark.slow  # a local Dask cluster calibrating several logs
def test_a_calibration_of_several_logs_on_workers_gives_the_serial_bytes(tmp_path, capsys, unstated_sigma_logs, cluster, monkeypatch):
    c, _ = cluster
    logs = [str(p) for p in unstated_sigma_logs]
    outs = {}
    for tag, engine_opts in (("serial", ["--workers", "0"]), ("dask", ["--scheduler", c.scheduler_address])):
        folder = tmp_path / tag
        folder.mkdir()
        monkeypatch.chdir(folder)  # the same command typed in two folders of one depth: the recorded command is the same
        code, out, err = run(capsys, "calibrate", *logs, "--name", "two-parks", "--out", "run", "--profiles-dir", "profiles", *engine_opts)
        assert code == 0, err
        assert ("in this process" if tag == "serial" else f"on the cluster at {c.scheduler_address}") in out
        outs[tag] = folder
    summary = yaml.safe_load((outs["serial"] / "run/summary.yaml").read_text())
    assert summary["range_sigma_source"] == "estimated"
    # the profile records neither --workers nor --scheduler: the same bytes wherever it was computed
    assert results(outs["dask"]) == results(outs["serial"])
    assert "--scheduler" not in (outs["dask"] / "profiles/two-parks@1.0.0.yaml").read_text()
    assert os.listdir(outs["dask"] / "profiles") == ["two-parks@1.0.0.yaml"]


def _http_sockets(dask_scheduler=None, dask_worker=None):
    server = (dask_scheduler or dask_worker).http_server
    return sorted(sock.getsockname()[0] for sock in server._sockets.values())  # noqa: SLF001


def test_the_local_cluster_listens_on_loopback_only():
    from detcal.engine import open_engine

    with open_engine(1, None, 3) as engine:
        client = engine.client
        assert client.scheduler.address.startswith("tcp://127.0.0.1:")
        assert list(client.nthreads().values()) == [1] and all(a.startswith("tcp://127.0.0.1:") for a in client.nthreads())
        # Dask's HTTP endpoints (health, metrics) too, on a free port: never 8787, which another cluster may hold
        assert client.run_on_scheduler(_http_sockets) == ["127.0.0.1"]
        assert list(client.run(_http_sockets).values()) == [["127.0.0.1"]]
        env = client.run(lambda: {k: os.environ.get(k) for k in ("MALLOC_TRIM_THRESHOLD_", "OPENBLAS_NUM_THREADS")})
        assert list(env.values()) == [{"MALLOC_TRIM_THRESHOLD_": None, "OPENBLAS_NUM_THREADS": "1"}]
        # no statistical profiler walking the task's stack; what the tasks import is there before the first task
        assert list(client.run(_worker_state).values()) == [(False, [])]


def _worker_state(dask_worker=None):
    import sys

    from detcal.engine import PRELOAD

    return "profile" in dask_worker.periodic_callbacks, [m for m in PRELOAD if m not in sys.modules]


class _Terminal(io.StringIO):
    def isatty(self) -> bool:
        return True


def test_a_bar_counts_tasks_on_a_terminal_and_nothing_is_drawn_in_ci_or_a_pipe(monkeypatch, capsys):
    from calib.progress import progress

    term = _Terminal()
    monkeypatch.setattr(sys, "stderr", term)
    monkeypatch.delenv("CI", raising=False)
    monkeypatch.setenv("TERM", "xterm")
    assert list(progress(iter(range(3)), 3, "sweep on 2 local workers")) == [0, 1, 2]
    drawn = term.getvalue()
    assert "sweep on 2 local workers" in drawn and "3/3" in drawn  # the last frame: every task counted
    assert capsys.readouterr().out == ""  # on stderr: results on stdout stay clean
    for ci, stream in (("true", _Terminal()), (None, io.StringIO())):  # CI on a terminal; a pipe
        monkeypatch.setattr(sys, "stderr", stream)
        if ci:
            monkeypatch.setenv("CI", ci)
        else:
            monkeypatch.delenv("CI", raising=False)
        assert list(progress(iter(range(3)), 3, "sweep")) == [0, 1, 2]
        assert stream.getvalue() == ""


def test_force_keeps_the_old_sweep_when_the_cluster_refuses(tmp_path, capsys, park_log, serial):
    """--force replaces a sweep only once the engine is up: a scheduler without workers leaves the old results."""
    import shutil

    import dask
    from distributed import LocalCluster

    from detcal.engine import LOCAL_CONFIG

    out = tmp_path / "sw"
    shutil.copytree(serial, out)
    before = results(out)
    with dask.config.set(LOCAL_CONFIG), LocalCluster(n_workers=0, processes=False, protocol="tcp", host="127.0.0.1", dashboard_address=None) as c:
        code, _, err = run(capsys, "slam", "sweep", str(park_log), *SWEEP, "--scheduler", c.scheduler_address, "--out", str(out), "--force")
    assert code == 2
    assert_one_line_error(err, "the cluster has no workers")
    assert results(out) == before
