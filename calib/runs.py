"""Run folders of ``detcal calibrate`` and ``detcal validate``."""

from __future__ import annotations

from pathlib import Path

from calib.calibrate import Calibration
from calib.config import dump_yaml
from calib.io.atomic import atomic_output
from profiles.store import dump_profile

GZ = {"method": "gzip", "mtime": 0}  # fixed header time: same tables, same bytes


def write_calibration_run(cal: Calibration, out: Path, *, overwrite: bool = False) -> list[str]:
    """profile.yaml, config.yaml, summary.yaml, detections.csv.gz, pairs.csv.gz and the report figures."""
    from calib.report import write_report

    with atomic_output(out, overwrite=overwrite, directory=True) as tmp:
        tmp.mkdir()
        (tmp / "profile.yaml").write_text(dump_profile(cal.profile))
        (tmp / "config.yaml").write_text(dump_yaml(cal.config.model_dump(mode="json")))
        (tmp / "summary.yaml").write_text(dump_yaml(cal.summary))
        cal.labelled.detections.to_csv(tmp / "detections.csv.gz", index=False, float_format="%.9g", compression=GZ)
        cal.labelled.pairs.to_csv(tmp / "pairs.csv.gz", index=False, float_format="%.9g", compression=GZ)
        figures = write_report(cal, tmp)
    return figures
