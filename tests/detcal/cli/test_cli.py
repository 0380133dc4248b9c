"""The CLI: exit codes (0 ok, 1 bad data, 2 usage), one-line messages, never a traceback."""

import re
import subprocess
import sys

import pytest

from detcal.cli import main
from calib.io.registry import read_log
from tests.calib.io.test_carmen import BASE, flaser, write
from tests.calib.io.test_rosbag import write_bag
from tests.conftest import VENDORED


def run(capsys, *argv):
    code = main(list(argv))
    cap = capsys.readouterr()
    return code, cap.out, cap.err


def assert_one_line_error(err: str, needle: str) -> None:
    assert "Traceback" not in err
    lines = [x for x in err.splitlines() if x.strip()]
    assert len(lines) == 1 and lines[0].startswith("detcal: error: ") and needle in lines[0], err


@pytest.mark.parametrize(
    ("extra", "needle"),
    [
        ("FLASER 4 1 2 3", "t.clf:7: FLASER declares 4 beams"),
        (flaser(0.0, [1.0, 2.0, 3.0, 4.0]), "t.clf:7: FLASER time goes backwards"),
        (flaser(1.2, [1.0, 2.0, 3.0, 4.0]).replace("3.00", "nan"), "t.clf:7: range reading: NaN value"),
        (flaser(1.2, [1.0, -2.0, 3.0, 4.0]), "t.clf:7: range reading 2 is negative"),
        (flaser(1.2, [1.0, 2.0, 3.0, 4.0]).replace("1.200000", "1e300", 1), "t.clf:7: timestamp '1e300' is out of range"),
    ],
)
def test_bad_carmen_logs_exit_1(tmp_path, capsys, extra, needle):
    code, _, err = run(capsys, "log", "info", str(write(tmp_path, [*BASE, extra])))
    assert code == 1
    assert_one_line_error(err, needle)


def test_truncated_native_log_exit_1(tmp_path, capsys, small_sim):
    from calib.io.native import write_native

    p = write_native(small_sim.log, tmp_path / "a.dlog")
    (tmp_path / "cut.dlog").write_bytes(p.read_bytes()[:5000])
    code, _, err = run(capsys, "log", "info", str(tmp_path / "cut.dlog"))
    assert code == 1
    assert_one_line_error(err, "cut.dlog: not a detcal log or truncated")


def test_usage_errors_exit_2(tmp_path, capsys):
    bag = write_bag(tmp_path / "a.bag", True)
    code, _, err = run(capsys, "log", "info", str(bag), "--scan-topic", "/nope")
    assert code == 2
    assert_one_line_error(err, "unknown scan topic '/nope'")
    code, _, err = run(capsys, "log", "info", str(tmp_path / "missing.clf"))
    assert code == 2
    assert_one_line_error(err, "missing.clf: no such file or folder")
    code, _, err = run(capsys, "log", "convert", str(bag), str(tmp_path / "x.txt"))
    assert code == 2
    assert_one_line_error(err, "cannot tell the output format")
    (tmp_path / "c.yaml").write_text("laser: {beams: 3}\n")
    code, _, err = run(capsys, "simulate", "park", "--out", str(tmp_path / "s"), "--config", str(tmp_path / "c.yaml"))
    assert code == 2
    assert_one_line_error(err, "c.yaml: laser.beams: unknown key")
    assert not (tmp_path / "s").exists()
    code, _, err = run(capsys, "log", "info", str(bag), "--no-such-option")
    assert code == 2 and "Traceback" not in err and "No such option" in err


def test_convert_round_trip_and_no_silent_overwrite(tmp_path, capsys):
    src = VENDORED / "utias_dataset1"
    code, out, _ = run(capsys, "log", "convert", str(src), str(tmp_path / "u.dlog"))
    assert code == 0 and "wrote" in out
    code, _, _ = run(capsys, "log", "convert", str(tmp_path / "u.dlog"), str(tmp_path / "ubag"))
    assert code == 0
    before = (tmp_path / "u.dlog").read_bytes()
    code, _, err = run(capsys, "log", "convert", str(tmp_path / "ubag"), str(tmp_path / "u.dlog"))
    assert code == 2
    assert_one_line_error(err, "u.dlog: already exists (use --force to replace it)")
    assert (tmp_path / "u.dlog").read_bytes() == before
    code, _, _ = run(capsys, "log", "convert", str(tmp_path / "ubag"), str(tmp_path / "u.dlog"), "--force")
    assert code == 0 and (tmp_path / "u.dlog").read_bytes() == before  # bag -> native gives the same bytes
    assert len(read_log(tmp_path / "u.dlog").detections) == 49


@pytest.mark.slow  # the installed console script in fresh interpreters
def test_simulate_and_info_through_the_console_script(tmp_path):
    cfg = tmp_path / "small.yaml"
    cfg.write_text("width: 40\nheight: 30\ntrees: {count: 10}\nbushes: {count: 2}\nwalls: {count: 1, max_length: 6}\nposts: {count: 2}\npath: {margin: 6}\n")
    exe = [sys.executable, "-c", "from detcal.cli import run; run()"]
    r = subprocess.run([*exe, "simulate", "park", "--seed", "3", "--out", str(tmp_path / "s"), "--config", str(cfg)], capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    assert sorted(p.name for p in (tmp_path / "s").iterdir()) == [".detcal-output", "config.yaml", "log.dlog", "overview.png", "summary.yaml", "warnings.yaml", "world.yaml"]
    r = subprocess.run([*exe, "log", "info", str(tmp_path / "s/log.dlog")], capture_output=True, text=True)
    assert r.returncode == 0 and "361 beams" in r.stdout and "ground_truth" in r.stdout
    r = subprocess.run([*exe, "simulate", "park", "--out", str(tmp_path / "s")], capture_output=True, text=True)
    assert r.returncode == 2 and "already exists" in r.stderr and "Traceback" not in r.stderr
    r = subprocess.run([*exe, "--help"], capture_output=True, text=True)
    assert r.returncode == 0 and "simulate" in r.stdout


@pytest.mark.parametrize("cmd", [["log", "info"], ["log", "convert"], ["simulate", "park"], ["log"], ["simulate"], ["slam"], ["slam", "run"], ["slam", "sweep"]])
def test_every_command_has_help(capsys, cmd):
    code, out, _ = run(capsys, *cmd, "--help")
    assert code == 0 and "Usage" in out


def _commands(cmd, path=()):
    yield path, cmd
    for name, sub in getattr(cmd, "commands", {}).items():
        yield from _commands(sub, (*path, name))


def test_help_lists_each_options_choices_from_the_registries(capsys):
    """Every option with a fixed set of values shows them (read from the registries), no help shows typer's `<str>`."""
    from calib.io.registry import READERS
    from detcal.cli import command
    from slam_runtime.mapfilter import MAP_FILTERS

    code, out, _ = run(capsys, "slam", "run", "--help")
    assert code == 0 and f"--filter [{'|'.join(MAP_FILTERS.names())}]" in out and "--pd-mode [profile|constant]" in out
    code, out, _ = run(capsys, "log", "info", "--help")
    assert code == 0 and f"--format [{'|'.join(READERS.names())}]" in out and "--laser [front|rear]" in out
    code, out, _ = run(capsys, "calibrate", "--help")
    assert code == 0 and "--poses [auto|reference|icp]" in out
    for path, _cmd in _commands(command()):
        if path:
            code, out, _ = run(capsys, *path, "--help")
            assert code == 0 and not re.search(r"<(str|int|float|path|list\[\w+\])>", out), (path, out)
