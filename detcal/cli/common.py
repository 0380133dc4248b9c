"""What every command group shares: consoles, the reader options (defined once), output checks, tables.

Reader options are declared once here and added to a command by
:func:`reader_options`, which hands the command a single
:class:`calib.io.registry.ReadOptions` object: a command names the options it
offers, typer shows them in its help, and the body never repeats them.
"""

from __future__ import annotations

import functools
import inspect
import os
import sys
import typing
from collections.abc import Callable
from pathlib import Path
from typing import Annotated

import typer
from pydantic import ValidationError
from rich.console import Console
from rich.table import Table

from calib.io.registry import READERS, ReadOptions
from profiles.errors import DataError, UsageError
from profiles.override import updated

out = Console(highlight=False, markup=False)  # file names may hold brackets

#: The arguments of the running command (set by :func:`detcal.cli.main`), for provenance.
ARGV: list[str] = []

READER_OPTIONS: dict[str, tuple[type, object, typer.models.OptionInfo]] = {
    "fmt": (
        str | None,
        None,
        typer.Option("--format", "-f", help=f"Input format: {', '.join(READERS.names())} (default: from the path)."),
    ),
    "max_backstep": (float, 1.0, typer.Option(help="Tolerated step back in time within a stream [s]; such records are re-sorted. 0 = strict.")),
    "laser": (str, "front", typer.Option(help="CARMEN: which laser, front or rear.")),
    "range_max": (float | None, None, typer.Option(help="CARMEN: readings at or above this [m] are no return (default: the log's saturation value).")),
    "range_sigma": (
        float | None,
        None,
        typer.Option(help="Laser range noise sigma_r [m], replacing the log's (calibrate estimates it from the scans when the log has none)."),
    ),
    "robot": (int, 1, typer.Option(help="UTIAS: which robot (1-5).")),
    "scan_topic": (str | None, None, typer.Option(help="Bags: the LaserScan topic.")),
    "odom_topic": (str | None, None, typer.Option(help="Bags: the nav_msgs/Odometry topic.")),
    "truth_topic": (str | None, None, typer.Option(help="Bags: a ground-truth pose topic (Odometry or PoseStamped).")),
}
ALL_READER_OPTIONS = tuple(READER_OPTIONS)
READER_PANEL = "Reader options"
for _opt in READER_OPTIONS.values():
    _opt[2].rich_help_panel = READER_PANEL


class SectionedCommand(typer.core.TyperCommand):
    """A command whose --help lists its options by section (each option's ``rich_help_panel``, in the order the
    sections first appear) and the options of the sections in :attr:`compact` by their flags only, on a few lines:
    what most users change fits on one screen, the rest is named where to read about it."""

    #: sections listed by their flags only, and where their options are described
    compact = {READER_PANEL: "described in detcal log info --help"}

    def format_options(self, ctx, formatter) -> None:
        args, sections, names = [], {}, {}
        for param in self.get_params(ctx):
            rv = param.get_help_record(ctx)
            if rv is None:
                continue
            if param.param_type_name == "argument":
                args.append(rv)
                continue
            panel = getattr(param, "rich_help_panel", None) or ("Options" if param.name != "help" or not sections else list(sections)[-1])
            if panel in self.compact:
                names.setdefault(panel, []).append(param.opts[0])
            else:
                sections.setdefault(panel, []).append(rv)
        if args:
            with formatter.section("Arguments"):
                formatter.write_dl(args)
        for title, rows in sections.items():
            with formatter.section(title):
                formatter.write_dl(rows)
        for title, flags in names.items():
            with formatter.section(title):
                words, line = [*flags, f"({self.compact[title]})"], ""
                width = (formatter.width or 80) - formatter.current_indent
                for w in words:  # whole flags per line (a flag is not broken at its hyphen)
                    if line and len(line) + 1 + len(w) > width:
                        formatter.write(f"{'':>{formatter.current_indent}}{line}\n")
                        line = w
                    else:
                        line = f"{line} {w}" if line else w
                formatter.write(f"{'':>{formatter.current_indent}}{line}\n")


def reader_options(*names: str) -> Callable:
    """Give a command the reader options ``names`` (default: all) as one ``reader: ReaderArgs`` argument.

    The wrapped function declares ``reader: ReaderArgs``; typer sees the
    individual options in its place.
    """
    names = names or ALL_READER_OPTIONS

    def deco(func: Callable) -> Callable:
        hints = typing.get_type_hints(func, include_extras=True)
        sig = inspect.signature(func)
        params = [p.replace(annotation=hints.get(p.name, p.annotation)) for p in sig.parameters.values() if p.name != "reader"]
        extra = [
            inspect.Parameter(n, inspect.Parameter.KEYWORD_ONLY, default=READER_OPTIONS[n][1], annotation=Annotated[READER_OPTIONS[n][0], READER_OPTIONS[n][2]])
            for n in names
        ]
        new_sig = sig.replace(parameters=[p.replace(kind=inspect.Parameter.KEYWORD_ONLY) for p in params] + extra)

        @functools.wraps(func)
        def wrapper(**kwargs):
            given = {n: kwargs.pop(n) for n in names}
            return func(**kwargs, reader=ReaderArgs(**given))

        wrapper.__signature__ = new_sig  # type: ignore[attr-defined]
        wrapper.__annotations__ = {p.name: p.annotation for p in new_sig.parameters.values()}
        return wrapper

    return deco


