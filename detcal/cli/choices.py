"""What ``--help`` shows as an option's value: its choices, read from the registries when the help is printed.

typer would show ``<str>`` for every text option; :func:`label` walks the click
command built from the typer app and gives each option without a metavar of
its own its choices (``[rbphd|lmb|glmb]``) or a plain name of its kind
(``TEXT``, ``INT``, ``PATH``). The values are still checked by the commands
(their messages name the option and the choices); this is what a person sees.
"""

from __future__ import annotations

import typing
from collections.abc import Callable


def _literal(model_path: str, field: str) -> Callable[[], tuple[str, ...]]:
    def choices() -> tuple[str, ...]:
        module, _, name = model_path.rpartition(".")
        model = getattr(__import__(module, fromlist=[name]), name)
        return typing.get_args(model.model_fields[field].annotation)

    return choices


def _registry(module: str, name: str) -> Callable[[], tuple[str, ...]]:
    return lambda: getattr(__import__(module, fromlist=[name]), name).names()


def _fixed(*values: str) -> Callable[[], tuple[str, ...]]:
    return lambda: values


#: (command path, option) or option alone -> its choices; the command path is the words after ``detcal``
CHOICES: dict[tuple[str, str] | str, Callable[[], tuple[str, ...]]] = {
    "--filter": _registry("slam_runtime.mapfilter", "MAP_FILTERS"),
    "--features": _registry("slam_runtime.features", "FEATURE_MODELS"),
    "--pd-mode": _literal("slam_runtime.config.DetectionOptions", "pd_mode"),
    "--poses": _literal("slam_runtime.config.SlamConfig", "poses"),
    ("calibrate", "--poses"): lambda: __import__("detcal.cli.calibrate", fromlist=["POSE_SOURCES"]).POSE_SOURCES,
    ("validate", "--poses"): lambda: __import__("detcal.cli.calibrate", fromlist=["POSE_SOURCES"]).POSE_SOURCES,
    "--format": _registry("calib.io.registry", "READERS"),
    ("profile export", "--format"): _fixed("yaml", "json"),
    "--to": _registry("calib.io.registry", "WRITERS"),
    "--laser": _fixed("front", "rear"),
    "--cv": _fixed("robots", "time"),
}

_KIND = {"str": "TEXT", "int": "INT", "float": "FLOAT", "Path": "PATH", "bool": "BOOL", "text": "TEXT", "integer": "INT", "path": "PATH"}


def _kind(param) -> str:
    """TEXT, INT, FLOAT or PATH: from the annotation typer recorded (or the click type's name)."""
    desc = getattr(param, "type_descriptor", None)
    t = getattr(desc, "annotation", None)
    while typing.get_args(t) and not isinstance(t, type):  # list[int], int | None -> int
        t = next(a for a in typing.get_args(t) if a is not type(None))
    name = getattr(t, "__name__", None) or getattr(getattr(param, "type", None), "name", "")
    return _KIND.get(name, "TEXT")


def _choices(path: str, opt: str) -> tuple[str, ...] | None:
    fn = CHOICES.get((path, opt)) or CHOICES.get(opt)
    return tuple(fn()) if fn is not None else None


def label(cmd, path: str = ""):
    """Set the metavar of every parameter of ``cmd`` (a click command built by typer) and its subcommands that
    has none; returns ``cmd``."""
    for param in cmd.params:
        if param.param_type_name == "argument" and hasattr(param, "display_type_rich"):
            param.display_type_rich = lambda ctx=None: None  # its metavar (LOG, PROFILE) says what it is
        if param.metavar is not None or getattr(param, "is_flag", False):
            continue
        name = next((o for o in param.opts if o.startswith("--")), param.opts[0])
        option = param.param_type_name == "option"
        found = _choices(path, name) if option else None
        if found:
            param.metavar = "[" + "|".join(found) + "]"
        elif option:
            param.metavar = _kind(param)
        else:
            param.metavar = param.name.upper()
        if getattr(param, "multiple", False) or (param.nargs != 1 and not option):
            param.metavar += "..."
    for name, sub in getattr(cmd, "commands", {}).items():
        label(sub, f"{path} {name}".strip())
    return cmd
