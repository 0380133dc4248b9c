"""Atomic outputs: write beside, then rename over; never delete first.

Used by every writer of detcal (logs, run folders, profiles, bags); it lives in
``profiles`` because that package imports nothing else of ours.

* A file is written to a hidden temporary name in the same folder
  (``.<name>.<pid>.<token>.part``) and moved over the target with
  ``os.replace``, which replaces an existing file atomically.
* A folder is built inside a hidden temporary folder under its final name
  (``.<name>.<pid>.<token>.part/<name>``: a ROS 2 bag names its files after
  its folder, so the temporary name must not leak into them), then moved into
  place. An existing folder is swapped with the new one in one step
  (``renameat2(RENAME_EXCHANGE)`` on Linux; elsewhere it is first moved aside,
  never deleted before the new one is in place) and only then removed.
* Replacing needs ``overwrite`` (``--force``) and is refused for a target of
  another kind (a folder where a file goes or the reverse), a symbolic link,
  or a target detcal did not write: a folder detcal writes holds the marker
  file :data:`MARKER`; a file is recognised by the writer's ``owned`` test.
* A writer killed half-way leaves only hidden ``.part`` entries, never a
  partial target; the next write of the same target removes those of dead
  processes.

Several outputs of one step (a profile and its run folder) are prepared
completely before the first is moved into place (:func:`atomic_outputs`).
"""

from __future__ import annotations

import contextlib
import errno
import ctypes
import ctypes.util
import os
import re
import shutil
import tempfile
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path

from profiles.errors import UsageError

#: Marker file inside every folder detcal writes; ``--force`` replaces only such folders.
MARKER = ".detcal-output"
_MARKER_TEXT = "written by detcal; `--force` may replace this folder\n"


@dataclass(frozen=True)
class Output:
    """One output of a step: ``path``; ``directory`` for a folder; ``owned(path)`` recognises a file detcal wrote."""

    path: Path
    directory: bool = False
    overwrite: bool = False
    owned: Callable[[Path], bool] | None = None


def written_by_detcal(path: Path, directory: bool, owned: Callable[[Path], bool] | None = None) -> bool:
    if path.is_symlink():
        return False
    if directory:
        return path.is_dir() and (path / MARKER).is_file()
    if not path.is_file() or owned is None:
        return False
    try:
        return bool(owned(path))
    except Exception:  # a recogniser that chokes on a foreign file: not ours  # noqa: BLE001
        return False


def check_replaceable(path: str | Path, *, overwrite: bool, directory: bool, owned: Callable[[Path], bool] | None = None) -> None:
    """Refuse an existing ``path`` unless ``overwrite`` and it is of the same kind and written by detcal."""
    path = Path(path)
    if not os.path.lexists(path):
        return
    if not overwrite:
        raise UsageError(f"{path}: already exists (use --force to replace it)")
    what = "folder" if directory else "file"
    if path.is_symlink():
        raise UsageError(f"{path}: is a symbolic link; --force replaces only a {what} detcal wrote (remove it yourself)")
    if directory and not path.is_dir():
        raise UsageError(f"{path}: exists and is not a folder; --force replaces only a folder detcal wrote (remove it yourself)")
    if not directory and path.is_dir():
        raise UsageError(f"{path}: is a folder; --force replaces only a file detcal wrote (remove it yourself)")
    if not written_by_detcal(path, directory, owned):
        kind = getattr(owned, "kind", None)  # what the recogniser accepts, e.g. "profile"
        if not directory and kind is not None and path.is_file():
            raise UsageError(f"{path}: is not a {kind} detcal wrote; --force replaces only a {kind} (remove it yourself)")
        hint = f" (no {MARKER} inside)" if directory else ""
        raise UsageError(f"{path}: was not written by detcal{hint}; --force does not replace it (remove it yourself)")


def _remove(p: Path) -> None:
    if p.is_dir() and not p.is_symlink():
        shutil.rmtree(p, ignore_errors=True)
    else:
        with contextlib.suppress(FileNotFoundError):
            p.unlink()


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # someone else's process
        return True
    return True


def _clean_stale(path: Path) -> None:
    """Remove ``.part`` leftovers of ``path`` written by processes that no longer run (killed writers)."""
    pat = re.compile(rf"^\.{re.escape(path.name)}\.(\d+)\.[^.]+\.part$")
    try:
        entries = list(path.parent.iterdir())
    except OSError:
        return
    for e in entries:
        m = pat.match(e.name)
        if m and int(m.group(1)) != os.getpid() and not _alive(int(m.group(1))):
            _remove(e)


def _mode_of_plain_file(p: Path) -> None:
    umask = os.umask(0)  # mkstemp makes 0600; give the file the mode a plain open() would
    os.umask(umask)
    os.chmod(p, 0o666 & ~umask)


_RENAME_EXCHANGE = 2
_AT_FDCWD = -100


def _exchange(a: Path, b: Path) -> bool:
    """Swap two paths in one step (Linux renameat2); False where the system cannot."""
    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or None, use_errno=True)
        fn = libc.renameat2
    except (OSError, AttributeError):
        return False
    fn.argtypes = [ctypes.c_int, ctypes.c_char_p, ctypes.c_int, ctypes.c_char_p, ctypes.c_uint]
    return fn(_AT_FDCWD, os.fsencode(a), _AT_FDCWD, os.fsencode(b), _RENAME_EXCHANGE) == 0


