"""Profiles written by earlier builds load in this release, migrated step by step to the current schema.

The corpus (tests/data/profiles-legacy/, its README names the commit and path of each file) holds every bundled and
benchmark profile as earlier commits of this repository held it: schema 1 from before the provenance recorded
``parameters.landmarks``, schema 2 with and without the later optional fields. What a migration changes is
documented in :mod:`profiles.migrate` (and docs/reference/profile.md): the schema number, nothing else.
"""

from __future__ import annotations

from pathlib import Path

import pytest
import yaml

from detcal.cli import main
from profiles.migrate import MIGRATIONS, migrate_document
from profiles.notices import collected
from profiles.override import updated
from profiles.profile import SCHEMA_VERSION, SUPPORTED_SCHEMAS
from profiles.store import comparable, dump_profile, load_profile_file, same_content

CORPUS = Path(__file__).resolve().parents[1] / "data" / "profiles-legacy"
FILES = sorted(CORPUS.glob("*.yaml"))


def test_the_corpus_holds_every_earlier_schema_and_a_calibration_before_landmarks_were_recorded():
    schemas = {yaml.safe_load(f.read_text())["schema_version"] for f in FILES}
    assert schemas == set(SUPPORTED_SCHEMAS) - {SCHEMA_VERSION}
    calibrations = [yaml.safe_load(f.read_text())["provenance"]["parameters"] for f in FILES if "sim-park-laser" in f.name]
    assert any("landmarks" not in p for p in calibrations) and any("landmarks" in p for p in calibrations)
    assert set(MIGRATIONS) == set(SUPPORTED_SCHEMAS) - {SCHEMA_VERSION}  # one step from every earlier schema


@pytest.mark.parametrize("path", FILES, ids=[f.stem for f in FILES])
def test_every_legacy_profile_loads_and_migrates_to_the_same_content(path, tmp_path, capsys):
    as_written = load_profile_file(path, migrate=False)
    assert as_written.schema_version < SCHEMA_VERSION
    with collected() as lines:
        migrated = load_profile_file(path)
    assert len(lines) == 1 and f"profile schema {as_written.schema_version} migrated to schema {SCHEMA_VERSION}" in lines[0]
    # documented: the schema number is all a migration changes (the provenance kept as recorded, commit unknown)
    assert migrated == updated(as_written, {"schema_version": SCHEMA_VERSION})
    assert migrated.provenance.commit is None and migrated.provenance.packages == {}
    assert migrated.provenance.parameters == yaml.safe_load(path.read_text())["provenance"]["parameters"]

    # detcal profile migrate: a new file, the old one untouched, the new one loads without a migration
    before = path.read_bytes()
    dest = tmp_path / "m.yaml"
    assert main(["profile", "migrate", str(path), "--out", str(dest)]) == 0
    assert path.read_bytes() == before
    cap = capsys.readouterr()
    assert f"migrated from schema {as_written.schema_version} to schema {SCHEMA_VERSION}" in " ".join(cap.out.split()) and cap.err == ""
    back = load_profile_file(dest, notify=False)
    assert back.schema_version == SCHEMA_VERSION and same_content(back, migrated)
    assert dest.read_text().endswith(dump_profile(back))  # the current schema's own bytes (below a comment kept from the old file)
    assert main(["profile", "migrate", str(dest), "--out", str(tmp_path / "again.yaml")]) == 0 and not (tmp_path / "again.yaml").exists()
    # the rounded figures differ from the old ones by less than the store's tolerance, every other value not at all
    old, new = comparable(as_written), comparable(back)
    assert old.pop("schema_version") == as_written.schema_version and new.pop("schema_version") == SCHEMA_VERSION


def test_a_command_says_a_migration_in_one_warning_and_never_writes_over_a_file(tmp_path, capsys):
    src = FILES[0]
    assert main(["profile", "validate", str(src)]) == 0
    cap = capsys.readouterr()
    warnings = [x for x in cap.err.splitlines() if x.strip()]
    assert len(warnings) == 1 and warnings[0].startswith(f"detcal: warning: {src}: profile schema 1 migrated to schema {SCHEMA_VERSION}")
    assert "schema 1, migrated to 3 when loaded" in " ".join(cap.out.split())
    (tmp_path / "taken.yaml").write_text("mine\n")
    assert main(["profile", "migrate", str(src), "--out", str(tmp_path / "taken.yaml")]) == 2
    assert "exists; a migrated profile is never written over a file" in capsys.readouterr().err
    assert (tmp_path / "taken.yaml").read_text() == "mine\n"


def test_the_migration_chain_refuses_a_step_that_forgets_its_number(monkeypatch):
    monkeypatch.setitem(MIGRATIONS, 1, lambda doc: doc)
    with pytest.raises(AssertionError, match="migration step 1 wrote schema_version 1"):
        migrate_document({"schema_version": 1}, SCHEMA_VERSION)
