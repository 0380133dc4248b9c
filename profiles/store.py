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
import math
import os
from dataclasses import dataclass
from pathlib import Path

import yaml
from pydantic import ValidationError

from profiles import strict_yaml
from profiles.atomic import atomic_output
from profiles.errors import DataError, DetcalError, UsageError
from profiles.document import columns_from_bins, render, written
from profiles.migrate import migrate_document
from profiles.migrate import notify as migration_notice
from profiles.notices import notice
from profiles.plausibility import refusal, suspicions
from profiles.profile import DETECTOR_KINDS, LATER_OPTIONAL, SCHEMA_VERSION, SUPPORTED_SCHEMAS, V2_FIELDS, V3_FIELDS, DetectorProfile, semver_key
from profiles.provenance import parameter_models

BUILTIN = Path(__file__).resolve().parent / "builtin"


def user_dirs() -> list[Path]:
    env = os.environ.get("DETCAL_PROFILES")
    if env:
        return [Path(p).expanduser() for p in env.split(os.pathsep) if p]
    base = Path(os.environ.get("XDG_DATA_HOME") or Path.home() / ".local" / "share")
    return [base / "detcal" / "profiles"]


def _field_path(loc: tuple) -> str:
    return ".".join(str(p) for p in loc) or "(top level)"


def _check_parameters(prof: DetectorProfile, where: str) -> None:
    """The recorded parameters must fit one of the models of the way this detcal makes such profiles
    (:mod:`profiles.provenance`); a profile written by hand (none recorded) or by another detcal version is kept as
    recorded. So is one whose record only lacks keys this detcal records (written by an earlier build of the same
    version, before those keys were recorded: its statistics are what they were, its record says less): a misspelt
    key or a wrong value is refused, a missing one is not (a profile once written keeps loading)."""
    models = parameter_models(prof.detector.kind, prof.provenance.detcal_version)
    if not models or not prof.provenance.parameters:
        return
    closest = None
    for model in models:
        try:
            model.model_validate(prof.provenance.parameters)
            return
        except ValidationError as exc:
            if all(e["type"] == "missing" for e in exc.errors()):
                return
            if closest is None or exc.error_count() < closest.error_count():
                closest = exc
    e = next(x for x in closest.errors() if x["type"] != "missing")  # what is wrong, rather than what is not recorded
    msg = "unknown key" if e["type"] == "extra_forbidden" else e["msg"]
    raise DataError(f"{where}: provenance.parameters.{_field_path(e['loc'])}: {msg}") from None


