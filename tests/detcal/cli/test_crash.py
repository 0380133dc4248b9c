"""kill -9 at several points of a calibrate, a profile export and a forced slam run.

After every kill: what stands at an output's name is whole -- the old output
or the new one, or (only in the moment a folder is moved aside on systems
without an atomic swap) nothing -- never a partial one; the profile store
lists only whole profiles; and a rerun works, gives the same bytes as an
uninterrupted run and leaves no temporary behind.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest
import yaml

from detcal.cli import main
from calib.io.native import write_native
from profiles.atomic import MARKER
from profiles.store import load_profile_file, same_content
from tests.calib.test_calibrate import park
from tests.conftest import ROOT

SIGKILL_EXIT = -9


def killed(argv: list[str], target: str, when: str = "after", call: int = 1, no_exchange: bool = False) -> None:
    """Run detcal in a subprocess armed to SIGKILL itself at ``target``; the kill must happen."""
    spec = {"argv": [str(a) for a in argv], "kill": {"target": target, "call": call, "when": when}, "no_exchange": no_exchange}
    r = subprocess.run([sys.executable, "-m", "tests.detcal.cli.crash_driver", json.dumps(spec)], cwd=ROOT, capture_output=True, text=True, env=os.environ.copy(), check=False)
    assert r.returncode == SIGKILL_EXIT, f"the kill at {target} did not happen (exit {r.returncode}): {r.stderr[-2000:]}"


def leftovers(*folders: Path) -> list[str]:
    return [p.name for f in folders if f.is_dir() for p in f.iterdir() if p.name.endswith(".part")]


def same(a: Path | bytes, b: Path | bytes) -> bool:
    """Two profiles with the same content (the command line, which names the output folders, aside)."""
    from profiles.store import parse_profile

    docs = [yaml.safe_load(x.read_bytes() if isinstance(x, Path) else x) for x in (a, b)]
    return same_content(parse_profile(docs[0], "a"), parse_profile(docs[1], "b"))


def whole_run_folder(path: Path, profile: bytes) -> bool:
    """A run folder detcal finished: its marker, and the expected profile."""
    return (path / MARKER).is_file() and same(path / "profile.yaml", profile)


@pytest.fixture(scope="module")
def logs(tmp_path_factory):
    d = tmp_path_factory.mktemp("crash")
    (d / "c.yaml").write_text("pd: {min_count: 30}\n")
    a = write_native(park(41, 0.5), d / "a.dlog")
    b = write_native(park(42, 0.5), d / "b.dlog")
    # the uninterrupted run, for comparison
    assert main(["calibrate", str(a), "--name", "crash", "--config", str(d / "c.yaml"), "--profiles-dir", str(d / "ref"), "--out", str(d / "ref_run")]) == 0
    return d, a, b, (d / "ref/crash@1.0.0.yaml").read_bytes()


@pytest.mark.slow  # a calibration killed at several points in fresh interpreters (tens of CPU seconds)
def test_calibrate_killed_at_several_points(tmp_path, logs):
    d, a, b, ref = logs
    profiles, run = tmp_path / "profiles", tmp_path / "run"
    common = ["--name", "crash", "--config", d / "c.yaml", "--profiles-dir", profiles, "--out", run]
    args = ["calibrate", a, *common]
    prof = profiles / "crash@1.0.0.yaml"
    # 1. during the computation: nothing written
    killed(args, "calib.calibrate:label_log", "before")
    assert not run.exists() and not prof.exists()
    # 2. half-way through the run folder's figures: only a hidden temporary
    killed(args, "detcal.reports.calibration:plot_roc")
    assert not run.exists() and not prof.exists() and leftovers(tmp_path)
    # 3. after the run folder is in place, before the profile: the folder is whole, the store has nothing
    killed(args, "profiles.atomic:_Staged.install")
    assert whole_run_folder(run, ref) and not prof.exists()
    # a rerun works: the run folder is the same request (left alone), the profile is written
    assert main([str(x) for x in args]) == 0
    assert same(prof, ref) and prof.read_bytes() == (run / "profile.yaml").read_bytes()
    assert leftovers(tmp_path, profiles) == []

    # --force over these outputs with another log: the old ones stay whole until the new ones are complete
    forced = ["calibrate", b, *common, "--force"]
    old = prof.read_bytes()
    # 4. the folder swapped in one step (renameat2), then killed before the profile: new folder, old profile
    killed(forced, "profiles.atomic:_Staged.install")
    new_run = (run / "profile.yaml").read_bytes()
    assert not same(new_run, old) and whole_run_folder(run, new_run) and prof.read_bytes() == old
    assert "b.dlog" in new_run.decode()
    # 5. without an atomic swap, killed between moving the old folder aside and the new one in: no folder
    # stands there (the old one waits, hidden, beside it); the profile is still the old, whole one
    killed(forced, "os:rename", no_exchange=True)
    assert not run.exists() and prof.read_bytes() == old and leftovers(tmp_path)
    assert load_profile_file(prof).ref == "crash@1.0.0"
    assert main([str(x) for x in forced]) == 0
    assert prof.read_bytes() == (run / "profile.yaml").read_bytes() == new_run
    assert leftovers(tmp_path, profiles) == []


def test_profile_export_killed(tmp_path, logs):
    d, *_ = logs
    src = d / "ref/crash@1.0.0.yaml"
    out = tmp_path / "exported.json"
    assert main(["profile", "export", str(src), "--format", "json", "--out", str(out)]) == 0
    old = out.read_bytes()
    args = ["profile", "export", src, "--format", "yaml", "--out", out, "--force"]
    killed(args, "pathlib:Path.write_text", "half")  # half of the new text written, then killed
    assert out.read_bytes() == old
    killed(args, "os:replace", "before")  # complete, not yet moved over the old one
    assert out.read_bytes() == old and json.loads(old)["name"] == "crash"
    assert main([str(x) for x in args]) == 0
    assert out.read_bytes() == src.read_bytes() and leftovers(tmp_path) == []


@pytest.mark.slow  # a SLAM run killed in a fresh interpreter
def test_forced_slam_run_killed(tmp_path, logs):
    d, a, *_ = logs
    run, ref = tmp_path / "run", tmp_path / "ref"
    base = ["slam", "run", str(a), "--profile", str(d / "ref/crash@1.0.0.yaml"), "--frames", "15"]
    assert main([*base, "--seed", "1", "--out", str(run)]) == 0
    assert main([*base, "--seed", "2", "--out", str(ref)]) == 0  # the uninterrupted forced run's outputs
    old = (run / "trajectory.csv").read_bytes()
    forced = [*base, "--seed", "2", "--out", run, "--force"]
    killed(forced, "detcal.reports.slam_run:_figures", "before")  # tables written to the temporary, no figures
    assert (run / "trajectory.csv").read_bytes() == old and (run / "ospa.png").is_file()
    killed(forced, "os:rename", no_exchange=True)
    assert not run.exists() and leftovers(tmp_path)
    assert main([str(x) for x in forced]) == 0
    for name in ("trajectory.csv", "map.csv"):  # (metrics.yaml also holds the time per step)
        assert (run / name).read_bytes() == (ref / name).read_bytes()
    assert leftovers(tmp_path) == []
