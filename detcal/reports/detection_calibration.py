"""The run folder of a detection-level calibration (``detcal calibrate`` on UTIAS-like logs) and its figures."""

from __future__ import annotations

from calib.config import dump_yaml
from calib.detlevel import DetectionCalibration
from detcal.reports.calibration import plot_clutter, plot_clutter_density, plot_pd, plot_pd_grid, plot_sensors
from profiles.store import dump_profile


def fill_detection_run(cal: DetectionCalibration, folder) -> list[str]:
    """Create ``folder`` with profile.yaml (and sensors/ with the per-sensor profiles), summary.yaml,
    config.yaml, pairs.csv.gz and the figures; returns the figure names."""

    figures = []
    tmp = folder
    tmp.mkdir()
    (tmp / "profile.yaml").write_text(dump_profile(cal.profile))
    if cal.members:
        (tmp / "sensors").mkdir()
        for m in cal.members:
            (tmp / "sensors" / f"{m.name}@{m.version}.yaml").write_text(dump_profile(m))
    (tmp / "summary.yaml").write_text(dump_yaml(cal.summary))
    if cal.config is not None:
        (tmp / "config.yaml").write_text(dump_yaml(cal.config.model_dump(mode="json")))
    if cal.motion is not None:  # SLAM settings for `detcal slam run --config`: the vehicle model measured on these logs
        m = cal.motion
        v = {k: float(f"{x:.4g}") for k, x in m["velocity"].items()}
        head = (
            f"# velocity odometry measured against ground truth over {m['windows']} windows of {m['window_s']:g} s"
            f" (the turn-rate scale over windows of {m['scale_window_s']:g} s; {m['broken_truth_intervals']} intervals"
            " of the ground truth left out as glitches)\n"
        )
        (tmp / "motion.yaml").write_text(head + dump_yaml({"motion": {"velocity": v}}))
    cal.pairs.to_csv(tmp / "pairs.csv.gz", index=False, float_format="%.9g", compression={"method": "gzip", "mtime": 0})
    if cal.profile.pd.two_d:
        plot_pd_grid(cal.profile.pd, cal.pairs, tmp / "pd_range_bearing.png")
        figures.append("pd_range_bearing.png")
    else:
        plot_pd(cal, tmp / "pd_vs_range.png")
        figures.append("pd_vs_range.png")
    plot_clutter(cal, tmp / "clutter.png")
    figures.append("clutter.png")
    if cal.profile.clutter.density is not None:
        plot_clutter_density(cal.profile.clutter, tmp / "clutter_density.png")
        figures.append("clutter_density.png")
    if len(cal.names) > 1:
        plot_sensors(cal, tmp / "sensors.png")
        figures.append("sensors.png")
    return figures
