"""YAML configs into pydantic models, with errors that name the file and the field path."""

from __future__ import annotations

from pathlib import Path
from typing import TypeVar

import yaml
from pydantic import BaseModel, ValidationError

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


def load_yaml_model(model: type[M], path: str | Path | None, updates: dict | None = None) -> M:
    """Defaults when ``path`` is None; otherwise the YAML file validated against ``model``. ``updates`` (top-level keys;
    None: not given) replace the file's values before validation, so that checks across fields see the command line's
    values (``--particles`` beside a file's ``islands``)."""
    given = {k: v for k, v in (updates or {}).items() if v is not None}

    def refuse(exc: ValidationError, where: str):
        loc = exc.errors()[0]["loc"]
        if loc and loc[0] in given:  # the command line's value: name its option
            return UsageError(f"--{str(loc[0]).replace('_', '-')}: {exc.errors()[0]['msg']}")
        return UsageError(validation_message(exc, where))

    if path is None:
        try:
            return model.model_validate(given)
        except ValidationError as exc:
            raise refuse(exc, "the command line") from None
    path = Path(path)
    if not path.is_file():
        raise UsageError(f"{path}: no such config file")
    try:
        data = yaml.safe_load(path.read_text(encoding="utf-8")) or {}
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
    data = {**data, **given}
    try:
        return model.model_validate(data)
    except ValidationError as exc:
        raise refuse(exc, str(path)) from None


def dump_yaml(data: object) -> str:
    """Deterministic YAML (sorted keys, exact floats)."""
    return yaml.safe_dump(data, sort_keys=True, default_flow_style=None, width=120)
