"""Rebuild a profile from its recorded provenance and compare it with the file, byte for byte.

A profile records how it was made (``provenance``): the command line as typed
(paths relative to the working folder it ran in), the inputs' digests, the
creation time (``SOURCE_DATE_EPOCH`` when set) and, since schema 3, the git
commit of the source that ran and the versions of the numerical packages.
:func:`rebuild` runs that command again:

- in a private staging folder, the command's input paths linked there from the
  working folder it ran in (``origin``) so that the command runs as typed and
  records the same command line; its outputs (``--out``, ``--profiles-dir`` and
  the user profile folder) land in the staging folder, never beside the original;
- with ``SOURCE_DATE_EPOCH`` set to the recorded creation time;
- with the recorded commit's source (a shared clone of this checkout at that
  commit, first on ``PYTHONPATH``), so the source commit written is the recorded
  one; a profile that records none (schema 1 and 2) is rebuilt by the source that
  runs, which the result says.

The rebuilt file is then compared with the recorded one: the same bytes; the
same bytes below a comment someone added above the document; the same content
(:func:`profiles.store.same_content`: what an older schema's file can at best
give, since this detcal writes the current schema); or different, with the
fields that differ.
"""

from __future__ import annotations

import os
import shlex
import subprocess
import sys
import tempfile
from dataclasses import dataclass, field
from datetime import datetime
from pathlib import Path

from profiles.errors import DataError, UsageError
from profiles.document import body
from profiles.store import diff_profiles, load_profile_file, migrated, same_content
from profiles.version import SOURCE_ROOT

#: the options naming a command's outputs: they land in the staging folder, as typed
OUTPUT_OPTIONS = ("--out", "--profiles-dir")


@dataclass
class Rebuilt:
    """``verdict``: ``same bytes``, ``same bytes below the header comment``, ``same content`` or ``differs``;
    ``differences``: (field path, recorded, rebuilt) when not the same content; ``notes``: what the comparison
    could not hold fixed (no recorded commit, other package versions)."""

    recorded: Path
    text: str
    verdict: str
    differences: list[tuple[str, object, object]] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)


def _epoch(created: str, where: Path) -> int:
    try:
        return int(datetime.fromisoformat(created.replace("Z", "+00:00")).timestamp())
    except ValueError:
        raise DataError(f"{where}: provenance.created: {created!r} is not an ISO 8601 time") from None


def _git(*args: str, cwd: Path) -> subprocess.CompletedProcess:
    return subprocess.run(["git", *args], cwd=cwd, capture_output=True, text=True, check=False)


def _source_at(commit: str, src: Path, where: Path) -> Path:
    """A shared clone of this checkout at ``commit`` (the source that made the profile) in the new folder ``src``."""
    if commit.endswith("+dirty"):
        raise DataError(f"{where}: provenance.commit: {commit} was made by a source with uncommitted changes; it cannot be rebuilt from its provenance")
    if not (SOURCE_ROOT / ".git").exists() or _git("cat-file", "-e", f"{commit}^{{commit}}", cwd=SOURCE_ROOT).returncode != 0:
        raise DataError(f"{where}: provenance.commit: {commit} is not in the history of the detcal checkout that runs ({SOURCE_ROOT.name}); rebuild it from a clone that has it")
    src.parent.mkdir(parents=True, exist_ok=True)
    for args in (("clone", "--quiet", "--shared", "--no-checkout", str(SOURCE_ROOT), str(src)), ("-C", str(src), "checkout", "--quiet", "--detach", commit)):
        r = _git(*args, cwd=src.parent)
        if r.returncode != 0:
            raise DataError(f"{where}: cannot check out the source of commit {commit}: {' '.join(r.stderr.split())}")
    return src


def _ups(v: str) -> int:
    """How many folders above the working folder the relative path ``v`` starts."""
    parts = Path(os.path.normpath(v)).parts
    return next((i for i, p in enumerate(parts) if p != ".."), len(parts))


def _values(words: list[str]) -> list[str]:
    return [w.partition("=")[2] if w.startswith("--") and "=" in w else w for w in words]


def _outputs(words: list[str]) -> dict[str, str]:
    """The command's output options (:data:`OUTPUT_OPTIONS`) and their values, as typed."""
    found = {}
    for i, w in enumerate(words):
        opt, eq, value = w.partition("=")
        if opt in OUTPUT_OPTIONS:
            found[opt] = value if eq else (words[i + 1] if i + 1 < len(words) else "")
    return found


def _workdir(words: list[str], root: Path) -> Path:
    """The working folder the command runs in: inside ``root``, nested deep enough for its ``..`` paths."""
    depth = max((_ups(v) for v in _values(words) if v and not v.startswith("-")), default=0)
    return root.joinpath(*["w"] * max(depth, 1))