#: Called with the temporary path of every folder output when it is complete, before it is moved into place (the
#: application adds a command's warnings to its run folders: ``detcal.run_warnings``).
FOLDER_FINISHERS: list[Callable[[Path], None]] = []


class _Staged:
    """The temporary entry of one output, and how to move it into place."""

    def __init__(self, out: Output) -> None:
        self.out = out
        path = out.path
        prefix = f".{path.name}.{os.getpid()}."
        try:
            path.parent.mkdir(parents=True, exist_ok=True)
            _clean_stale(path)
            if out.directory:
                self.holder = Path(tempfile.mkdtemp(prefix=prefix, suffix=".part", dir=path.parent))
                self.tmp = self.holder / path.name
            else:
                fd, name = tempfile.mkstemp(prefix=prefix, suffix=".part", dir=path.parent)
                os.close(fd)
                self.holder = self.tmp = Path(name)
        except OSError as exc:
            blocker = next((p for p in path.parents if p.exists() and not p.is_dir()), None)
            why = f"{blocker} is a file, not a folder" if blocker is not None else (exc.strerror or str(exc))
            raise UsageError(f"{path}: cannot write here ({why})") from None

    def finish(self) -> None:
        """Everything but the move: the marker of a folder, the mode of a file."""
        if self.out.directory:
            if not self.tmp.is_dir():
                raise UsageError(f"{self.out.path}: the writer produced no folder")
            for finisher in FOLDER_FINISHERS:
                finisher(self.tmp)
            (self.tmp / MARKER).write_text(_MARKER_TEXT)
        else:
            _mode_of_plain_file(self.tmp)

    def install(self) -> None:
        path = self.out.path
        if not self.out.directory:
            os.replace(self.tmp, path)  # atomic over an existing file
            return
        if os.path.lexists(path):
            if not _exchange(self.tmp, path):
                # no atomic swap: move the old folder aside (kept until the new one is in place)
                os.rename(path, self.holder / ".replaced")
                os.rename(self.tmp, path)
        else:
            os.rename(self.tmp, path)
        _remove(self.holder)  # the old folder (after a swap) and the empty holder

    def discard(self) -> None:
        _remove(self.holder)


#: Free space [bytes] under which a file system counts as the full one when a write fails for want of space.
_FULL_BYTES = 1 << 20


def _failed_output(staged: list[_Staged], exc: OSError) -> Path:
    """The output a failed write was for: the one whose temporary entry the error names; for a full disk or quota
    without a file name (a write to an open file), the one whose file system has no room left; else the first."""
    for s in staged:
        for name in (exc.filename, exc.filename2):
            if name is not None and (Path(name) == s.holder or s.holder in Path(name).parents):
                return s.out.path
    if exc.errno in (errno.ENOSPC, errno.EDQUOT, errno.EFBIG):
        for s in staged:
            try:
                st = os.statvfs(s.holder.parent)
            except OSError:
                continue
            if st.f_bavail * st.f_frsize < _FULL_BYTES:
                return s.out.path
    return staged[0].out.path


@contextlib.contextmanager
def atomic_outputs(outputs: list[Output]) -> Iterator[list[Path]]:
    """Yield one temporary path per output; move them all into place only if the block succeeds.

    Every existing target is checked first (:func:`check_replaceable`). The
    targets are moved in the order given, after all of them are complete.
    A folder's temporary path does not exist yet (the writer creates it); a
    file's is an empty file.
    """
    outputs = [Output(Path(o.path), o.directory, o.overwrite, o.owned) for o in outputs]
    for o in outputs:
        check_replaceable(o.path, overwrite=o.overwrite, directory=o.directory, owned=o.owned)
    staged: list[_Staged] = []
    try:
        for o in outputs:
            staged.append(_Staged(o))
        try:
            yield [s.tmp for s in staged]
        except OSError as exc:
            raise UsageError(f"{_failed_output(staged, exc)}: cannot write ({exc.strerror or exc})") from None
        for s in staged:
            s.finish()
        for o in outputs:  # the targets may have appeared meanwhile
            check_replaceable(o.path, overwrite=o.overwrite, directory=o.directory, owned=o.owned)
        for s in staged:
            s.install()
    finally:
        for s in staged:
            s.discard()


@contextlib.contextmanager
def atomic_output(
    path: str | Path, *, overwrite: bool = False, directory: bool = False, owned: Callable[[Path], bool] | None = None
) -> Iterator[Path]:
    """Yield a temporary path beside ``path``; move it into place only if the block succeeds.

    ``directory=True`` yields a path that does not exist yet (for writers that
    create a folder themselves, such as a ROS 2 bag); otherwise an empty file.
    An existing ``path`` is refused unless ``overwrite``, and even then unless
    it is of the same kind and was written by detcal (``owned`` recognises a file).
    """
    with atomic_outputs([Output(Path(path), directory, overwrite, owned)]) as tmps:
        yield tmps[0]
