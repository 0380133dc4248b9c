"""The ground truth through the command line: calibrate's gate (refusal, its override) and icp's trajectories."""

import numpy as np
import pytest
import yaml

from calib.icp import IcpResult
from calib.io.native import write_native
from calib.sim.park import simulate_park
from detectors.geometry import compose, interpolate_poses, relative
from tests.calib.floorplan import floorplan_log, path_poses, rectangle
from tests.conftest import small_park_config
from tests.detcal.cli.test_cli import assert_one_line_error, run


@pytest.fixture(scope="module")
def two_laps(tmp_path_factory):
    """A seeded park log of two laps, and its true vehicle poses at the scans."""
    log = simulate_park(small_park_config(laps=2.0), 51).log
    ref = log.reference["ground_truth"]
    path = write_native(log, tmp_path_factory.mktemp("laps") / f"{log.name}.dlog")
    return path, log.name, interpolate_poses(ref.stamp, ref.poses, log.scans.stamp)


@pytest.fixture
def corrupted_icp(two_laps, monkeypatch):
    """An "ICP" that returns the true poses with the second lap turned by 3 degrees about its first pose: each lap
    is smooth, the map is doubled (the gate judges poses, whoever made them)."""
    import calib.groundtruth  # noqa: F401  imported before the patch: it binds icp_ground_truth by name at import, and
    import calib.icp  # an import inside the patch would keep the fake for every later test of this worker

    _, _, truth = two_laps
    k0 = len(truth) // 2
    bad = truth.copy()
    bad[k0:] = compose(compose(truth[k0], np.array([0.0, 0.0, np.radians(3.0)])), relative(truth[k0], truth[k0:]))
    monkeypatch.setattr(calib.icp, "icp_ground_truth", lambda lg, cfg=None, origin=None, progress=None: IcpResult(bad, np.arange(len(bad)), [], bad))
    return bad


def _written(folder) -> list[str]:
    return sorted(p.name for p in folder.iterdir()) if folder.exists() else []


def test_calibrate_refuses_a_doubled_map_and_writes_nothing(tmp_path, capsys, two_laps, corrupted_icp):
    path, name, _ = two_laps
    args = ["calibrate", str(path), "--poses", "icp", "--name", "laps", "--profiles-dir", str(tmp_path / "profiles"), "--out", str(tmp_path / "run")]
    code, out, err = run(capsys, *args)
    assert code == 1
    # the log, the failed figure, its threshold (0.08 m: calib.gtquality's default ceiling)
    assert_one_line_error(err, f"{name}: ground truth fails: map_consistency_p95_m ")
    assert "> 0.08 m" in err and "no profile written" in err and "--accept-poor-ground-truth" in err
    assert _written(tmp_path / "profiles") == [] and not (tmp_path / "run").exists()
    assert _written(tmp_path) == []  # nothing half-written beside them either (no .part folder)


def test_accept_poor_ground_truth_writes_the_profile_and_records_it(tmp_path, capsys, two_laps, corrupted_icp):
    path, name, _ = two_laps
    prof_dir = tmp_path / "profiles"
    args = ["calibrate", str(path), "--poses", "icp", "--name", "laps", "--profiles-dir", str(prof_dir), "--out", str(tmp_path / "run")]
    code, out, err = run(capsys, *args, "--accept-poor-ground-truth")
    assert code == 0, err
    assert f"written anyway (--accept-poor-ground-truth): {name}: ground truth fails: map_consistency_p95_m" in err
    assert f"ground truth of {name}" in out and "fails: map_consistency_p95_m" in out
    assert "data sufficiency" in out and "passes: landmarks" in out
    prof = yaml.safe_load((prof_dir / "laps@1.0.0.yaml").read_text())
    assert prof["provenance"]["parameters"]["accept_poor_ground_truth"] is True
    assert "--accept-poor-ground-truth" in prof["provenance"]["command"]
    quality = yaml.safe_load((tmp_path / "run/quality.yaml").read_text())
    gt = quality["logs"][name]["ground_truth"]
    assert quality["logs"][name]["pose_source"] == "icp" and gt["passed"] is False
    assert gt["checks"]["map_consistency_p95_m"]["passed"] is False and gt["failing_stretches"]
    assert quality["data_sufficiency"]["passed"] is True and len(quality["accepted_poor"]) == 1
    assert (tmp_path / "run/map.png").is_file()
    # the same request without the override is another request: refused before any work, the profile kept
    code, _, err = run(capsys, *args)
    assert code == 2 and "exists with other content" in err


def test_calibrate_refuses_too_thin_data_with_their_counts(tmp_path, capsys):
    cfg = small_park_config()
    cfg.trees.count = 2  # two landmarks: nothing a P_D table can stand on
    log = simulate_park(cfg, 5).log
    path = write_native(log, tmp_path / "logs" / f"{log.name}.dlog")
    code, _, err = run(capsys, "calibrate", str(path), "--name", "thin", "--profiles-dir", str(tmp_path / "profiles"), "--out", str(tmp_path / "run"))
    assert code == 1
    assert_one_line_error(err, f"{log.name}: data fails: landmarks 2 < 5 (landmarks labelled) (and 2 more: true_detections, populated_pd_bins)")
    assert _written(tmp_path / "profiles") == [] and not (tmp_path / "run").exists()