def parse_profile(data: object, where: str, *, migrate: bool = True, notify: bool = True) -> DetectorProfile:
    """Validate a loaded document; refuse other schema versions by name.

    A document of an earlier schema is validated as what it says it is, then (``migrate``) taken to the current
    schema by the steps of :mod:`profiles.migrate`, which (``notify``) says so in one line to its listeners;
    ``migrate=False`` gives the profile as its schema has it.
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
    data = columns_from_bins(data, where)
    try:
        prof = DetectorProfile.model_validate(data)
    except ValidationError as exc:
        errs = exc.errors()
        e = errs[0]
        msg = "unknown key" if e["type"] == "extra_forbidden" else e["msg"]
        if e["type"] == "value_error" and "error" in e.get("ctx", {}):
            msg = str(e["ctx"]["error"])  # a model's own check: its text names the fields, without pydantic's "Value error, "
        more = f" (and {len(errs) - 1} more)" if len(errs) > 1 else ""
        raise DataError(f"{where}: {_field_path(e['loc'])}: {msg}{more}") from None
    _check_parameters(prof, where)
    bad = refusal(prof)
    if bad is not None:
        raise DataError(f"{where}: {bad[0]}: {bad[1]}")
    if notify:
        for line in suspicions(prof):
            notice(f"{where}: {line}")
    return migrated(prof, where, notify=notify) if migrate else prof


def migrated(prof: DetectorProfile, where: str, *, notify: bool = True) -> DetectorProfile:
    """``prof`` (read from ``where``) as the current schema: migrated when it is an earlier schema's (said in one
    notice unless ``notify`` is False), else itself."""
    if prof.schema_version >= SCHEMA_VERSION:
        return prof
    old = prof.schema_version
    prof = DetectorProfile.model_validate(migrate_document(prof.model_dump(mode="json"), SCHEMA_VERSION))
    if notify:
        migration_notice(where, old, SCHEMA_VERSION)
    return prof


def load_profile_file(path: str | Path, *, migrate: bool = True, notify: bool = True) -> DetectorProfile:
    """The profile in the file ``path`` (an earlier schema's migrated, see :func:`parse_profile`)."""
    path = Path(path)
    if not path.is_file():
        raise UsageError(f"{path}: no such profile file")
    return parse_profile(read_document(path), str(path), migrate=migrate, notify=notify)


def read_document(path: Path) -> object:
    """A YAML (or ``.json``) document; unreadable text is a DataError naming the file (and line)."""
    try:
        text = path.read_text(encoding="utf-8")
    except UnicodeDecodeError as exc:
        raise DataError(f"{path}: not UTF-8 text (byte {exc.start})") from None
    except OSError as exc:
        raise DataError(f"{path}: cannot read ({exc.strerror or exc})") from None
    try:
        return json.loads(text, object_pairs_hook=_unique_keys) if path.suffix == ".json" else strict_yaml.load(text)
    except (yaml.YAMLError, json.JSONDecodeError) as exc:
        mark = getattr(exc, "problem_mark", None)
        line = f":{mark.line + 1}" if mark is not None else (f":{exc.lineno}" if isinstance(exc, json.JSONDecodeError) else "")
        raise DataError(f"{path}{line}: not valid YAML/JSON ({getattr(exc, 'problem', None) or getattr(exc, 'msg', exc)})") from None
    except _DuplicateKey as exc:
        raise DataError(f"{path}: not valid JSON ({exc})") from None
    except (RecursionError, ValueError) as exc:
        raise DataError(f"{path}: not valid YAML/JSON ({type(exc).__name__})") from None


class _DuplicateKey(ValueError):
    pass


def _unique_keys(pairs: list[tuple[str, object]]) -> dict:
    """A JSON object refusing a key given twice (json keeps the last one without a word)."""
    out: dict = {}
    for k, v in pairs:
        if k in out:
            raise _DuplicateKey(f"key {k!r} is given twice in one object")
        out[k] = v
    return out


def looks_like_profile(path: Path) -> bool:
    """True for a file detcal wrote as a profile (YAML or JSON with schema_version, name and version); ``--force`` may replace it."""
    try:
        data = read_document(path)
    except DataError:
        return False
    return isinstance(data, dict) and {"schema_version", "name", "version"} <= set(data)


looks_like_profile.kind = "profile"  # named when --force is refused (profiles.atomic.check_replaceable)


def document(profile: DetectorProfile) -> dict:
    """The profile as its file holds it: a schema-1 or -2 profile without the fields later schemas added (so it keeps
    its bytes); a schema-3 profile with its fitted figures rounded and its P_D table as bins
    (:mod:`profiles.document`)."""
    exclude = {}
    if profile.schema_version < 3:
        exclude = {k: set(v) for k, v in V3_FIELDS.items()}
    if profile.schema_version == 1:
        exclude |= V2_FIELDS
    data = profile.model_dump(mode="json", exclude=exclude or None)
    for section in ("noise", "sensors", "planes"):  # optional sections: absent rather than null, so older profiles keep their bytes
        if data.get(section) is None:
            data.pop(section, None)
    for section, keys in LATER_OPTIONAL.items():
        for k in keys:
            if isinstance(data.get(section), dict) and data[section].get(k, 0) is None:
                data[section].pop(k)
    det = data.get("detector", {})
    if det.get("plane", 0) is None:
        det.pop("plane")
    kind = DETECTOR_KINDS.get(det.get("kind"), None)
    if det.get("circle", 0) is None and kind is not None and kind.schema >= 2:
        det.pop("circle")  # kinds that came with schema 2 never wrote the circle: null schema-1 documents carry
    return written(profile, data) if profile.schema_version >= 3 else data


def comparable(profile: DetectorProfile) -> dict:
    """The profile as schema 3 writes it (rounded, the P_D table as bins), whatever its schema: what diffs and
    content comparisons look at."""
    return written(profile, profile.model_dump(mode="json"))


def dump_profile(profile: DetectorProfile, fmt: str = "yaml") -> str:
    """Deterministic text (same profile, same bytes): schema order; schema 3 with units in comments, fitted figures
    rounded and the P_D table one bin per line (:mod:`profiles.document`); schema 1 and 2 as they were written."""
    if fmt not in ("yaml", "json"):
        raise UsageError(f"--format: expected yaml or json, got {fmt!r}")
    data = document(profile)
    if fmt == "json":
        return json.dumps(data, indent=2) + "\n"
    if profile.schema_version >= 3:
        return render(profile, data)
    return yaml.safe_dump(data, sort_keys=False, default_flow_style=None, width=100, allow_unicode=True)


def profile_filename(profile: DetectorProfile) -> str:
    return f"{profile.name}@{profile.version}.yaml"


#: Provenance fields that say when and how a profile was made, not what it holds (the source commit and the
#: package versions: another build of the same detcal computes the same profile within the tolerance below).
_NOT_CONTENT = ("created", "command", "commit", "packages")


#: Relative tolerance within which two profiles' numbers are the same content: a calibration's sums (a
#: covariance through BLAS, say) round differently in the last bits under another numpy or BLAS build, which
#: does not make it another profile; compared as written (rounded to six digits), such a difference can flip
#: the last written digit, a relative change below 1e-5.
SAME_REL_TOL = 1e-5


def same_content(a: DetectorProfile, b: DetectorProfile) -> bool:
    """Equal as written (:func:`comparable`) in everything but the creation time, the command line (its output
    options do not change the content) and the build that ran; numbers equal within :data:`SAME_REL_TOL`,
    every other value exactly."""
    da, db = comparable(a), comparable(b)
    for k in _NOT_CONTENT:
        da["provenance"].pop(k, None), db["provenance"].pop(k, None)
    return _same(da, db)


def _same(x, y) -> bool:
    """``x == y``, with floats compared within :data:`SAME_REL_TOL` (NaN equal to NaN, an int never to a float)."""
    if isinstance(x, dict) and isinstance(y, dict):
        return x.keys() == y.keys() and all(_same(x[k], y[k]) for k in x)
    if isinstance(x, list) and isinstance(y, list):
        return len(x) == len(y) and all(_same(u, v) for u, v in zip(x, y, strict=True))
    if isinstance(x, float) and isinstance(y, float):
        return math.isclose(x, y, rel_tol=SAME_REL_TOL, abs_tol=0.0) or (math.isnan(x) and math.isnan(y))
    return type(x) is type(y) and x == y


def bundled(name: str, version: str) -> Path | None:
    """The bundled profile file of ``name@version``, if there is one."""
    p = BUILTIN / f"{name}@{version}.yaml"
    return p if p.is_file() else None


@dataclass(frozen=True)
class Request:
    """What identifies a profile before it is computed: name@version, description, inputs and parameters.

    Two calibrations of the same request give the same profile (up to the
    creation time and command line), so a rerun is no conflict; another
    request under an existing name@version is refused before any work.
    """

    name: str
    version: str
    description: str
    inputs: list
    parameters: dict
    detcal_version: str
    seed: int | None
    derived: tuple[str, ...] = ()  # parameters the work derives from inputs and config (compared as the content, later)

    @classmethod
    def of(cls, p: DetectorProfile, derived: tuple[str, ...] = ()) -> Request:
        v = p.provenance
        params = {k: x for k, x in v.parameters.items() if k not in derived}
        return cls(p.name, p.version, p.description, list(v.inputs), params, v.detcal_version, v.seed, tuple(derived))

    @property
    def ref(self) -> str:
        return f"{self.name}@{self.version}"


def same_request(a: Request, b: Request) -> bool:
    return a == b


def check_save(request: Request, folder: str | Path | None = None, *, force: bool = False) -> tuple[Path, str]:
    """What saving the profile of ``request`` will do, decided before any work: (path, ``"write"``,
    ``"replace"``, ``"unchanged"`` or ``"bundled"``); a conflict is a UsageError."""
    folder = Path(folder) if folder is not None else user_dirs()[0]
    path = folder / f"{request.name}@{request.version}.yaml"
    builtin = bundled(request.name, request.version)
    if builtin is not None and folder.resolve() != BUILTIN.resolve():
        old = _load_or_none(builtin)
        if old is not None and same_request(Request.of(old, request.derived), request):
            return builtin, "bundled"
        raise UsageError(
            f"profile {request.ref} is bundled with detcal with other content; a user profile of that name and version "
            "would shadow it: choose another --name or --version"
        )
    if not path.exists():
        return path, "write"
    old = _load_or_none(path)
    if old is not None and same_request(Request.of(old, request.derived), request) and not force:
        return path, "unchanged"
    if not force:
        raise UsageError(f"{path}: profile {request.ref} exists with other content; bump the version (--version) or use --force")
    return path, "replace"


def check_new_version(name: str, version: str, folder: str | Path | None = None, *, force: bool = False) -> tuple[Path, str]:
    """Where a profile whose content is only known after the work (self-calibration) will be saved,
    decided before any work: (path, ``"write"`` or ``"replace"``). An existing version is refused
    unless ``force``; a bundled name@version is always refused (a user profile would shadow it)."""
    folder = Path(folder) if folder is not None else user_dirs()[0]
    path = folder / f"{name}@{version}.yaml"
    if bundled(name, version) is not None and folder.resolve() != BUILTIN.resolve():
        raise UsageError(f"profile {name}@{version} is bundled with detcal; a user profile of that name and version would shadow it: choose another --name or --version")
    if not os.path.lexists(path):
        return path, "write"
    if not force:
        raise UsageError(f"{path}: profile {name}@{version} exists; bump the version (--version) or use --force")
    return path, "replace"


def _load_or_none(path: Path) -> DetectorProfile | None:
    try:
        return load_profile_file(path, notify=False)  # compared with what is to be written, not used
    except DetcalError:
        return None


def save_profile(profile: DetectorProfile, folder: str | Path | None = None, *, force: bool = False) -> tuple[Path, str]:
    """Write ``<folder>/<name>@<version>.yaml`` atomically.

    An existing version is never replaced unless ``force``; when it holds the same
    profile (all but the creation time and command line) nothing is written. A
    user profile never shadows a bundled one of the same name@version: the same
    content is left to the bundled file, other content is refused. Returns the
    path and ``"written"``, ``"replaced"``, ``"unchanged"`` or ``"unchanged (bundled)"``.
    """
    path, status = final_status(profile, folder, force)
    if status in ("unchanged", "unchanged (bundled)"):
        return path, status
    with atomic_output(path, overwrite=force, owned=looks_like_profile) as tmp:
        write_profile_text(profile, tmp)
    return path, status


def write_profile_text(profile: DetectorProfile, path: Path) -> None:
    """The profile's YAML into ``path`` (a temporary of an atomic output), flushed to disk."""
    with open(path, "w", encoding="utf-8") as fh:
        fh.write(dump_profile(profile))
        fh.flush()
        os.fsync(fh.fileno())


def final_status(profile: DetectorProfile, folder: str | Path | None, force: bool, derived: tuple[str, ...] = ()) -> tuple[Path, str]:
    """(path, ``"written"``, ``"replaced"``, ``"unchanged"`` or ``"unchanged (bundled)"``) for a finished profile."""
    path, plan = check_save(Request.of(profile, derived), folder, force=force)
    if plan == "bundled":
        if not same_content(load_profile_file(path, notify=False), profile):
            raise UsageError(f"profile {profile.ref} is bundled with detcal with other content; choose another --name or --version")
        return path, "unchanged (bundled)"
    if plan == "unchanged":
        if same_content(load_profile_file(path, notify=False), profile):
            return path, "unchanged"
        raise UsageError(f"{path}: profile {profile.ref} exists with other content; bump the version (--version) or use --force")
    return path, {"write": "written", "replace": "replaced"}[plan]


@dataclass(frozen=True)
class Entry:
    name: str
    version: str
    path: Path
    origin: str  # builtin | user
    shadowed_by: Path | None = None  # another file of the same name@version that resolve() picks instead


def registry() -> list[Entry]:
    """Every profile file of the registry (not validated; see :func:`resolve`).

    When several files hold the same name@version (a user profile left beside a
    bundled one, or the same one in two user folders), the one :func:`resolve`
    picks is the first user folder's, then the bundled one; the others say
    which file shadows them.
    """
    found = []
    for origin, folders in (("user", user_dirs()), ("builtin", [BUILTIN])):
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
                found.append(Entry(name, version, f, origin))
    winner: dict[tuple[str, str], Path] = {}
    out = []
    for e in found:  # precedence: the order found (user folders in order, then bundled)
        first = winner.setdefault((e.name, e.version), e.path)
        out.append(e if first == e.path else Entry(e.name, e.version, e.path, e.origin, first))
    return sorted(out, key=lambda e: (e.origin != "builtin", e.name, semver_key(e.version), str(e.path)))


def _lookup(ref: str | Path) -> tuple[Path, Entry | None]:
    """The file ``ref`` names: a path as given, or the registry's entry of ``name[@version]`` (newest version when
    omitted)."""
    ref_s = str(ref)
    p = Path(ref_s)
    if p.suffix in (".yaml", ".yml", ".json") and (p.exists() or os.sep in ref_s):
        return p, None
    name, _, version = ref_s.partition("@")
    entries = registry()
    cands = [e for e in entries if e.name == name and (not version or e.version == version) and e.shadowed_by is None]
    if not cands:
        known = sorted({f"{e.name}@{e.version}" for e in entries})
        where = ", ".join(str(d) for d in user_dirs())
        env = "set by DETCAL_PROFILES" if os.environ.get("DETCAL_PROFILES") else "DETCAL_PROFILES to change"
        if p.suffix in (".yaml", ".yml", ".json"):
            raise UsageError(f"{ref_s}: no such profile file")
        raise UsageError(
            f"no profile {ref_s!r}; known: {', '.join(known) or 'none'}. Profiles are searched in the bundled ones and in "
            f"{where} ({env}); give a profile file by its path (e.g. ./my-laser@1.0.0.yaml)"
        )
    best = max(cands, key=lambda e: semver_key(e.version))
    return best.path, best


def profile_path(ref: str | Path) -> Path:
    """The file :func:`resolve` reads for ``ref``."""
    return _lookup(ref)[0]


def resolve(ref: str | Path) -> DetectorProfile:
    """A profile from a file path or ``name[@version]`` (newest version when omitted)."""
    path, best = _lookup(ref)
    if best is None:
        return load_profile_file(path)
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
    fa, fb = flatten(comparable(a)), flatten(comparable(b))
    keys = sorted(set(fa) | set(fb))
    return [(k, fa.get(k), fb.get(k)) for k in keys if fa.get(k) != fb.get(k)]
