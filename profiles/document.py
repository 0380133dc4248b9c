"""A profile as a person reads and diffs it: the written document of schema 3.

What :func:`profiles.store.dump_profile` writes for a schema-3 profile, and
how the reader turns it back into the model's fields:

* every quantity carries its unit in a comment (``range_max: 80.0  # m``),
  from :data:`profiles.units.UNITS`;
* fitted figures are rounded to :data:`profiles.units.SIGNIFICANT` significant
  digits; what a person or a log header gave (the sensor, the detector's
  parameters, bin edges, the recorded parameters) is written exactly;
* the P_D table is written as ``bins``, one row per bin
  (``{from, to, pd, counts, detections, wilson_low, wilson_high}``), so a change
  in one bin is a change of one line; matrices are one row per line; no line
  is wrapped;
* the same profile gives the same bytes (keys in schema order).

The model keeps the table as columns (``edges``, ``pd``, ``counts``, ...);
:func:`columns_from_bins` is the reader's side of the transformation.
"""

from __future__ import annotations

import copy

import numpy as np
import yaml
from pydantic import BaseModel

from profiles.errors import DataError
from profiles.units import SIGNIFICANT, rounded, unit

#: the P_D table's per-bin columns, in the order a bin row lists them
BIN_COLUMNS = ("pd", "counts", "detections", "wilson_low", "wilson_high", "between_sensor_sd", "effective_counts")
#: models whose floats are written exactly: given by a person or a log header, not fitted
EXACT_MODELS = ("SensorModel", "Mount", "LidarGeometry", "BeamGeometry", "DetectorSpec", "CircleDetectorParams", "PlaneDetectorParams", "Provenance")


def _is_exact_field(name: str) -> bool:
    return name.endswith(("edges", "edges_deg"))


def _round_tree(v):
    if isinstance(v, float):
        return rounded(v)
    if isinstance(v, list):
        return [_round_tree(x) for x in v]
    return v


def round_fitted(model: BaseModel, data: dict) -> None:
    """Round the fitted floats of ``data`` (``model``'s dump, changed in place) to :data:`SIGNIFICANT` digits.

    A covariance whose rounding would leave it not positive definite keeps its exact figures (never met with
    descriptors of a few units, whose condition numbers are far below 1e5).
    """
    if type(model).__name__ in EXACT_MODELS:
        return
    for name, value in list(data.items()):
        sub = getattr(model, name, None)
        if isinstance(sub, BaseModel) and isinstance(value, dict):
            round_fitted(sub, value)
        elif isinstance(sub, list | tuple) and sub and isinstance(sub[0], BaseModel):
            for m, d in zip(sub, value, strict=True):
                round_fitted(m, d)
        elif not _is_exact_field(name):
            r = _round_tree(value)
            if name == "covariance" and np.linalg.eigvalsh(np.asarray(r, dtype=np.float64)).min() <= 0:
                continue
            data[name] = r


def bins_from_columns(pd: dict) -> dict:
    """The P_D table's columns -> ``bins`` (one mapping per bin, in place of ``edges`` and the columns)."""
    edges = pd["edges"]
    cols = [c for c in BIN_COLUMNS if pd.get(c) is not None]
    rows = []
    for i in range(len(edges) - 1):
        rows.append({"from": edges[i], "to": edges[i + 1], **{c: pd[c][i] for c in cols}})
    out = {}
    for k, v in pd.items():
        if k == "edges":
            out["bins"] = rows
        elif k not in BIN_COLUMNS:
            out[k] = v
    return out