def test_accept_poor_ground_truth_is_refused_where_no_ground_truth_is_registered(tmp_path, capsys):
    from calib.sim.rfs import RfsSimConfig, simulate_rfs

    path = write_native(simulate_rfs(RfsSimConfig(steps=60), 1), tmp_path / "d.dlog")
    code, _, err = run(capsys, "calibrate", str(path), "--accept-poor-ground-truth", "--out", str(tmp_path / "run"))
    assert code == 2
    assert_one_line_error(err, "--accept-poor-ground-truth applies to laser logs")


def _relations(log, truth, path, gap: int = 20) -> int:
    """Relations as the benchmark gives them (t1 t2 x y z roll pitch yaw): scan pairs ``gap`` scans apart, their true
    relative pose; returns how many."""
    t = log.scans.stamp / 1e9
    i = np.arange(0, len(truth) - gap, 10)
    rel = relative(truth[i], truth[i + gap])
    z = np.zeros(i.size)
    np.savetxt(path, np.column_stack([t[i], t[i + gap], rel[:, 0], rel[:, 1], z, z, z, rel[:, 2]]), fmt="%.9f")
    return i.size


def _relation_error(out: str, n: int) -> float:
    line = next(x for x in out.splitlines() if x.startswith("relation error of the ground truth"))
    assert f"({n} relations)" in line and " m (max " in line and " deg (max " in line
    return float(line.split(": ")[1].split(" +- ")[0])


def test_icp_writes_tum_and_kitti_trajectories_and_scores_relations(tmp_path, capsys):
    from tests.calib.test_groundtruth import _room_with_boxes

    truth = path_poses(np.array([[1.0, 1.0], [19.0, 1.0], [19.0, 11.0], [1.0, 11.0], [1.0, 1.5]]), 1.0)
    log = floorplan_log(_room_with_boxes(3), truth, 7)
    path = write_native(log, tmp_path / "room.dlog")
    n = _relations(log, truth, tmp_path / "room.relations")
    code, out, err = run(capsys, "icp", str(path), "--relations", str(tmp_path / "room.relations"), "--out", str(tmp_path / "gt"))
    assert code == 0, err
    # 1 cm range noise, 2 cm odometry noise per metre, a room with boxes in it: the registration holds every pose within
    # 0.08 m of the truth (the front end's own test), so a 20-scan relation within a few centimetres
    assert _relation_error(out, n) < 0.03
    # the TUM file parses on its own (numbers only, 8 columns, unit quaternions about z) and says what poses.csv says
    tum = np.loadtxt(tmp_path / "gt/poses_tum.txt", comments="#", ndmin=2)
    csv = np.loadtxt(tmp_path / "gt/poses.csv", delimiter=",", skiprows=1, ndmin=2)
    assert tum.shape == (len(truth), 8) and np.allclose(tum[:, 0], csv[:, 0], atol=1e-9, rtol=0)
    assert np.allclose(tum[:, 1:3], csv[:, 1:3]) and np.allclose(tum[:, 3:6], 0.0)
    assert np.allclose(np.hypot(tum[:, 6], tum[:, 7]), 1.0)
    yaw = 2 * np.arctan2(tum[:, 6], tum[:, 7])
    assert np.allclose(np.angle(np.exp(1j * (yaw - csv[:, 3]))), 0.0, atol=1e-7)
    kitti = np.loadtxt(tmp_path / "gt/poses_kitti.txt", ndmin=2)
    assert kitti.shape == (len(truth), 12) and np.allclose(kitti[:, [3, 7]], csv[:, 1:3])
    q = yaml.safe_load((tmp_path / "gt/quality.yaml").read_text())
    assert q["relations"]["relations"] == n and q["figures"]["reference_ate_m"] < 0.08


def test_icp_says_when_its_ground_truth_fails(tmp_path, capsys):
    """A room 20 m long seen by a 12 m laser from 1 m off its walls: along the walls the scans see two parallel lines,
    and the registration slides (metres off the truth, the relations say). The quality report says so, from the scans
    alone: its only loop closure disagrees with the graph and is turned off."""
    walls = np.vstack([rectangle(0, 0, 20, 12), rectangle(5, 4, 6, 5), rectangle(12, 7, 13.5, 8), rectangle(15, 2, 15.5, 3.5)])
    truth = path_poses(np.array([[1.0, 1.0], [19.0, 1.0], [19.0, 11.0], [1.0, 11.0], [1.0, 1.5]]), 1.0)
    log = floorplan_log(walls, truth, 7)
    path = write_native(log, tmp_path / "hall.dlog")
    n = _relations(log, truth, tmp_path / "hall.relations")
    code, out, err = run(capsys, "icp", str(path), "--relations", str(tmp_path / "hall.relations"), "--out", str(tmp_path / "gt"))
    assert code == 0, err  # a report, not a refusal: the run folder shows where
    assert _relation_error(out, n) > 0.3
    assert_one_line_error(err.replace("detcal: warning: ", "detcal: error: "), "floorplan: ground truth fails: back_end_rejected_share 1 > 0.3")
    assert yaml.safe_load((tmp_path / "gt/quality.yaml").read_text())["passed"] is False
