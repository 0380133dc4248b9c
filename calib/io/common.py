"""Helpers shared by the text readers: opening (plain/.gz/.bz2), exact time parsing, time order."""

from __future__ import annotations

import bz2
import gzip
import hashlib
import io
import lzma
import math
import zlib
import warnings
from collections.abc import Iterator
from pathlib import Path

import numpy as np

from detectors.sensor_log import MAX_SECONDS, seconds_to_stamp
from profiles.errors import DataError, UsageError

#: Default tolerance for records that step back in time within one stream.
#: Real logs have such jitter (inter-process timestamps of the Radish CARMEN logs). Within this tolerance records are
#: sorted back into order and counted; beyond it the log is refused.
DEFAULT_MAX_BACKSTEP = 1.0


def require_file(path: Path) -> Path:
    if not path.exists():
        raise UsageError(f"{path}: no such file or folder")
    return path


def open_text(path: Path) -> io.TextIOBase:
    """Open a text log, decompressing ``.gz``/``.bz2``/``.xz`` by suffix."""
    require_file(path)
    if path.is_dir():
        raise UsageError(f"{path}: is a folder, expected a log file")
    suffix = path.suffix.lower()
    opener = {".gz": gzip.open, ".bz2": bz2.open, ".xz": lzma.open}.get(suffix)
    if opener is None:
        return open(path, encoding="utf-8", errors="replace")  # noqa: SIM115
    return opener(path, "rt", encoding="utf-8", errors="replace")


def iter_lines(path: Path) -> Iterator[tuple[int, str]]:
    """(1-based line number, stripped line); a damaged compressed stream is a DataError."""
    lineno = 0
    try:
        with open_text(path) as fh:
            for lineno, line in enumerate(fh, start=1):  # noqa: B007
                yield lineno, line.strip()
    except (EOFError, OSError, ValueError, lzma.LZMAError, zlib.error) as exc:
        raise DataError(f"{path}: compressed stream is truncated or corrupt after line {lineno} ({exc})") from None


def parse_stamp(token: str, path: Path, lineno: int, what: str = "timestamp") -> int:
    """Decimal seconds -> int64 ns without going through float, so 6-decimal stamps stay exact.

    Exponent notation goes through float; NaN, infinities and times beyond the
    int64 range (+-292 years) are refused with the file and line.
    """
    try:
        if "e" in token or "E" in token:
            sec_f = float(token)
            if math.isnan(sec_f):
                raise ValueError(token)
            if not abs(sec_f) < MAX_SECONDS:
                raise DataError(f"{path}:{lineno}: {what} {token!r} is out of range (at most {MAX_SECONDS:.3g} s)")
            ns = round(sec_f * 1e9)
        else:
            neg = token.startswith("-")
            body = token[1:] if token[:1] in "+-" else token
            sec, _, frac = body.partition(".")
            if not (sec + frac).isascii() or not (sec + frac).isdigit():
                raise ValueError(token)
            ns = int(sec or "0") * 1_000_000_000 + int((frac + "000000000")[:9] or "0")
            ns = -ns if neg else ns
    except (ValueError, OverflowError):
        raise DataError(f"{path}:{lineno}: {what} {token!r} is not a number") from None
    if abs(ns) >= MAX_SECONDS * 1e9:
        raise DataError(f"{path}:{lineno}: {what} {token!r} is out of range (at most {MAX_SECONDS:.3g} s)")
    return ns


def parse_floats(tokens: list[str], path: Path, lineno: int, what: str) -> np.ndarray:
    try:
        out = np.array(tokens, dtype=np.float64)
    except ValueError:
        bad = next(t for t in tokens if not _is_float(t))
        raise DataError(f"{path}:{lineno}: {what}: {bad!r} is not a number") from None
    if np.isnan(out).any():
        raise DataError(f"{path}:{lineno}: {what}: NaN value")
    return out


def _is_float(t: str) -> bool:
    try:
        float(t)
    except ValueError:
        return False
    return True


def time_order(stamps: np.ndarray, lines: np.ndarray, path: Path, what: str, max_backstep: float) -> tuple[np.ndarray, int]:
    """Permutation that sorts one stream by time, and how many records it moved.

    A record earlier than the latest stamp before it by more than
    ``max_backstep`` seconds is refused with its line number.
    """
    stamps = np.asarray(stamps, dtype=np.int64)
    if stamps.size == 0:
        return np.arange(0), 0
    first = _first_backstep(stamps, max_backstep)
    if first is not None:
        back = int(np.maximum.accumulate(stamps)[first] - stamps[first])
        raise DataError(
            f"{path}:{int(lines[first])}: {what} time goes backwards by {back / 1e9:.6f} s "
            f"(more than the tolerated {max_backstep:g} s); --max-backstep SECONDS tolerates more, as logs rewritten by SLAM tools may need"
        )
    perm = np.argsort(stamps, kind="stable")
    return perm, int(np.count_nonzero(perm != np.arange(stamps.size)))


