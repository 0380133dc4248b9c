"""YAML configs into pydantic models, with errors that name the file and the field path."""

from __future__ import annotations

from pathlib import Path
from typing import TypeVar

import yaml
from pydantic import BaseModel, ValidationError

from profiles import strict_yaml
from profiles.errors import UsageError

M = TypeVar("M", bound=BaseModel)


def validation_message(exc: ValidationError, where: str) -> str:
    """One line: ``where: a.b.c: what was wrong`` for the first error (and how many more)."""
    errs = exc.errors()
    e = errs[0]
    loc = ".".join(str(p) for p in e["loc"])
    msg = e["msg"]
    if e["type"] == "extra_forbidden":
        msg = "unknown key"
    elif e["type"] == "union_tag_not_found" and "discriminator" in e.get("ctx", {}):
        msg = f"missing the key {e['ctx']['discriminator']}, which says which kind it is"
    elif e["type"] == "value_error" and "error" in e.get("ctx", {}):
        msg = str(e["ctx"]["error"])  # a model's own check: its text names the fields, without pydantic's "Value error, "
    more = f" (and {len(errs) - 1} more)" if len(errs) > 1 else ""
    if not loc:
        return f"{where}: {msg}{more}"
    return f"{where}: {loc}: {msg}{more}"


def load_yaml_model(model: type[M], path: str | Path | None, updates: dict | None = None, flags: dict[str, str] | None = None) -> M:
    """Defaults when ``path`` is None; otherwise the YAML file validated against ``model``. ``updates`` ({dotted path:
    value}; None: not given) replace the file's values before the one validation, so that checks across fields see the
    command line's values (``--particles`` beside a file's ``islands``); an error in one of them names its option
    (``flags``: dotted path -> option, default ``--<key>``)."""
    given = {k: v for k, v in (updates or {}).items() if v is not None}

    def refuse(exc: ValidationError, where: str):
        loc = ".".join(str(p) for p in exc.errors()[0]["loc"])
        for key in sorted(given, key=len, reverse=True):
            if loc == key or loc.startswith(key + "."):  # the command line's value: name its option
                flag = (flags or {}).get(key, f"--{key.replace('_', '-')}")
                return UsageError(f"{flag}: {exc.errors()[0]['msg']}")
        return UsageError(validation_message(exc, where))

    data = {}
    if path is not None:
        data = read_yaml_mapping(Path(path))
    for key, value in given.items():
        set_dotted(data, key, value)
    try:
        return model.model_validate(data)
    except ValidationError as exc:
        raise refuse(exc, "the command line" if path is None else str(path)) from None


def set_dotted(data: dict, key: str, value: object) -> None:
    """Set the dotted setting ``key`` (``motion.ackermann.sigma_speed``) in a settings mapping, making the groups it
    passes through where they are absent or empty (null); a group that is not a mapping is left as it is (the
    validation then reports the file's own error)."""
    node = data
    *parents, last = key.split(".")
    for part in parents:
        if node.get(part) is None:
            node[part] = {}
        if not isinstance(node[part], dict):
            return
        node = node[part]
    node[last] = value


def read_yaml_mapping(path: Path) -> dict:
    """The mapping at the top of a YAML file; a UsageError naming the file (and line) for anything else."""
    if not path.is_file():
        raise UsageError(f"{path}: no such config file")
    try:
        data = strict_yaml.load(path.read_text(encoding="utf-8")) or {}
    except UnicodeDecodeError as exc:
        raise UsageError(f"{path}: not UTF-8 text (byte {exc.start})") from None
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        line = f":{mark.line + 1}" if mark is not None else ""
        raise UsageError(f"{path}{line}: not valid YAML ({getattr(exc, 'problem', None) or exc})") from None
    except (RecursionError, ValueError) as exc:
        raise UsageError(f"{path}: not valid YAML ({type(exc).__name__})") from None
    except OSError as exc:
        raise UsageError(f"{path}: cannot read ({exc.strerror or exc})") from None
    if not isinstance(data, dict):
        raise UsageError(f"{path}: expected a mapping at the top level")
    return data


def dump_yaml(data: object) -> str:
    """Deterministic YAML (sorted keys, exact floats)."""
    return yaml.safe_dump(data, sort_keys=True, default_flow_style=None, width=120)


def dump_yaml_ordered(data: object) -> str:
    """As :func:`dump_yaml`, the mappings' keys in their own order (a run's settings and metrics as written)."""
    return yaml.safe_dump(data, sort_keys=False, default_flow_style=None, width=120)
