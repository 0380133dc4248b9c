"""``detcal profile ...``: list, show, validate, diff, export and the schema."""

from __future__ import annotations

import os
import re
import sys
from pathlib import Path
from typing import Annotated

import typer
from rich.table import Table

from detcal.cli.common import out, warn
from profiles.errors import UsageError

app = typer.Typer(help="List, show, validate, compare and export detector profiles.", no_args_is_help=True, rich_markup_mode=None)

ProfileArg = Annotated[str, typer.Argument(metavar="PROFILE", help="name or name@version, or a file.")]


@app.command("list")
def profile_list() -> None:
    """List the bundled and user profiles (name@version, origin, file, and which file wins when several share a
    name@version); a file that does not load, or holds another profile than its name says, is marked so."""
    from profiles.errors import DetcalError
    from profiles.profile import SCHEMA_VERSION
    from profiles.store import load_profile_file, registry, user_dirs

    for d in user_dirs():  # a folder the registry cannot look into would otherwise just list nothing
        if d.exists() and not d.is_dir():
            warn(f"{d}: a user profile folder is a file; skipped")
        elif d.is_dir() and not os.access(d, os.R_OK | os.X_OK):
            warn(f"{d}: a profile folder that cannot be read; its profiles are not listed")
    t = Table(title="detector profiles (user folders: " + ", ".join(str(d) for d in user_dirs()) + ")")
    for col in ("profile", "origin", "file", "status"):
        t.add_column(col, overflow="fold")
    for e in registry():
        status = "active" if e.shadowed_by is None else f"shadowed by {e.shadowed_by}"
        try:
            prof = load_profile_file(e.path, migrate=False)
            held = prof.ref
            if prof.schema_version < SCHEMA_VERSION:
                status += f" (schema {prof.schema_version}, migrated when loaded: detcal profile migrate)"
        except DetcalError as exc:
            msg = re.sub(rf"^{re.escape(str(e.path))}(?::(\d+))?: ", lambda m: f"line {m[1]}: " if m[1] else "", " ".join(str(exc).split()))
            status = f"unreadable ({msg})"
        else:
            if held != f"{e.name}@{e.version}":
                status = f"holds {held}, not what its file name says"
        t.add_row(f"{e.name}@{e.version}", e.origin, str(e.path), status)
    out.print(t)


@app.command("show")
def profile_show(
    ref: ProfileArg,
    as_yaml: Annotated[bool, typer.Option("--yaml", help="Print the profile file's YAML instead of tables.")] = False,
) -> None:
    """Show a profile as tables: what it is and how it was made, its quantities with their units, the P_D table one
    bin per row."""
    from profiles.store import dump_profile, resolve

    prof = resolve(ref)
    if as_yaml:
        sys.stdout.write(dump_profile(prof))
        return
    for table in profile_tables(prof):
        out.print(table)


def profile_tables(prof) -> list[Table]:
    """A profile as rich tables: (1) every quantity outside the P_D table, with its unit, (2) the P_D table."""
    from pydantic import BaseModel

    from profiles.store import comparable
    from profiles.units import unit

    doc = comparable(prof)
    fields = Table(title=f"{prof.ref} ({prof.kind}){': ' + prof.description if prof.description else ''}")
    fields.add_column("field", no_wrap=True)
    fields.add_column("value", overflow="fold")
    fields.add_column("unit", overflow="fold")

    def walk(model: BaseModel, data: dict, prefix: str) -> None:
        for key, value in data.items():
            sub = getattr(model, key, None)
            if key in ("bins", "parameters") or value is None or value in ({}, []):
                continue
            if isinstance(sub, BaseModel) and isinstance(value, dict):
                walk(sub, value, f"{prefix}{key}.")
            else:
                fields.add_row(prefix + key, _cell(value), unit(type(model).__name__, key, data) or "")

    walk(prof, doc, "")
    bins = doc["pd"]["bins"]
    covariate = prof.pd.covariate
    pd = Table(title=f"P_D against {covariate} [{unit('PdTable', 'edges', {'covariate': covariate})}]: one row per bin")
    cols = [c for c in bins[0] if c not in ("from", "to")]
    for col in (covariate, *cols):
        pd.add_column(col, justify="right")
    pd.caption = "units: " + "; ".join(f"{c} [{unit('PdTable', c, {'covariate': covariate})}]" for c in cols)
    for b in bins:
        pd.add_row(f"[{_cell(b['from'])}, {_cell(b['to'])})", *(_cell(b[c]) for c in cols))
    return [fields, pd]