def _first_backstep(stamps: np.ndarray, max_backstep: float) -> int | None:
    """Index of the first record earlier than the latest stamp before it by more than ``max_backstep`` s."""
    back = np.maximum.accumulate(stamps) - stamps
    over = np.flatnonzero(back > max_backstep * 1e9)
    return int(over[0]) if over.size else None


def file_digest(path: Path) -> str:
    """sha256 of a file, or of a folder's files in sorted order."""
    h = hashlib.sha256()
    files = sorted(p for p in path.rglob("*") if p.is_file()) if path.is_dir() else [path]
    for f in files:
        if path.is_dir():
            h.update(str(f.relative_to(path)).encode())
        with open(f, "rb") as fh:
            for chunk in iter(lambda fh=fh: fh.read(1 << 20), b""):
                h.update(chunk)
    return h.hexdigest()


def read_table(path: Path, ncols: int, what: str) -> np.ndarray:
    """A whitespace-separated numeric table with ``#`` comments -> (n, ncols) float64.

    Fast path through ``numpy.loadtxt``; on failure the offending line is found
    and named. NaN cells are refused.
    """
    require_file(path)
    try:
        with warnings.catch_warnings():  # an empty file: numpy warns, the caller says what it needed
            warnings.simplefilter("ignore", UserWarning)
            table = np.loadtxt(path, comments="#", ndmin=2, dtype=np.float64)
    except ValueError:
        table = None
    if table is None or (table.size and table.shape[1] != ncols):
        for lineno, line in iter_lines(path):
            if not line or line.startswith("#"):
                continue
            tok = line.split()
            if len(tok) != ncols:
                raise DataError(f"{path}:{lineno}: {what}: expected {ncols} columns, got {len(tok)}")
            parse_floats(tok, path, lineno, what)
        raise DataError(f"{path}: {what}: unreadable table")
    if table.size == 0:
        return np.zeros((0, ncols))
    bad = np.flatnonzero(~np.isfinite(table).all(axis=1))
    if bad.size:
        lineno = data_line(path, int(bad[0]))
        raise DataError(f"{path}:{lineno}: {what}: NaN or infinite value")
    return table


def require_rows(path: Path, table: np.ndarray, ok: np.ndarray, what: str, rule: str) -> None:
    """Refuse the first row of ``table`` (read by :func:`read_table`) where ``ok`` is False, naming its line."""
    bad = np.flatnonzero(~np.asarray(ok, dtype=bool))
    if bad.size:
        raise DataError(f"{path}:{data_line(path, int(bad[0]))}: {what}: {rule}")


def data_line(path: Path, row: int) -> int:
    """The 1-based line number of data row ``row`` (0-based, comments and blank lines skipped) of a table file."""
    k = -1
    for lineno, line in iter_lines(path):
        if line and not line.startswith("#"):
            k += 1
            if k == row:
                return lineno
    return -1


def table_time_order(stamps: np.ndarray, path: Path, what: str, max_backstep: float) -> tuple[np.ndarray, int]:
    """:func:`time_order` for a table read by :func:`read_table`; line numbers are found only on error."""
    try:
        return time_order(stamps, np.full(np.asarray(stamps).size, -1), path, what, max_backstep)
    except DataError:
        row = _first_backstep(np.asarray(stamps, dtype=np.int64), max_backstep)
        back = int(np.maximum.accumulate(stamps)[row] - stamps[row])
        raise DataError(
            f"{path}:{data_line(path, row)}: {what} time goes backwards by {back / 1e9:.6f} s "
            f"(more than the tolerated {max_backstep:g} s)"
        ) from None


def table_stamps(seconds: np.ndarray, path: Path, what: str) -> np.ndarray:
    """Time column of a table read by :func:`read_table` -> int64 ns; a time out of range names its line."""
    t = np.asarray(seconds, dtype=np.float64)
    bad = np.flatnonzero(~(np.abs(t) < MAX_SECONDS))
    if bad.size:
        raise DataError(f"{path}:{data_line(path, int(bad[0]))}: {what}: time {float(t[bad[0]])!r} s is out of range (at most {MAX_SECONDS:.3g} s)")
    return seconds_to_stamp(t)


def index_of(values: np.ndarray, keys: np.ndarray) -> np.ndarray:
    """Position of each value (N,) in ``keys`` (K,), -1 where absent; vectorised with a sorted search."""
    values = np.asarray(values)
    keys = np.asarray(keys)
    if keys.size == 0:
        return np.full(values.shape, -1, dtype=np.int64)
    order = np.argsort(keys, kind="stable")
    pos = np.clip(np.searchsorted(keys[order], values), 0, keys.size - 1)
    hit = keys[order][pos] == values
    return np.where(hit, order[pos], -1).astype(np.int64)
