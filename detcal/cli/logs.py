"""``detcal log info`` and ``detcal log convert``."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import numpy as np
import typer
from rich.table import Table

from detcal.cli.common import ReaderArgs, fresh, out, reader_options

app = typer.Typer(help="Inspect and convert sensor logs.", no_args_is_help=True, rich_markup_mode=None)


@app.command("info")
@reader_options()
def log_info(path: Annotated[Path, typer.Argument(help="A log file or folder.")], reader: ReaderArgs) -> None:
    """Print a summary of a log: streams, counts, duration, beam geometry."""
    log = reader.read(path, empty_ok=True)
    out.print(info_table(log, path))


def info_table(log, path: Path) -> Table:
    t = Table(title=f"{path} ({log.source.get('reader', 'native')})", show_header=True)
    t.add_column("stream")
    t.add_column("count", justify="right")
    t.add_column("details")
    span = log.time_span()
    if log.scans is not None:
        s = log.scans
        ang = log.scan_angles()
        beams = np.isfinite(np.broadcast_to(ang, s.ranges.shape))  # a scan's own beams (not the padding of a shorter layout)
        share = np.isfinite(s.ranges).sum() / max(1, int(beams.sum()))
        t.add_row("scans", f"{len(s):,}", f"{s.n_beams} beams, {share * 100:.1f} % returning")
    if log.odometry is not None:
        t.add_row("odometry", f"{len(log.odometry):,}", f"{log.odometry.kind}: {', '.join(log.odometry.columns)}")
    for k, r in log.reference.items():
        t.add_row(f"reference ({k})", f"{len(r):,}", "x, y" + (", theta" if np.isfinite(r.poses[:, 2]).any() else ""))
    if log.landmarks is not None:
        t.add_row("landmarks", f"{len(log.landmarks):,}", "with radii" if np.isfinite(log.landmarks.radius).any() else "positions")
    if log.detections is not None:
        d = log.detections
        t.add_row("detection frames", f"{d.n_frames:,}", "")
        t.add_row("detections", f"{len(d):,}", "descriptors: " + (", ".join(sorted(d.descriptors)) or "none"))
    if log.clouds is not None:
        c = log.clouds
        per = np.diff(c.offsets)
        if per.size:
            rng = np.linalg.norm(c.points[:, :3].astype(np.float64), axis=1)
            detail = (
                f"{c.points.shape[0]:,} points; per frame min {per.min():,}, median {int(np.median(per)):,}, max {per.max():,}; "
                f"range {rng.min():.2f}-{rng.max():.1f} m (median {np.median(rng):.1f}); z {c.points[:, 2].min():.2f} to {c.points[:, 2].max():.2f} m"
            )
            empty = int((per == 0).sum())
            if empty:
                detail += f"; {empty} empty frames"
        else:
            detail = "no frames"
        t.add_row("point clouds", f"{len(c):,}", detail)
    if log.planes is not None:
        kinds, counts = np.unique(log.planes.kind, return_counts=True)
        t.add_row("planes (truth)", f"{len(log.planes):,}", ", ".join(f"{k} {n}" for k, n in zip(kinds, counts, strict=True)))
    if span is not None:
        t.add_row("duration", "", f"{(span[1] - span[0]) / 1e9:,.3f} s")
    sen = log.sensor
    if sen is not None:
        geo = f"{sen.kind}"
        layouts = sen.layouts()
        if len(layouts) == 1:
            g = layouts[0]
            geo += (
                f", {g.n_beams} beams from {np.rad2deg(g.angle_min):.2f} deg every "
                f"{np.rad2deg(g.angle_increment):.4f} deg (fov {np.rad2deg(sen.field_of_view):.1f} deg)"
            )
        elif layouts:
            used = np.bincount(log.scans.geometry, minlength=len(layouts)) if log.scans is not None else np.zeros(len(layouts), int)
            geo += f", {len(layouts)} beam layouts: " + "; ".join(
                f"{g.n_beams} beams from {np.rad2deg(g.angle_min):.2f} deg every {np.rad2deg(g.angle_increment):.4f} deg ({n:,} scans)"
                for g, n in zip(layouts, used, strict=True)
            )
        if sen.range_max is not None:
            geo += f", range {sen.range_min:g}-{sen.range_max:g} m"
        if sen.range_sigma is not None:
            geo += f", sigma_r {sen.range_sigma:g} m"
        if sen.lidar is not None:
            va = sen.lidar.vertical_angles_deg
            geo += (
                f", {len(va)} rings from {max(va):.2f} to {min(va):.2f} deg, azimuth step {sen.lidar.azimuth_increment_deg:g} deg, "
                f"height {sen.lidar.height:g} m"
            )
        m = sen.mount
        geo += f", mounted at ({m.x:g}, {m.y:g}, {m.theta:g})"
        t.add_row("sensor", "", geo)
    moved = {k: v for k, v in dict(log.source.get("reordered", {})).items() if v}
    if moved:
        t.add_row("re-sorted", "", ", ".join(f"{k}: {v}" for k, v in moved.items()) + " records were out of time order")
    untimed = {k: v for k, v in dict(log.source.get("untimed", {})).items() if v}
    if untimed:
        t.add_row("untimed", "", ", ".join(f"{k}: {v}" for k, v in untimed.items()) + " records stamped 0, placed by their order")
    return t


@app.command("convert")
@reader_options()
def log_convert(
    src: Annotated[Path, typer.Argument(help="The log to read.")],
    dst: Annotated[Path, typer.Argument(help="Output: NAME.dlog (native) or a folder name (a ROS 2 bag; KITTI frames with --to kitti).")],
    reader: ReaderArgs,
    to: Annotated[str | None, typer.Option("--to", help="Output format: native, ros2 or kitti (default: from DST).")] = None,
    force: Annotated[bool, typer.Option(help="Replace DST if it exists.")] = False,
) -> None:
    """Convert a log to detcal's native format, a ROS 2 bag or KITTI Velodyne frames (point clouds only)."""
    from calib.io.native import is_detcal_log
    from calib.io.registry import output_format, write_log

    kind = output_format(dst, to)  # check before the (possibly long) read
    if kind == "native":
        fresh(dst, force, directory=False, owned=is_detcal_log, inputs=[src])
    else:
        fresh(dst, force, inputs=[src])
    log = reader.read(src)
    write_log(log, dst, kind, overwrite=force)
    if kind == "kitti":  # only the clouds travel (calib.io.kitti.write_kitti)
        out.print(f"wrote {dst} ({kind}): {len(log.clouds)} frames of point clouds")
    else:
        out.print(f"wrote {dst} ({kind}): {', '.join(log.streams())}")
