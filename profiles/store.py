"""Load, save and find detector profiles.

Profiles are addressed as ``name@version`` (the newest version when it is
omitted) or by a file path. The registry searches, in order:

1. the bundled profiles, package data in ``profiles/builtin/*.yaml``;
2. the user folders: ``$DETCAL_PROFILES`` (``os.pathsep``-separated) or, when
   unset, ``$XDG_DATA_HOME/detcal/profiles`` (``~/.local/share/detcal/profiles``).

A profile file is named ``<name>@<version>.yaml``. Writes go to a temporary
file and are renamed into place; an existing ``name@version`` is never
replaced unless asked (``force``).
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass
from pathlib import Path

import yaml
from pydantic import ValidationError

from profiles.atomic import atomic_output
from profiles.errors import DataError, UsageError
from profiles.profile import SCHEMA_VERSION, SUPPORTED_SCHEMAS, V2_FIELDS, DetectorProfile, semver_key

BUILTIN = Path(__file__).resolve().parent / "builtin"


def user_dirs() -> list[Path]:
    env = os.environ.get("DETCAL_PROFILES")
    if env:
        return [Path(p).expanduser() for p in env.split(os.pathsep) if p]
    base = Path(os.environ.get("XDG_DATA_HOME") or Path.home() / ".local" / "share")
    return [base / "detcal" / "profiles"]


def _field_path(loc: tuple) -> str:
    return ".".join(str(p) for p in loc) or "(top level)"


def parse_profile(data: object, where: str) -> DetectorProfile:
    """Validate a loaded document; refuse other schema versions by name.

    Schema 1 documents load as they are: every field schema 2 added is optional
    with a default meaning the schema-1 behaviour (see :mod:`profiles.profile`).
    """
    if not isinstance(data, dict):
        raise DataError(f"{where}: a profile is a mapping at the top level")
    version = data.get("schema_version")
    if version not in SUPPORTED_SCHEMAS or isinstance(version, bool):
        if isinstance(version, int) and not isinstance(version, bool) and version > SCHEMA_VERSION:
            raise DataError(
                f"{where}: schema_version {version} is newer than this detcal reads ({SCHEMA_VERSION}); upgrade detcal"
            )
        raise DataError(
            f"{where}: schema_version {version!r} is not supported; this detcal reads schemas "
            f"{', '.join(map(str, SUPPORTED_SCHEMAS))} and has no migration from it"
        )
    try:
        return DetectorProfile.model_validate(data)
    except ValidationError as exc:
        errs = exc.errors()
        e = errs[0]
        msg = "unknown key" if e["type"] == "extra_forbidden" else e["msg"]
        more = f" (and {len(errs) - 1} more)" if len(errs) > 1 else ""
        raise DataError(f"{where}: {_field_path(e['loc'])}: {msg}{more}") from None


def load_profile_file(path: str | Path) -> DetectorProfile:
    path = Path(path)
    if not path.is_file():
        raise UsageError(f"{path}: no such profile file")
    text = path.read_text(encoding="utf-8")
    try:
        data = json.loads(text) if path.suffix == ".json" else yaml.safe_load(text)
    except (yaml.YAMLError, json.JSONDecodeError) as exc:
        mark = getattr(exc, "problem_mark", None)
        line = f":{mark.line + 1}" if mark is not None else ""
        raise DataError(f"{path}{line}: not valid YAML/JSON ({getattr(exc, 'problem', exc)})") from None
    return parse_profile(data, str(path))


def dump_profile(profile: DetectorProfile, fmt: str = "yaml") -> str:
    """Deterministic text: schema order, floats written exactly (round trip is lossless).

    A schema-1 profile is written without the fields schema 2 added (it cannot
    use them), so it keeps its bytes.
    """
    data = profile.model_dump(mode="json", exclude=V2_FIELDS if profile.schema_version == 1 else None)
    for section in ("noise", "sensors"):  # optional sections: absent rather than null, so older profiles keep their bytes
        if data.get(section) is None:
            data.pop(section, None)
    if fmt == "json":
        return json.dumps(data, indent=2) + "\n"
    if fmt != "yaml":
        raise UsageError(f"--format: expected yaml or json, got {fmt!r}")
    return yaml.safe_dump(data, sort_keys=False, default_flow_style=None, width=100, allow_unicode=True)


def profile_filename(profile: DetectorProfile) -> str:
    return f"{profile.name}@{profile.version}.yaml"


def same_content(a: DetectorProfile, b: DetectorProfile) -> bool:
    """Equal in everything but the creation time."""
    da, db = a.model_dump(mode="json"), b.model_dump(mode="json")
    da["provenance"].pop("created"), db["provenance"].pop("created")
    return da == db


def save_profile(profile: DetectorProfile, folder: str | Path | None = None, *, force: bool = False) -> tuple[Path, str]:
    """Write ``<folder>/<name>@<version>.yaml`` atomically.

    An existing version is never replaced unless ``force``; when it holds the same
    profile (all but the creation time) nothing is written. Returns the path and
    ``"written"``, ``"replaced"`` or ``"unchanged"``.
    """
    folder = Path(folder) if folder is not None else user_dirs()[0]
    path = folder / profile_filename(profile)
    status = "written"
    if path.exists():
        try:
            old = load_profile_file(path)
        except DataError:
            old = None
        if old is not None and same_content(old, profile) and not force:
            return path, "unchanged"
        if not force:
            raise UsageError(f"{path}: profile {profile.ref} exists with other content; bump the version (--version) or use --force")
        status = "replaced"
    text = dump_profile(profile)
    with atomic_output(path, overwrite=force) as tmp:
        with open(tmp, "w", encoding="utf-8") as fh:
            fh.write(text)
            fh.flush()
            os.fsync(fh.fileno())
    return path, status


@dataclass(frozen=True)
class Entry:
    name: str
    version: str
    path: Path
    origin: str  # builtin | user


def registry() -> list[Entry]:
    """Every profile file of the registry (not validated; see :func:`resolve`)."""
    out = []
    for origin, folders in (("builtin", [BUILTIN]), ("user", user_dirs())):
        for folder in folders:
            if not folder.is_dir():
                continue
            for f in sorted(folder.glob("*@*.yaml")):
                if f.name.startswith("."):
                    continue
                name, _, version = f.stem.partition("@")
                try:
                    semver_key(version)
                except ValueError:
                    continue
                out.append(Entry(name, version, f, origin))
    return out


def resolve(ref: str | Path) -> DetectorProfile:
    """A profile from a file path or ``name[@version]`` (newest version when omitted)."""
    ref_s = str(ref)
    p = Path(ref_s)
    if p.suffix in (".yaml", ".yml", ".json") and (p.exists() or os.sep in ref_s):
        return load_profile_file(p)
    name, _, version = ref_s.partition("@")
    cands = [e for e in registry() if e.name == name and (not version or e.version == version)]
    if not cands:
        known = sorted({f"{e.name}@{e.version}" for e in registry()})
        raise UsageError(f"no profile {ref_s!r}; known: {', '.join(known) or 'none'}")
    # newest version; a user profile shadows a bundled one of the same version
    best = max(cands, key=lambda e: (semver_key(e.version), e.origin == "user"))
    prof = load_profile_file(best.path)
    if (prof.name, prof.version) != (best.name, best.version):
        raise DataError(f"{best.path}: holds {prof.ref}, but its file name says {best.name}@{best.version}")
    return prof


def flatten(data: object, prefix: str = "") -> dict[str, object]:
    """Nested mappings/lists -> {"a.b.0": value} for diffs."""
    out: dict[str, object] = {}
    if isinstance(data, dict):
        for k, v in data.items():
            out.update(flatten(v, f"{prefix}{k}."))
    elif isinstance(data, list) and data and any(isinstance(v, dict | list) for v in data):
        for i, v in enumerate(data):
            out.update(flatten(v, f"{prefix}{i}."))
    else:
        out[prefix[:-1]] = data
    return out


def diff_profiles(a: DetectorProfile, b: DetectorProfile) -> list[tuple[str, object, object]]:
    """(field path, value in a, value in b) for every field that differs."""
    fa, fb = flatten(a.model_dump(mode="json")), flatten(b.model_dump(mode="json"))
    keys = sorted(set(fa) | set(fb))
    return [(k, fa.get(k), fb.get(k)) for k in keys if fa.get(k) != fb.get(k)]