def _cell(v) -> str:
    if isinstance(v, float):
        return f"{v:.6g}"
    if isinstance(v, list):
        return "[" + ", ".join(_cell(x) for x in v) + "]"
    if isinstance(v, dict):
        return ", ".join(f"{k}: {_cell(x)}" for k, x in v.items())
    return str(v)


@app.command("validate")
def profile_validate(path: Annotated[Path, typer.Argument(metavar="FILE", help="A profile file (YAML or JSON).")]) -> None:
    """Check a profile file against the schema; errors name the field path."""
    from profiles.store import load_profile_file, migrated

    as_written = load_profile_file(path, migrate=False)  # an earlier schema's: validated as it is, then migrated
    p, written = migrated(as_written, str(path)), as_written.schema_version  # (the migration said in one warning)
    out.print(f"{path}: valid profile {p.ref} (schema {written}" + (f", migrated to {p.schema_version} when loaded)" if written != p.schema_version else ")"))


@app.command("migrate")
def profile_migrate(
    path: Annotated[Path, typer.Argument(metavar="FILE", help="A profile file of an earlier schema (YAML or JSON).")],
    dest: Annotated[
        Path | None, typer.Option("--out", help="The migrated profile's file (default: FILE's name with .migrated before its suffix); never replaced.")
    ] = None,
) -> None:
    """Write a profile of an earlier schema as the current schema, to a new file (FILE is left as it is).

    Each step and what it changes is in the profile reference (docs/reference/profile.md, "Schema versions and
    migration"); the numbers and the recorded provenance are kept."""
    from profiles.atomic import atomic_output
    from profiles.profile import SCHEMA_VERSION
    from profiles.store import dump_profile, load_profile_file, migrated, profile_filename, same_content

    old = load_profile_file(path, migrate=False)
    if old.schema_version == SCHEMA_VERSION:
        out.print(f"{path}: already schema {SCHEMA_VERSION}; nothing to migrate, nothing written")
        return
    new = migrated(old, str(path), notify=False)
    if dest is None:
        dest = path.with_name(f"{path.stem}.migrated{path.suffix or '.yaml'}")
    if dest.suffix == ".yaml" and "@" in dest.stem and dest.name != profile_filename(new):
        raise UsageError(f"{dest}: the profile store reads a file named name@version.yaml as that profile; name it {profile_filename(new)} or without '@'")
    if os.path.lexists(dest):
        raise UsageError(f"{dest}: exists; a migrated profile is never written over a file: give another --out")
    text = dump_profile(new, "json" if dest.suffix == ".json" else "yaml")
    if dest.suffix != ".json":  # a comment a person wrote above the document is kept above it
        from profiles.document import body

        original = path.read_text(encoding="utf-8")
        text = original[: len(original) - len(body(original))] + text
    with atomic_output(dest, overwrite=False) as tmp:
        tmp.write_text(text)
    # what was written reads back as the same profile (the written figures are rounded within the store's tolerance)
    back = load_profile_file(dest)
    if not same_content(back, new):
        raise AssertionError(f"{dest}: the migrated profile does not read back as the profile migrated")
    out.print(f"wrote {dest}: {new.ref} migrated from schema {old.schema_version} to schema {SCHEMA_VERSION}")


