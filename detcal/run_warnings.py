"""The warnings of one command, kept for its run folder.

Every warning the command line prints (:func:`detcal.cli.common.warn`: each a
count or a fact about the input, such as records dropped outside the truth's
time span or a profile migrated from an earlier schema) is recorded here as
well; every run folder the command writes (a folder with a ``summary.yaml``, or the
``metrics.yaml`` that summarises a SLAM run) gets them, as they were printed,
in ``warnings.yaml`` (written also when there are none) and under ``warnings``
in that summary. The same inputs give the same
warnings, so the bytes stay reproducible. Warnings printed after the folder is
in place are not in it.
"""

from __future__ import annotations

from pathlib import Path

import yaml

from calib.config import dump_yaml, dump_yaml_ordered

_RECORDED: list[str] = []
#: the files that summarise a run folder (the first found gets the warnings), each with its writer's YAML dumper
SUMMARIES = {"summary.yaml": dump_yaml, "metrics.yaml": dump_yaml_ordered}


def record(line: str) -> None:
    """Keep one printed warning (a repeat of the same line is kept once)."""
    if line not in _RECORDED:
        _RECORDED.append(line)


def recorded() -> list[str]:
    return list(_RECORDED)


def clear() -> None:
    """Forget what was recorded (the start of a command)."""
    _RECORDED.clear()


def add_to_run_folder(folder: Path) -> None:
    """``warnings.yaml`` and the summary's ``warnings`` in a run folder about to be moved into place (one with a
    ``summary.yaml`` or ``metrics.yaml`` mapping; any other folder output, such as a ROS 2 bag, is left alone)."""
    summary_file = next((Path(folder) / n for n in SUMMARIES if (Path(folder) / n).is_file()), None)
    if summary_file is None:
        return
    lines = recorded()
    (Path(folder) / "warnings.yaml").write_text(dump_yaml({"count": len(lines), "warnings": lines}))
    if not lines:
        return
    summary = yaml.safe_load(summary_file.read_text())
    if isinstance(summary, dict) and "warnings" not in summary:  # written again as its writer wrote it
        summary_file.write_text(SUMMARIES[summary_file.name]({**summary, "warnings": lines}))
