"""``detcal detect``: the circle detector over every scan of a log."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from calib.cli.common import ReaderArgs, fresh, out, reader_options, summary_table
from profiles.errors import UsageError


@reader_options("fmt", "max_backstep", "laser", "range_max", "range_sigma", "scan_topic")
def detect_cmd(
    log_path: Annotated[Path, typer.Argument(metavar="LOG", help="A log with laser scans.")],
    reader: ReaderArgs,
    out_dir: Annotated[Path | None, typer.Option("--out", help="Run folder (default: runs/detect_<log name>).")] = None,
    profile: Annotated[str | None, typer.Option(help="Use a profile's detector, Hotelling gate and P_D table (name or name@version, or a file).")] = None,
    config: Annotated[Path | None, typer.Option(help="YAML with `detector:` parameters and an optional `hotelling:` gate.")] = None,
    plot: Annotated[int | None, typer.Option("--plot", metavar="SCAN", help="Also draw this scan: clusters, circles, P_D field.")] = None,
    force: Annotated[bool, typer.Option(help="Replace the run folder if it exists.")] = False,
) -> None:
    """Run the circle (tree) detector over every scan and write a detections table."""
    from calib.config import load_yaml_model
    from calib.detect import DetectConfig, write_detect_run

    pd_table = None
    if profile is not None:
        if config is not None:
            raise UsageError("--profile and --config both set the detector; give one")
        from profiles.schema import HotellingParams
        from profiles.store import resolve

        prof = resolve(profile)
        if prof.detector.kind != "circle2d":
            raise UsageError(f"profile {prof.ref} is for an external detector, not the circle detector")
        hot = None if prof.hotelling is None else HotellingParams.model_validate(prof.hotelling.model_dump(include=set(HotellingParams.model_fields)))
        cfg = DetectConfig(detector=prof.detector.circle, hotelling=hot, k_sigma=prof.detector.k_sigma)
        pd_table = prof.pd if prof.pd.covariate == "n_p" else None
    else:
        cfg = load_yaml_model(DetectConfig, config)
    log = reader.read(log_path)
    target = out_dir or Path("runs") / f"detect_{log.name}"
    fresh(target, force)
    summary = write_detect_run(log, cfg, target, plot_scan=plot, pd_table=pd_table, overwrite=force)
    out.print(summary_table(f"detections -> {target}", summary))
