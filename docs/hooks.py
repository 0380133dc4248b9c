"""MkDocs hooks: the generated reference pages.

A page that holds ``<!-- generated: cli -->`` gets the help of every ``detcal``
command, read from the typer app (:func:`detcal.cli.command`); one that holds
``<!-- generated: profile-schema -->`` gets a table per model of a detector
profile, read from the pydantic models (:class:`profiles.profile.DetectorProfile`)
with the units of :mod:`profiles.units`. Nothing of either is written by hand,
so the reference cannot drift from the code.
"""

from __future__ import annotations

from pydantic_core import PydanticUndefined


def cli_reference() -> str:
    """Markdown: one section per command, its ``--help`` as the command line prints it (100 columns)."""
    from detcal.cli import command

    root = command()
    parts: list[str] = []

    def walk(cmd, ctx, path: list[str]) -> None:
        subs = getattr(cmd, "commands", {})
        if path and not subs:
            title = "detcal " + " ".join(path)
            parts.append(f"## `{title}`\n\n```text\n{cmd.get_help(ctx).rstrip()}\n```\n")
        for name in subs:
            sub = subs[name]
            walk(sub, sub.context_class(sub, info_name=name, parent=ctx), [*path, name])

    top = root.context_class(root, info_name="detcal", max_content_width=100, terminal_width=100)
    parts.append(f"```text\n{root.get_help(top).rstrip()}\n```\n")
    walk(root, top, [])
    return "\n".join(parts)


def _type_name(annotation) -> str:
    text = str(annotation).replace("typing.", "")
    if isinstance(annotation, type):
        text = annotation.__name__
    for mod in ("profiles.schema.", "profiles.profile.", "profiles.planes.", "NoneType"):
        text = text.replace(mod, "None" if mod == "NoneType" else "")
    return text.replace("<class '", "").replace("'>", "")


def _cell(text: str) -> str:
    return " ".join(str(text).split()).replace("|", "\\|")


def profile_schema_reference() -> str:
    """Markdown: every model of a detector profile, its fields with type, default, unit and description."""
    from profiles.profile import SCHEMA_VERSION, DetectorProfile
    from profiles.units import UNITS, models_of

    models = models_of(DetectorProfile)
    parts = [f"Schema version {SCHEMA_VERSION}. Every model refuses unknown keys; a unit that depends on another field "
             "says so (the clutter space).\n"]  # fmt: skip
    for cls in models:
        doc = _cell((cls.__doc__ or "").strip().split("\n\n")[0])
        rows = ["| field | type | default | unit | description |", "|---|---|---|---|---|"]
        for name, f in cls.model_fields.items():
            default = "required" if f.default is PydanticUndefined and f.default_factory is None else (
                "(empty)" if f.default_factory is not None else repr(f.default))  # fmt: skip
            u = UNITS.get(f"{cls.__name__}.{name}", "")
            u = "depends on `space`" if callable(u) and name in ("volume", "kappa") else ("of the covariate" if callable(u) else u)
            rows.append(f"| `{name}` | `{_cell(_type_name(f.annotation).replace(' | ', ' or '))}` | `{_cell(default)}` | {_cell(u)} | {_cell(f.description or '')} |")
        parts.append(f"## {cls.__name__}\n\n{doc}\n\n" + "\n".join(rows) + "\n")
    return "\n".join(parts)


GENERATORS = {"<!-- generated: cli -->": cli_reference, "<!-- generated: profile-schema -->": profile_schema_reference}


def on_page_markdown(markdown: str, page, config, files) -> str:
    for marker, generate in GENERATORS.items():
        if marker in markdown:
            markdown = markdown.replace(marker, generate())
    return markdown
