"""The ``detcal`` command line: the one composition root.

Thin by design: parse, cross-check options, call one pipeline function, print
a result table. One module per command group (``logs``, ``simulate``,
``detect``, ``calibrate`` (with selfcal and icp), ``validate``, ``profile``, ``slam``); the reader options are
defined once (:mod:`detcal.cli.common`). Library errors
(:class:`profiles.errors.DetcalError`) become one-line plain-text messages with
exit code 1 (bad data) or 2 (usage); a user never sees a traceback for bad
input.
"""

from __future__ import annotations

import os
import sys
from typing import Annotated

import typer

from detcal import __version__
from detcal.environment import check_source_date_epoch, numba_cache
from profiles.errors import DetcalError

# Before the commands' modules are imported: numpy reads SOURCE_DATE_EPOCH as it imports f2py (a bad value is kept
# out of its way and reported by main), and numba's kernels (cache=True) look for a cache folder at import.
try:
    check_source_date_epoch()
    _ENV_ERROR: DetcalError | None = None
except DetcalError as _exc:
    _ENV_ERROR = _exc
    os.environ.pop("SOURCE_DATE_EPOCH")
_NUMBA_FALLBACK = numba_cache()

import importlib  # noqa: E402

from detcal.cli.common import out, warn  # noqa: E402

#: The command groups and single commands, by name: (module of detcal.cli, its typer app or command function). A run
#: of one command imports only its module (:func:`build`): a SLAM run does not pay for the calibration's imports.
GROUPS = {"log": ("logs", "app"), "simulate": ("simulate", "app"), "profile": ("profile", "app"), "slam": ("slam", "app")}
COMMANDS = {
    "detect": ("detect", "detect_cmd"), "calibrate": ("calibrate", "calibrate_cmd"), "validate": ("validate", "validate_cmd"),
    "icp": ("calibrate", "icp_cmd"), "selfcal": ("calibrate", "selfcal_cmd"),
}  # fmt: skip


def build(only: str | None = None) -> typer.Typer:
    """The app with every command (``only`` None) or with the command or group ``only`` alone (the others' modules
    not imported)."""
    app = typer.Typer(
        help="detcal: measure a feature detector's P_D and clutter statistics for RFS SLAM.",
        no_args_is_help=True,
        rich_markup_mode=None,  # plain help: option texts hold brackets such as [m]
        add_completion=False,
        pretty_exceptions_enable=False,
    )
    for name, (module, attr) in GROUPS.items():
        if only is None or only == name:
            app.add_typer(getattr(importlib.import_module(f"detcal.cli.{module}"), attr), name=name)
    for name, (module, attr) in COMMANDS.items():
        if only is None or only == name:
            app.command(name)(getattr(importlib.import_module(f"detcal.cli.{module}"), attr))
    app.callback()(_root)
    return app


def _version(value: bool) -> None:
    if value:
        out.print(f"detcal {__version__}")
        raise typer.Exit()


def _root(
    version: Annotated[bool, typer.Option("--version", callback=_version, is_eager=True, help="Print the version and exit.")] = False,
) -> None:
    """detcal: measure a feature detector's P_D and clutter statistics for RFS SLAM."""


def command(only: str | None = None):
    """The click command of the app (with ``only`` alone: :func:`build`), each option's value shown as its choices
    (:mod:`detcal.cli.choices`)."""
    from detcal.cli.choices import label

    return label(typer.main.get_command(build(only)))


def _only(args: list[str]) -> str | None:
    """The command or group the arguments run when they name one and ask for nothing of the whole app (its help, its
    version); None otherwise."""
    if not args or args[0] not in GROUPS and args[0] not in COMMANDS:
        return None
    return args[0]


def __getattr__(name: str):
    if name == "app":  # the whole app, built when asked for
        return build()
    raise AttributeError(name)


def error_line(message: str) -> None:
    """One plain-text line on stderr (never console markup: file names may hold brackets)."""
    sys.stderr.write(f"detcal: error: {' '.join(str(message).split())}\n")
    sys.stderr.flush()


def main(argv: list[str] | None = None) -> int:
    """Entry point: run the app, map DetcalError to a one-line message and its exit code.

    Usage errors found by the option parser are reported by typer itself (exit 2).
    """
    from detcal import run_warnings
    from detcal.cli import common
    from profiles.atomic import FOLDER_FINISHERS
    from profiles.notices import on_notice

    common.ARGV = list(sys.argv[1:] if argv is None else argv)
    run_warnings.clear()
    FOLDER_FINISHERS.append(run_warnings.add_to_run_folder)  # this command's run folders get its warnings
    said: set[str] = set()  # a profile loaded twice by one command is reported once

    def said_once(line: str) -> None:
        if line not in said:
            said.add(line)
            warn(line)

    stop_listening = on_notice(said_once)
    if _NUMBA_FALLBACK:
        warn(f"numba cannot write its cache of compiled kernels beside detcal nor under the user's cache folder; using {_NUMBA_FALLBACK}")
    try:
        if _ENV_ERROR is not None:
            raise _ENV_ERROR
        check_source_date_epoch()
        command(_only(common.ARGV)).main(args=argv, prog_name="detcal")
    except SystemExit as exc:
        code = exc.code
        if code == 130:  # typer turns a Ctrl-C into exit 130 itself
            sys.stderr.write("detcal: interrupted\n")
        return code if isinstance(code, int) else (0 if code is None else 1)
    except DetcalError as exc:
        error_line(str(exc))
        return exc.exit_code
    except OSError as exc:  # the system refused a read or write (permissions, a full disk): not a bug of ours
        where = f"{exc.filename}: " if exc.filename else ""
        error_line(f"{where}{exc.strerror or exc}")
        return 1
    except MemoryError:  # a reader that could not check a size first: say what it is, not a traceback
        error_line("out of memory: the input is too large for this machine's memory (it is not necessarily damaged)")
        return 1
    except KeyboardInterrupt:
        sys.stderr.write("detcal: interrupted\n")
        return 130
    finally:
        stop_listening()
        FOLDER_FINISHERS.remove(run_warnings.add_to_run_folder)
    return 0


def run() -> None:
    """Console-script entry point."""
    sys.exit(main())