def columns_from_bins(data: dict, where: str) -> dict:
    """A document whose ``pd`` holds ``bins`` -> the model's columns (``data`` itself when it has none)."""
    pd = data.get("pd")
    if not isinstance(pd, dict) or "bins" not in pd:
        return data
    rows = pd["bins"]
    if not isinstance(rows, list) or not rows:
        raise DataError(f"{where}: pd.bins: a list of one or more bins")
    clash = sorted({"edges", *BIN_COLUMNS} & set(pd))
    if clash:
        raise DataError(f"{where}: pd.{clash[0]}: given both as a column and in pd.bins; give the table one way")
    cols = [c for c in BIN_COLUMNS if isinstance(rows[0], dict) and c in rows[0]]
    want = {"from", "to", *cols}
    table: dict = {"edges": [], **{c: [] for c in cols}}
    for i, row in enumerate(rows):
        if not isinstance(row, dict):
            raise DataError(f"{where}: pd.bins.{i}: a mapping {{from, to, pd, ...}}")
        if set(row) != want:
            key = sorted(set(row) ^ want)[0]
            what = "unknown key" if key in row else f"missing (bin 0 gives {key})" if key in rows[0] else "missing"
            raise DataError(f"{where}: pd.bins.{i}.{key}: {what}")
        if i and row["from"] != rows[i - 1]["to"]:
            raise DataError(f"{where}: pd.bins.{i}.from: {row['from']!r} is not the previous bin's end {rows[i - 1]['to']!r}")
        table["edges"].append(row["from"])
        for c in cols:
            table[c].append(row[c])
    table["edges"].append(rows[-1]["to"])
    out = dict(data)
    out["pd"] = {k: v for k, v in pd.items() if k != "bins"} | table
    return out


def written(profile: BaseModel, data: dict) -> dict:
    """The document of a schema-3 profile: fitted figures rounded, the P_D table as bins."""
    data = copy.deepcopy(data)
    round_fitted(profile, data)
    data["pd"] = bins_from_columns(data["pd"])
    return data


def _flow(v) -> str:
    """One value on one line, in YAML flow style (the YAML library's quoting and float forms)."""
    text = yaml.safe_dump([v], default_flow_style=True, sort_keys=False, width=float("inf"), allow_unicode=True).strip()
    return text[1:-1]


def _comment(u: str | None) -> str:
    return f"  # {u}" if u else ""


def _bins_legend(model: BaseModel, rows: list[dict]) -> str:
    pd = {"covariate": model.covariate}
    parts = [f"from, to [{unit('PdTable', 'edges', pd)}]"]
    for c in rows[0]:
        if c not in ("from", "to"):
            parts.append(f"{c} [{unit('PdTable', c, pd)}]")
    return "# one bin per line: " + "; ".join(parts)


def render(profile: BaseModel, data: dict) -> str:
    """YAML text of a written document (:func:`written`) with the units as comments."""
    head = [
        f"# detector profile {profile.name}@{profile.version} (schema {profile.schema_version}): units in comments; fitted",
        f"# figures to {SIGNIFICANT} significant digits; the P_D table one bin per line. Reference: docs/reference/profile.md",
    ]
    lines: list[str] = []
    _emit(profile, data, 0, lines)
    return "\n".join(head + lines) + "\n"


def _emit(model: BaseModel, data: dict, indent: int, lines: list[str]) -> None:
    pad = " " * indent
    cls = type(model).__name__
    for key, value in data.items():
        sub = getattr(model, key, None)
        if isinstance(sub, BaseModel) and isinstance(value, dict):
            lines.append(f"{pad}{_flow(key)}:")
            _emit(sub, value, indent + 2, lines)
        elif key == "bins" and cls == "PdTable":
            lines.append(f"{pad}{_bins_legend(model, value)}")
            lines.append(f"{pad}{key}:")
            lines.extend(f"{pad}- {_flow(row)}" for row in value)
        elif isinstance(value, dict) and value:
            # free mappings (provenance parameters, packages): one key per line, their values on one line each
            lines.append(f"{pad}{_flow(key)}:")
            for k, v in value.items():
                lines.append(f"{pad}  {_flow(k)}: {_flow(v)}")
        elif isinstance(value, list) and value and all(isinstance(v, list | dict) for v in value):
            lines.append(f"{pad}{_flow(key)}:{_comment(unit(cls, key, data))}")
            lines.extend(f"{pad}- {_flow(row)}" for row in value)
        else:
            lines.append(f"{pad}{_flow(key)}: {_flow(value)}{_comment(unit(cls, key, data))}")


def body(text: str) -> str:
    """The document below any comment lines above it (a comment added by hand, or the schema-3 header)."""
    lines = text.splitlines(keepends=True)
    i = next((k for k, line in enumerate(lines) if line.strip() and not line.lstrip().startswith("#")), len(lines))
    return "".join(lines[i:])