class ReaderArgs:
    """The reader options of one command: ``fmt`` and the :class:`ReadOptions` (validated once, errors name the option)."""

    def __init__(self, fmt: str | None = None, **opts) -> None:
        self.fmt = fmt
        try:
            self.options = ReadOptions(**opts)
        except ValidationError as exc:
            e = exc.errors()[0]
            flag = "--" + str(e["loc"][0]).replace("_", "-")
            raise UsageError(f"{flag}: {e['msg']}") from None

    def read(self, path: Path, robot: int | None = None, *, empty_ok: bool = False):
        """The log at ``path`` (``robot`` overrides the UTIAS robot). A log whose sensor stream is empty (no scans, no
        detections, no point clouds) is refused unless ``empty_ok`` (``log info``: it says so)."""
        from calib.io.registry import read_log

        opts = self.options if robot is None else updated(self.options, {"robot": robot})
        log = read_log(path, self.fmt, opts)
        if not empty_ok:
            refuse_empty(path, log)
        warn_untimed(path, log)
        warn_missing(path, log)
        return log

    def options_of(self, log):
        """The reader options that read ``log`` (a UTIAS log: with its robot)."""
        robot = log.source.get("robot")
        return self.options if robot is None else updated(self.options, {"robot": int(robot)})

    def read_many(self, paths: list[Path], robots: list[int] | None = None) -> tuple[list, list[Path]]:
        """Logs from paths; a UTIAS dataset folder gives one log per requested robot (each robot once)."""
        from calib.io.registry import detect_format

        loaded, used = [], []
        for p in paths:
            kind = self.fmt or detect_format(p)
            several = kind in READERS and READERS.get(kind).robots  # a dataset of several robots: one log each
            for r in list(dict.fromkeys(robots or [self.options.robot])) if several else [None]:
                loaded.append(self.read(p, r))
                used.append(p)
        return loaded, used


def refuse_empty(path: Path, log) -> None:
    """A clear error for a log whose sensor stream holds nothing: every command but ``log info`` needs some."""
    for what, stream in (("scans", log.scans), ("point clouds", log.clouds)):
        if stream is not None and len(stream) == 0:
            raise DataError(f"{path}: the log holds no {what}")
    if log.detections is not None and len(log.detections) == 0:
        robot = log.source.get("robot")
        raise DataError(f"{path}: the log holds no detections" + (f" (robot {robot})" if robot is not None else ""))


def warn(message: str) -> None:
    """One plain-text warning line on stderr, recorded for the command's run folder (:mod:`detcal.run_warnings`)."""
    from detcal import run_warnings

    line = " ".join(message.split())
    run_warnings.record(line)
    sys.stderr.write(f"detcal: warning: {line}\n")
    sys.stderr.flush()


def warn_untimed(path: Path, log) -> None:
    """Say how many records of a log had no time and were placed by their order (CARMEN ODOM lines stamped 0)."""
    for stream, n in dict(log.source.get("untimed", {})).items():
        warn(f"{path}: {n} {stream} records are stamped 0 (no time); placed by their order in the file")


def warn_missing(path: Path, log) -> None:
    """Say which topics of a bag hold fewer messages than its index declares, with the longest gap they leave."""
    for topic, m in dict(log.source.get("missing", {})).items():
        gap = ""
        if "longest_s" in m:
            gap = f"; the longest gap is {m['longest_s']:.3g} s, {m['after_s']:.3g} s into the log (median step {m['median_s']:.3g} s)"
        warn(f"{path}: topic {topic} holds {m['found']} of the {m['declared']} messages the bag's index lists{gap}")


def fresh(target: Path, force: bool, *, directory: bool = True, owned=None, inputs=()) -> None:
    """Refuse an existing output unless --force was given and it is of the same kind and written by detcal, and one
    that is or holds one of the command's ``inputs`` (files it reads: --force would delete them).

    Checked before any work; the writer checks again when it moves its output into place.
    """
    from profiles.atomic import check_replaceable

    check_replaceable(target, overwrite=force, directory=directory, owned=owned)
    if force and os.path.lexists(target):
        t = Path(target).resolve()
        for given in inputs:
            if given is None or not os.path.lexists(given):
                continue  # a profile given by name, an option not given
            p = Path(given).resolve()
            if p == t or t in p.parents:
                what = "is the input," if p == t else f"holds the input {given},"
                raise UsageError(f"{target}: {what} which --force would delete; write elsewhere")


def positive(flag: str, value: int | None) -> None:
    if value is not None and value < 1:
        raise UsageError(f"{flag}: expected a positive integer, got {value}")


def summary_table(title: str, rows: dict, why_undefined: Callable[[str], str] | None = None) -> Table:
    """A two-column table of quantities; a NaN is printed ``n/a`` with the reason ``why_undefined(key)`` gives."""
    t = Table(title=title)
    t.add_column("quantity")
    t.add_column("value", justify="right")
    for k, v in rows.items():
        if isinstance(v, float) and v != v:
            v = f"n/a ({why_undefined(k)})" if why_undefined is not None else "n/a (not defined here)"
        elif isinstance(v, float):
            v = f"{v:.4g}"
        elif isinstance(v, list):
            v = ", ".join(f"{x:.4g}" if isinstance(x, float) else str(x) for x in v)
        t.add_row(k, str(v))
    return t


def input_refs(path: Path, log) -> list:
    """The log's input files with their sha256 (see :func:`calib.io.registry.input_refs`)."""
    from calib.io.registry import input_refs as refs

    return refs(path, log)
