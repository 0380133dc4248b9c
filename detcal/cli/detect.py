"""``detcal detect``: the circle detector over every scan of a log, or the plane detector over every cloud."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from detcal.cli.common import ReaderArgs, fresh, out, reader_options, summary_table


@reader_options("fmt", "max_backstep", "laser", "range_max", "range_sigma", "scan_topic")
def detect_cmd(
    log_path: Annotated[Path, typer.Argument(metavar="LOG", help="A log with laser scans, or with 3D point clouds (planes).")],
    reader: ReaderArgs,
    out_dir: Annotated[Path | None, typer.Option("--out", help="Run folder (default: runs/detect_<log name>).")] = None,
    profile: Annotated[str | None, typer.Option(help="Use a profile's detector, Hotelling gate and P_D table (name or name@version, or a file).")] = None,
    config: Annotated[Path | None, typer.Option(help="YAML with `detector:` parameters and an optional `hotelling:` gate.")] = None,
    plot: Annotated[
        int | None,
        typer.Option("--plot", metavar="SCAN", help="Also draw this scan (clusters, circles, P_D field) or cloud (planes; predicted vs segmented)."),
    ] = None,
    force: Annotated[bool, typer.Option(help="Replace the run folder if it exists.")] = False,
) -> None:
    """Run the circle (tree) detector over every scan, or the plane detector over every point cloud, and write a table."""
    from detcal.reports.detect import detect_config, write_detect_run

    log = reader.read(log_path)
    if log.scans is None and log.clouds is not None:
        from detcal.reports.detect import plane_detect_config, write_plane_detect_run

        pcfg = plane_detect_config(profile, config)
        target = out_dir or Path("runs") / f"detect_{log.name}"
        fresh(target, force, inputs=[log_path, profile, config])
        summary = write_plane_detect_run(log, pcfg, target, plot_frame=plot, overwrite=force)
        out.print(summary_table(f"planes -> {target}", summary))
        return
    cfg, pd_table = detect_config(profile, config)
    target = out_dir or Path("runs") / f"detect_{log.name}"
    fresh(target, force, inputs=[log_path, profile, config])
    summary = write_detect_run(log, cfg, target, plot_scan=plot, pd_table=pd_table, overwrite=force)
    out.print(summary_table(f"detections -> {target}", summary))
