"""Run folders of ``detcal calibrate`` and ``detcal validate``."""

from __future__ import annotations

from pathlib import Path

import pandas as pd

from calib.calibrate import Calibration
from calib.config import dump_yaml
from calib.io.atomic import atomic_output
from profiles.store import dump_profile

GZ = {"method": "gzip", "mtime": 0}  # fixed header time: same tables, same bytes


def write_calibration_run(cal: Calibration, out: Path, *, overwrite: bool = False) -> list[str]:
    """The run folder of :func:`fill_calibration_run`, written atomically."""
    with atomic_output(out, overwrite=overwrite, directory=True) as tmp:
        figures = fill_calibration_run(cal, tmp)
    return figures


def fill_calibration_run(cal: Calibration, folder: Path) -> list[str]:
    """Create ``folder`` with profile.yaml, config.yaml, summary.yaml, detections.csv.gz, pairs.csv.gz,
    range_noise.csv (when sigma_r was estimated) and the report figures; returns the figure names."""
    from calib.report import write_report

    folder.mkdir()
    (folder / "profile.yaml").write_text(dump_profile(cal.profile))
    (folder / "config.yaml").write_text(dump_yaml(cal.config.model_dump(mode="json")))
    (folder / "summary.yaml").write_text(dump_yaml(cal.summary))
    cal.labelled.detections.to_csv(folder / "detections.csv.gz", index=False, float_format="%.9g", compression=GZ)
    cal.labelled.pairs.to_csv(folder / "pairs.csv.gz", index=False, float_format="%.9g", compression=GZ)
    if cal.range_noise is not None:
        pd.DataFrame(cal.range_noise.summary()["bands"]).to_csv(folder / "range_noise.csv", index=False, float_format="%.6g")
    return write_report(cal, folder)