def _stage(words: list[str], origin: Path, cwd: Path, root: Path, where: Path) -> None:
    """Link into the working folder ``cwd`` every input path the command names that is not there yet (the source
    checkout of the recorded commit holds the repository's own files as they were), as it lay from ``origin``."""
    values = _values(words)
    cwd.mkdir(parents=True, exist_ok=True)
    outputs = set(_outputs(words).values())
    for v in values:
        if not v or v.startswith("-") or v in outputs:
            continue
        if v.startswith("~") or os.path.isabs(v):
            continue  # the same file from any working folder
        real = origin / v
        if not os.path.lexists(real):
            continue  # not a path (a name, a number)
        link = Path(os.path.normpath(cwd / v))
        if root not in link.parents:
            raise UsageError(f"{where}: provenance.command: the path {v} leaves the staging folder")
        if not os.path.lexists(link):
            link.parent.mkdir(parents=True, exist_ok=True)
            link.symlink_to(real.resolve())
    for o in outputs:
        if o.startswith("~") or os.path.isabs(o):
            raise DataError(f"{where}: provenance.command: the output {o} lies outside the working folder; the command cannot be rerun apart from it")


def _result(words: list[str], cwd: Path, user: Path, ref: str) -> Path | None:
    """The profile the command wrote: in its --profiles-dir (or the user profile folder), else its run folder's."""
    opts = _outputs(words)
    for candidate in (cwd / opts.get("--profiles-dir", str(user)) / f"{ref}.yaml", cwd / opts.get("--out", "-") / "profile.yaml"):
        if candidate.is_file():
            return candidate
    return None


def rebuild(path: Path, *, origin: Path, timeout: float | None = None) -> Rebuilt:
    """Run the command ``path``'s provenance records (as it ran in the working folder ``origin``) and compare the
    profile it writes with ``path``."""
    path = Path(path)
    recorded = load_profile_file(path, migrate=False, notify=False)
    v = recorded.provenance
    if not v.command.startswith("detcal "):
        raise DataError(f"{path}: provenance.command: {v.command!r} is not a detcal command; the profile cannot be rebuilt from its provenance")
    words = shlex.split(v.command)[1:]
    notes = []
    with tempfile.TemporaryDirectory(prefix="detcal-rebuild-") as tmp:
        tmp = Path(tmp)
        env = {**os.environ, "SOURCE_DATE_EPOCH": str(_epoch(v.created, path))}
        user = tmp / "user-profiles"
        env["DETCAL_PROFILES"] = str(user)
        cwd = _workdir(words, tmp / "stage")
        if v.commit:  # the command runs in a checkout of the recorded commit, as from the repository's root
            _source_at(v.commit, cwd, path)
            env["PYTHONPATH"] = os.pathsep.join([str(cwd), *filter(None, [os.environ.get("PYTHONPATH")])])
        else:
            notes.append("the profile records no source commit: rebuilt by the source that runs")
        _stage(words, Path(origin).resolve(), cwd, tmp / "stage", path)
        try:
            r = subprocess.run([sys.executable, "-m", "detcal", *words], cwd=cwd, env=env, capture_output=True, text=True, timeout=timeout, check=False)
        except subprocess.TimeoutExpired:
            raise DataError(f"{path}: the recorded command did not finish in {timeout:g} s") from None
        if r.returncode != 0:
            last = next((x for x in reversed(r.stderr.splitlines()) if x.strip()), f"exit {r.returncode}")
            raise DataError(f"{path}: the recorded command failed (exit {r.returncode}): {last}")
        out = _result(words, cwd, user, recorded.ref)
        if out is None:
            raise DataError(f"{path}: the recorded command wrote no profile {recorded.ref}")
        text = out.read_text()
        rebuilt = load_profile_file(out, notify=False)
    if v.packages and rebuilt.provenance.packages != v.packages:
        notes.append("other package versions: " + ", ".join(f"{k} {v.packages.get(k)} -> {x}" for k, x in rebuilt.provenance.packages.items() if v.packages.get(k) != x))
    original = path.read_text()
    if text == original:
        verdict, diffs = "same bytes", []
    elif body(text) == body(original):
        verdict, diffs = "same bytes below the header comment", []
    else:
        current = migrated(recorded, str(path), notify=False)
        diffs = diff_profiles(current, rebuilt)
        verdict = "same content" if same_content(current, rebuilt) else "differs"
    return Rebuilt(path, text, verdict, diffs, notes)


def keep(result: Rebuilt, dest: Path) -> None:
    """Write the rebuilt profile to ``dest`` (never over a file)."""
    from profiles.atomic import atomic_output

    if os.path.lexists(dest):
        raise UsageError(f"{dest}: exists; a rebuilt profile is never written over a file")
    with atomic_output(dest, overwrite=False) as tmp:
        tmp.write_text(result.text)