@app.command("rebuild")
def profile_rebuild(
    path: Annotated[Path, typer.Argument(metavar="FILE", help="A profile file whose provenance records a detcal command.")],
    origin: Annotated[
        Path, typer.Option("--from", help="The working folder the recorded command ran in: its relative paths are read from here.")
    ] = Path("."),
    keep: Annotated[Path | None, typer.Option("--keep", help="Also write the rebuilt profile here (never over a file).")] = None,
) -> None:
    """Rebuild a profile from its provenance (its command, inputs, creation time and source commit) and compare it
    with FILE byte for byte; exit 1 when it differs. Nothing is written beside FILE: the command runs in a
    temporary folder (with the recorded commit's source when the profile records one)."""
    from detcal.pipelines.rebuild import keep as keep_rebuilt
    from detcal.pipelines.rebuild import rebuild
    from profiles.errors import DataError

    if keep is not None and os.path.lexists(keep):
        raise UsageError(f"{keep}: exists; a rebuilt profile is never written over a file")
    done = rebuild(path, origin=origin)
    if keep is not None:
        keep_rebuilt(done, keep)
    for note in done.notes:
        warn(f"{path}: {note}")
    if done.verdict == "differs":
        first = ", ".join(f"{k}: {_short(a)} -> {_short(b)}" for k, a, b in done.differences[:3])
        raise DataError(f"{path}: rebuilt from its provenance, {len(done.differences)} fields differ ({first}{', ...' if len(done.differences) > 3 else ''})")
    out.print(f"{path}: rebuilt from its provenance: {done.verdict}")


@app.command("diff")
def profile_diff(
    a: Annotated[str, typer.Argument(metavar="A", help="name or name@version, or a file.")],
    b: Annotated[str, typer.Argument(metavar="B", help="name or name@version, or a file.")],
) -> None:
    """Show the fields in which two profiles differ."""
    from profiles.store import diff_profiles, resolve

    pa, pb = resolve(a), resolve(b)
    rows = diff_profiles(pa, pb)
    if not rows:
        out.print(f"{pa.ref} and {pb.ref} are identical")
        return
    t = Table(title=f"{pa.ref} -> {pb.ref}: {len(rows)} fields differ")
    for col in ("field", pa.ref, pb.ref):
        t.add_column(col, overflow="fold")
    for k, va, vb in rows:
        t.add_row(k, _short(va), _short(vb))
    out.print(t)


def _short(v) -> str:
    if isinstance(v, float):
        return f"{v:.6g}"
    if isinstance(v, list):
        return "[" + ", ".join(_short(x) for x in v[:8]) + (", ..." if len(v) > 8 else "") + "]"
    return "-" if v is None else str(v)


@app.command("export")
def profile_export(
    ref: ProfileArg,
    export_fmt: Annotated[str, typer.Option("--format", help="yaml or json.")] = "yaml",
    dest: Annotated[Path | None, typer.Option("--out", help="Write here instead of standard output (never replaced without --force).")] = None,
    force: Annotated[bool, typer.Option(help="Replace --out if it exists.")] = False,
) -> None:
    """Export a profile as YAML or JSON."""
    from profiles.atomic import atomic_output
    from profiles.store import dump_profile, looks_like_profile, profile_filename, resolve

    prof = resolve(ref)
    text = dump_profile(prof, export_fmt)
    if dest is not None and dest.suffix == ".yaml" and "@" in dest.stem and dest.name != profile_filename(prof):
        # the registry reads a profile file as the name@version its file name says
        raise UsageError(
            f"{dest}: a file named {dest.stem} would hold {prof.name}@{prof.version}, and the profile store reads a file as the "
            f"profile its name says; name it {profile_filename(prof)} or without '@'"
        )
    if dest is None:
        sys.stdout.write(text)
        return
    with atomic_output(dest, overwrite=force, owned=looks_like_profile) as tmp:
        tmp.write_text(text)
    out.print(f"wrote {dest}")


@app.command("schema")
def profile_schema() -> None:
    """Print the JSON Schema of a detector profile."""
    import json

    from profiles.profile import DetectorProfile

    sys.stdout.write(json.dumps(DetectorProfile.model_json_schema(), indent=2) + "\n")
