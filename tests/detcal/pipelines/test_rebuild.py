"""Profiles rebuilt from their recorded provenance: the bundled profile to the same bytes, in the suite.

The bundled profile records its command (``make builtin-profile``), its input (the embedded default log, simulated
again from its seed), its creation time and the source commit that wrote it: ``detcal profile rebuild`` checks out
that commit, runs the command as typed and must write the file again byte for byte. The benchmark profiles are
rebuilt by ``make rebuild-profiles`` (Victoria Park self-calibrations: minutes each, on the real log).
"""

from __future__ import annotations

import shutil
import subprocess
from pathlib import Path

import pytest
import yaml

from detcal.cli import main
from detcal.pipelines.rebuild import SOURCE_ROOT, _ups, body, rebuild
from profiles.errors import DataError
from profiles.store import BUILTIN


def _has_commit(commit: str | None) -> bool:
    if commit is None or shutil.which("git") is None or not (SOURCE_ROOT / ".git").exists():
        return False
    return subprocess.run(["git", "cat-file", "-e", f"{commit}^{{commit}}"], cwd=SOURCE_ROOT, capture_output=True).returncode == 0


BUNDLED = sorted(BUILTIN.glob("*.yaml"))


@pytest.mark.slow  # a clone at the recorded commit and a whole calibration
@pytest.mark.parametrize("path", BUNDLED, ids=[p.stem for p in BUNDLED])
def test_every_bundled_profile_is_rebuilt_from_its_provenance_to_the_same_bytes(path, tmp_path, capsys):
    commit = yaml.safe_load(path.read_text())["provenance"].get("commit")
    if not _has_commit(commit):
        pytest.skip(f"the source commit {commit} the profile records is not in this checkout's git history (a release tarball?)")
    before = path.read_bytes()
    code = main(["profile", "rebuild", str(path), "--from", str(SOURCE_ROOT), "--keep", str(tmp_path / "rebuilt.yaml")])
    cap = capsys.readouterr()
    assert code == 0, cap.err
    assert "rebuilt from its provenance: same bytes" in " ".join(cap.out.split())
    assert (tmp_path / "rebuilt.yaml").read_bytes() == before == path.read_bytes()  # and nothing written over the original


def test_a_hand_written_or_dirty_profile_is_not_rebuilt(tmp_path):
    nominal = SOURCE_ROOT / "benchmarks/profiles/victoria-park-nominal@1.0.0.yaml"
    with pytest.raises(DataError, match=r"provenance.command: 'written by hand .*' is not a detcal command"):
        rebuild(nominal, origin=SOURCE_ROOT)
    d = yaml.safe_load((BUILTIN / "sim-park-laser@1.0.0.yaml").read_text())
    d["provenance"]["commit"] = "0" * 40 + "+dirty"
    (tmp_path / "p.yaml").write_text(yaml.safe_dump(d, sort_keys=False))
    with pytest.raises(DataError, match=r"provenance.commit: 0{40}\+dirty was made by a source with uncommitted changes"):
        rebuild(tmp_path / "p.yaml", origin=SOURCE_ROOT)


def test_the_staging_folder_holds_the_commands_parent_paths():
    assert [_ups(p) for p in ("../shared/data/vp", "../../x", "a/b", "./c", "..")] == [1, 2, 0, 0, 1]
    assert body("# a comment\n#\nschema_version: 2\nname: x\n") == "schema_version: 2\nname: x\n"
    assert body(Path(BUILTIN / "sim-park-laser@1.0.0.yaml").read_text()).startswith("schema_version: 3\n")


@pytest.mark.slow  # three short self-calibrations and a checkout (about a minute of CPU)
def test_a_self_calibrated_profile_is_rebuilt_from_its_provenance(tmp_path, capsys, monkeypatch):
    """A profile this source writes (a short self-calibration on a simulated log, from a starting profile and a SLAM
    config in another folder) records enough to be rebuilt byte for byte with one command: its command (paths as
    typed, relative to the working folder), its inputs' digests (the log, the starting profile, the config), its
    seed, its creation time and its source commit. Needs a clean checkout (a dirty one records ``+dirty``)."""
    from calib.io.native import write_native
    from calib.sim.rfs import simulate_rfs
    from profiles.override import updated
    from profiles.store import dump_profile, load_profile_file
    from profiles.version import source_commit
    from tests.detcal.pipelines.test_self_calibration import SIM, nominal

    commit = source_commit()
    if commit is None or commit.endswith("+dirty"):
        pytest.skip(f"the source is not a clean git checkout (commit {commit}): a profile it writes cannot be rebuilt")
    data = tmp_path / "data"
    data.mkdir()
    lp = write_native(simulate_rfs(updated(SIM, {"steps": 120}), 6), data / "sim.dlog")
    (data / "start.yaml").write_text(dump_profile(nominal()))
    (data / "slam.yaml").write_text("particles: 5\nfilter: {kind: rbphd, noise_inflation: 10.0, weighting: marginal}\n")
    work = tmp_path / "work"
    work.mkdir()
    monkeypatch.chdir(work)
    monkeypatch.setenv("SOURCE_DATE_EPOCH", "1764000000")
    args = ["selfcal", "../data/sim.dlog", "--profile", "../data/start.yaml", "--config", "../data/slam.yaml", "--iterations", "2", "--seed", "4"]
    assert main([*args, "--out", "sc", "--profiles-dir", "p", "--name", "sim-selfcal"]) == 0, capsys.readouterr().err
    made = work / "p/sim-selfcal@1.0.0.yaml"
    v = load_profile_file(made).provenance
    assert v.command == "detcal " + " ".join([*args, "--out", "sc", "--profiles-dir", "p", "--name", "sim-selfcal"]) and v.seed == 4
    assert [i.name for i in v.inputs] == ["sim.dlog", "start.yaml", "slam.yaml"] and v.commit == commit
    capsys.readouterr()
    monkeypatch.delenv("SOURCE_DATE_EPOCH")
    assert main(["profile", "rebuild", str(made), "--from", str(work)]) == 0, capsys.readouterr().err
    assert "rebuilt from its provenance: same bytes" in " ".join(capsys.readouterr().out.split())
    # another SLAM config under the same path: the rebuild finds the difference and names it
    (data / "slam.yaml").write_text("particles: 6\nfilter: {kind: rbphd, noise_inflation: 10.0, weighting: marginal}\n")
    done = rebuild(made, origin=work)
    assert done.verdict == "differs" and "provenance.inputs.2.sha256" in [k for k, _, _ in done.differences]
