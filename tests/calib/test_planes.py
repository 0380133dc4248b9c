"""Plane-detector calibration on simulated streets: the profile recovers the simulator's statistics."""

from __future__ import annotations

import numpy as np
import pytest

from calib.planes import PlaneCalibConfig, calibrate_planes, validate_planes
from profiles.errors import UsageError
from profiles.profile import DetectorProfile
from profiles.store import dump_profile, parse_profile


def test_profile_is_a_valid_lidar3d_planes_profile(street_profile):
    p = street_profile
    assert p.kind == "lidar3d-planes" and p.pd.covariate == "points" and p.clutter.space == "plane"
    import yaml

    back = parse_profile(yaml.safe_load(dump_profile(p)), "round trip")  # the written figures: six digits
    assert dump_profile(back) == dump_profile(p) and back.planes.pd_grid.points_edges == p.planes.pd_grid.points_edges


def test_pd_and_noise_recover_the_simulator(street_profile):
    """What the simulator makes true: planes with no expected returns are never found (P_D 0 below 10 points);
    planes with hundreds of unoccluded returns nearly always (the detector found >= 95 % of such planes in
    tests/detectors/test_plane.py; with the 2 % dropouts and partial views a bin at >= 400 points is >= 0.85);
    the fitted normal is within 0.2 deg and the offset within 1 cm (noise: 2 cm along the beams over hundreds of
    returns); the runtime's slab count is the ray-traced count less the 2 % dropouts plus returns of other surfaces
    crossing the slab (ground at a wall's foot), within [0.9, 1.3]."""
    t = street_profile.pd
    e, pd = np.asarray(t.edges), np.asarray(t.pd)
    assert np.all(pd[e[:-1] < 10] == 0.0)
    assert np.all(pd[e[:-1] >= 400] >= 0.85)
    st = street_profile.planes
    assert np.degrees(st.noise.normal_angle_median) < 0.2 and st.noise.offset_sigma < 0.01
    assert 0.9 <= st.slab_ratio <= 1.3
    assert street_profile.clutter.rate > 0  # trunks, crowns and building corners give false planes


def test_validation_on_a_held_out_street(street_profile, small_street):
    """On another street the profile's P_D predictions hold: ECE over the informative pairs <= 0.15 (a profile fitted
    on 16 frames, scored on ~160 informative pairs whose block-bootstrap noise floor is about 0.07), and a Brier
    score under half of the constant-rate predictor's (the profile knows which planes will be seen)."""
    from tests.conftest import small_street_config
    from calib.sim.street import simulate_street

    log = simulate_street(small_street_config(8), 23).log
    v = validate_planes(street_profile, log)
    assert v.summary["ece"] <= 0.15
    assert v.summary["brier"] < 0.5 * v.summary["brier_constant_rate"]
    assert v.summary["plane_frame_pairs_in_view"] > 200


def test_refusals(small_street):
    with pytest.raises(UsageError, match="no logs to calibrate"):
        calibrate_planes([], PlaneCalibConfig(), name="x", version="1.0.0")
    from dataclasses import replace

    with pytest.raises(UsageError, match="has no plane truth"):
        calibrate_planes([replace(small_street.log, planes=None)], PlaneCalibConfig(), name="x", version="1.0.0")


def test_profile_schema_refuses_mixed_kinds(street_profile):
    data = street_profile.model_dump(mode="json")
    bad = {**data, "planes": None}
    with pytest.raises(ValueError, match="a plane3d profile needs pd.covariate points, a planes section"):
        DetectorProfile.model_validate(bad)
    bad = {**data, "sensor": {**data["sensor"], "lidar": None}}
    with pytest.raises(ValueError, match="a plane3d detector needs a lidar3d sensor with its lidar geometry"):
        DetectorProfile.model_validate(bad)
    circle = {**data, "detector": {"kind": "circle2d"}}
    with pytest.raises(ValueError, match="planes and a P_D table over points belong to plane3d detectors"):
        DetectorProfile.model_validate(circle)


def test_calibration_counts_the_detections_the_filter_is_given(small_street, street_profile, monkeypatch):
    """The calibration's landmark detections (its clutter and detection counts) are, frame by frame, exactly the
    measurements the runtime source hands the filter: both go through ``detectors.plane.landmark_detections`` with
    the runtime detection model's view, so the profile cannot describe other units than the filter consumes."""
    from types import SimpleNamespace

    import calib.planes as cp
    import detectors.plane as dp
    from calib.planes import label_planes
    from detectors.plane_model import PlaneDetectionModel
    from slam_runtime.config import DetectionOptions

    calls = []
    real = dp.landmark_detections

    def spy(det, in_view, min_points, min_width):
        calls.append(getattr(in_view, "__self__", None))
        return real(det, in_view, min_points, min_width)

    monkeypatch.setattr(dp, "landmark_detections", spy)
    monkeypatch.setattr(cp, "landmark_detections", spy)
    log = small_street.log
    st = street_profile.planes
    cfg = PlaneCalibConfig(detector=street_profile.detector.plane, min_points=st.min_points, min_width=st.min_width, offset_max=st.offset_max, every=5)
    lab = label_planes(log, cfg)
    model = PlaneDetectionModel.from_options(street_profile, log.sensor, DetectionOptions())
    source = dp.CloudPlanes(log, street_profile, model)
    per_frame = lab.detections.groupby("frame")["landmark"].sum()
    assert len(calls) == lab.frames and all(isinstance(c, PlaneDetectionModel) for c in calls)
    checked = 0
    for f in range(0, len(log.clouds), 5):
        m = source(SimpleNamespace(rows=f))  # the source reads a frame's cloud by its row
        assert m.z.shape[0] == int(per_frame.get(f, 0)), f"frame {f}"
        checked += m.z.shape[0]
    assert checked > 0 and len(calls) == 2 * lab.frames
