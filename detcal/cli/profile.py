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
            held = load_profile_file(e.path).ref
        except DetcalError as exc:
            msg = re.sub(rf"^{re.escape(str(e.path))}(?::(\d+))?: ", lambda m: f"line {m[1]}: " if m[1] else "", " ".join(str(exc).split()))
            status = f"unreadable ({msg})"
        else:
            if held != f"{e.name}@{e.version}":
                status = f"holds {held}, not what its file name says"
        t.add_row(f"{e.name}@{e.version}", e.origin, str(e.path), status)
    out.print(t)


@app.command("show")
def profile_show(ref: ProfileArg) -> None:
    """Print a profile as YAML."""
    from profiles.store import dump_profile, resolve

    sys.stdout.write(dump_profile(resolve(ref)))


@app.command("validate")
def profile_validate(path: Annotated[Path, typer.Argument(metavar="FILE", help="A profile file (YAML or JSON).")]) -> None:
    """Check a profile file against the schema; errors name the field path."""
    from profiles.store import load_profile_file

    p = load_profile_file(path)
    out.print(f"{path}: valid profile {p.ref} (schema {p.schema_version})")


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
