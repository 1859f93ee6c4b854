"""Trajectory metrics: agreement with evo (evo_rpe / evo_ape -a) to 1e-6, and the KITTI devkit metric on
constructed trajectories with known answers."""
import copy
import dataclasses
import json

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from line_odom import datasets, evaluation, metrics
from line_odom.cli import main

from evo.core import metrics as evo_metrics  # test dependency (requirements/dev.txt)
from evo.core import sync
from evo.core.metrics import PoseRelation, StatisticsType, Unit
from evo.tools import file_interface

TUM_GT = datasets.SHARED_DATA / "tum_rgbd_fr1_xyz" / "groundtruth.txt"
KITTI_GT = datasets.SHARED_DATA / "kitti_odometry_mini" / "sequences" / "00" / "poses_gt.txt"


def _noisy_copy(poses, rng, sigma_t, sigma_r):
    """An odometry-like estimate: the true frame-to-frame motions with noise, chained from the identity."""
    out = [np.eye(4)]
    for a, b in zip(poses[:-1], poses[1:]):
        noise = np.eye(4)
        noise[:3, :3] = Rotation.from_rotvec(rng.normal(0.0, sigma_r, 3)).as_matrix()
        noise[:3, 3] = rng.normal(0.0, sigma_t, 3)
        out.append(out[-1] @ np.linalg.inv(a) @ b @ noise)
    return np.array(out)


def _evo_numbers(ref, est):
    out = {}
    for key, relation in (("trans", PoseRelation.translation_part), ("rot", PoseRelation.rotation_angle_deg)):
        rpe = evo_metrics.RPE(relation, 1, Unit.frames, all_pairs=False)
        rpe.process_data((ref, est))
        out[f"rpe_{key}_mean"] = rpe.get_statistic(StatisticsType.mean)
        out[f"rpe_{key}_max"] = rpe.get_statistic(StatisticsType.max)
    aligned = copy.deepcopy(est)
    aligned.align(ref, correct_scale=False)
    ape = evo_metrics.APE(PoseRelation.translation_part)
    ape.process_data((ref, aligned))
    out["ate_rmse"] = ape.get_statistic(StatisticsType.rmse)
    return out


def _assert_agrees(ours, evo):
    assert ours["rpe_trans_mean_m"] == pytest.approx(evo["rpe_trans_mean"], abs=1e-6)
    assert ours["rpe_trans_max_m"] == pytest.approx(evo["rpe_trans_max"], abs=1e-6)
    assert ours["rpe_rot_mean_deg"] == pytest.approx(evo["rpe_rot_mean"], abs=1e-6)
    assert ours["rpe_rot_max_deg"] == pytest.approx(evo["rpe_rot_max"], abs=1e-6)
    assert ours["ate_rmse_m"] == pytest.approx(evo["ate_rmse"], abs=1e-6)


def test_eval_tum_files_agree_with_evo(tmp_path):
    """Estimate at the depth stamps (30 Hz) against the 100 Hz mocap ground truth: both associate by nearest
    timestamp within 10 ms, so the same pairs enter RPE and the SE(3)-aligned ATE."""
    seq = datasets.tum_sequence(120)
    stamps, poses = seq.stamps[seq.pose_valid], seq.poses[seq.pose_valid]
    est = _noisy_copy(poses, np.random.default_rng(3), 0.004, 0.003)
    est_path = tmp_path / "est_tum.txt"
    evaluation.write_tum(est_path, evaluation.Trajectory(est, stamps))
    out_json = tmp_path / "metrics.json"
    assert main(["eval", str(est_path), str(TUM_GT), "--json", str(out_json)]) == 0
    ours = json.loads(out_json.read_text())
    assert ours["frames"] == len(est) and ours["frames_with_ground_truth"] == len(est)

    ref = file_interface.read_tum_trajectory_file(str(TUM_GT))
    evo_est = file_interface.read_tum_trajectory_file(str(est_path))
    ref, evo_est = sync.associate_trajectories(ref, evo_est, max_diff=0.01)
    _assert_agrees(ours, _evo_numbers(ref, evo_est))
    assert ours["ate_rmse_m"] > 1e-3  # the noise is really there: the comparison is not trivially 0 = 0


def test_eval_kitti_files_agree_with_evo(tmp_path):
    gt = evaluation.read_trajectory(KITTI_GT)
    est = _noisy_copy(gt.poses, np.random.default_rng(4), 0.05, 0.002)
    est_path = tmp_path / "est_kitti.txt"
    evaluation.write_kitti(est_path, evaluation.Trajectory(est))
    out_json = tmp_path / "metrics.json"
    assert main(["eval", str(est_path), str(KITTI_GT), "--json", str(out_json)]) == 0
    ours = json.loads(out_json.read_text())
    ref = file_interface.read_kitti_poses_file(str(KITTI_GT))
    evo_est = file_interface.read_kitti_poses_file(str(est_path))
    _assert_agrees(ours, _evo_numbers(ref, evo_est))
    assert "kitti_t_err_pct" not in ours  # 10 frames, ~8 m: too short for a 100 m segment


def test_nees_of_errors_drawn_from_their_covariance_averages_the_dimension():
    rng = np.random.default_rng(3)
    A = rng.normal(size=(6, 6))
    C = A @ A.T + 0.1 * np.eye(6)
    errors = rng.multivariate_normal(np.zeros(6), C, size=20000)
    n = metrics.nees(errors, np.broadcast_to(C, (len(errors), 6, 6)))
    assert abs(n.mean() - 6.0) < 0.15
    assert abs(metrics.nees(errors, np.broadcast_to(4 * C, (len(errors), 6, 6))).mean() - 1.5) < 0.05
    with pytest.raises(ValueError, match="errors, covariances"):
        metrics.nees(errors, C)


def test_motion_errors_are_the_chart_of_the_engine_covariance():
    truth = np.eye(4)[None].repeat(2, axis=0)
    truth[1, :3, 3] = [1.0, 2.0, 3.0]
    step = np.eye(4)
    step[:3, :3] = Rotation.from_rotvec([0.01, -0.02, 0.03]).as_matrix()
    step[:3, 3] = [0.1, 0.0, -0.2]
    e = metrics.motion_errors(step @ truth, truth)  # delta = exp(e) truth
    np.testing.assert_allclose(e, [[0.1, 0.0, -0.2, 0.01, -0.02, 0.03]] * 2, atol=1e-12)


def test_umeyama_recovers_a_known_rigid_transform():
    rng = np.random.default_rng(0)
    source = rng.normal(size=(50, 3))
    T = np.eye(4)
    T[:3, :3] = Rotation.from_rotvec([0.3, -1.2, 0.5]).as_matrix()
    T[:3, 3] = [4.0, -2.0, 1.0]
    target = source @ T[:3, :3].T + T[:3, 3]
    np.testing.assert_allclose(metrics.umeyama_alignment(source, target), T, atol=1e-12)
    errors, _ = metrics.absolute_trajectory_errors(np.array([_translation(p) for p in source]),
                                                   np.array([_translation(p) for p in target]))
    assert errors.max() < 1e-12


def _translation(t):
    T = np.eye(4)
    T[:3, 3] = t
    return T


def _straight_line(n, step=1.0):
    return np.array([_translation([i * step, 0.0, 0.0]) for i in range(n)])


def _expected_mean_over_segments(per_segment, n_frames):
    """Average of per_segment(L) over the devkit's segments of a 1 m/frame straight line of n_frames: a segment
    of length L from frame f ends at the first frame whose distance exceeds f + L, i.e. f + L + 1, so it exists
    for the starts f = 0, 10, 20, ... <= n_frames - 2 - L."""
    values = []
    for length in metrics.KITTI_SEGMENT_LENGTHS:
        starts = (n_frames - 2 - int(length)) // 10 + 1
        values += [per_segment(length)] * max(starts, 0)
    return float(np.mean(values))


def test_kitti_metric_one_percent_scale_error_on_a_straight_kilometre():
    gt = _straight_line(1001)  # 0 .. 1000 m
    est = gt.copy()
    est[:, :3, 3] *= 1.01
    t_err, r_err = metrics.kitti_errors(est, gt)
    # the devkit divides the error over f .. f+L+1 (L + 1 m driven) by the nominal length L
    expected = _expected_mean_over_segments(lambda L: 1.0 * (L + 1.0) / L, 1001)
    assert t_err == pytest.approx(expected, rel=1e-9)
    assert t_err == pytest.approx(1.0, abs=0.01)
    assert r_err == 0.0
    rows = metrics.kitti_segment_errors(est, gt)
    assert set(rows[:, 1]) == set(metrics.KITTI_SEGMENT_LENGTHS)
    assert rows[:, 0].max() == 890  # the last 100 m segment starts at frame 890 and ends at 991


def test_kitti_metric_constant_yaw_drift():
    gt = _straight_line(1001)
    drift = np.radians(0.01)  # per frame (= per metre)
    est = gt.copy()
    for i in range(len(est)):
        est[i, :3, :3] = Rotation.from_rotvec([0.0, 0.0, drift * i]).as_matrix()
    t_err, r_err = metrics.kitti_errors(est, gt)
    expected = _expected_mean_over_segments(lambda L: 0.01 * (L + 1.0) / L, 1001)
    assert r_err == pytest.approx(expected, rel=1e-6)
    assert r_err == pytest.approx(0.01, rel=0.01)


def test_kitti_metric_ignores_the_estimate_world_frame_and_needs_100m():
    rng = np.random.default_rng(5)
    gt = _straight_line(300)
    for i in range(1, len(gt)):  # a gently curving road
        gt[i] = gt[i - 1] @ _translation([1.0, 0.0, 0.0])
        gt[i, :3, :3] = gt[i - 1, :3, :3] @ Rotation.from_rotvec([0, 0, 0.01]).as_matrix()
    est = _noisy_copy(gt, rng, 0.01, 0.001)
    A = np.eye(4)
    A[:3, :3] = Rotation.from_rotvec([0.1, 0.2, 0.3]).as_matrix()
    A[:3, 3] = [10.0, -5.0, 2.0]
    np.testing.assert_allclose(metrics.kitti_errors(A @ est, gt), metrics.kitti_errors(est, gt), rtol=1e-9)
    np.testing.assert_allclose(metrics.kitti_errors(gt, gt), (0.0, 0.0), atol=1e-12)
    assert metrics.kitti_errors(_straight_line(90), _straight_line(90)) is None


def test_metrics_json_keys(tmp_path):
    gt = evaluation.Trajectory(_straight_line(200), np.arange(200) * 0.1)
    est = evaluation.Trajectory(gt.poses.copy(), gt.stamps.copy())
    est.poses[:, 0, 3] *= 1.02
    values = evaluation.compute_metrics(est, gt, frames_dropped=1, latencies_ms=np.arange(1.0, 101.0))
    for key in evaluation.METRIC_KEYS:
        assert key in values, key
    assert values["frames"] == 200 and values["frames_dropped"] == 1
    assert values["rpe_trans_mean_m"] == pytest.approx(0.02)
    assert values["kitti_t_err_pct"] == pytest.approx(2.0, abs=0.03)
    assert values["latency_mean_ms"] == pytest.approx(50.5)
    assert values["latency_p95_ms"] == pytest.approx(95.05)
    no_gt = evaluation.compute_metrics(est, None, frames_dropped=0, latencies_ms=[1.0])
    assert not set(evaluation.GT_KEYS) & set(no_gt)
    assert no_gt["frames"] == 200
    short = evaluation.compute_metrics(evaluation.Trajectory(gt.poses[:50], gt.stamps[:50]),
                                       evaluation.Trajectory(gt.poses[:50], gt.stamps[:50]))
    assert "kitti_t_err_pct" not in short and "ate_rmse_m" in short


@pytest.mark.parametrize("content, expected", [
    ("1 2 3\n", "3 columns"),
    ("a b c d e f g h\n", "not a trajectory file"),
    ("", "empty"),
    ("0 0 0 0 0 0 0 0\n", "zero quaternion"),
])
def test_eval_rejects_bad_files_with_one_line(tmp_path, capsys, content, expected):
    bad = tmp_path / "bad.txt"
    bad.write_text(content)
    assert main(["eval", str(bad), str(KITTI_GT)]) == 1
    err = capsys.readouterr().err
    assert expected in err and "Traceback" not in err and len(err.strip().splitlines()) == 1


def test_eval_errors_on_missing_file_and_mismatch(tmp_path, capsys):
    assert main(["eval", str(tmp_path / "nope.txt"), str(KITTI_GT)]) == 1
    assert "nope.txt" in capsys.readouterr().err
    short = tmp_path / "short.txt"
    evaluation.write_kitti(short, evaluation.Trajectory(_straight_line(3)))
    assert main(["eval", str(short), str(KITTI_GT)]) == 1
    assert "counts must agree" in capsys.readouterr().err
    far = tmp_path / "far.txt"
    evaluation.write_tum(far, evaluation.Trajectory(_straight_line(3), np.array([1.0, 2.0, 3.0])))
    assert main(["eval", str(far), str(TUM_GT)]) == 1
    assert "no estimate timestamp" in capsys.readouterr().err


def test_paired_difference_tells_a_shift_from_noise():
    rng = np.random.default_rng(7)
    common = rng.normal(0.05, 0.02, 9)  # the frames' shared difficulty (nine KITTI frame pairs)
    lower = common + rng.normal(0.0, 0.002, 9)
    mean, low, high = metrics.paired_difference(lower, common + 0.01)
    assert high < 0.0 and low < mean < high and abs(mean + 0.01) < 0.003
    mean, low, high = metrics.paired_difference(common + rng.normal(0.0, 0.01, 9), common + rng.normal(0.0, 0.01, 9))
    assert low < 0.0 < high
    assert metrics.paired_difference(common + 1.0, common) == pytest.approx((1.0, 1.0, 1.0))
    with pytest.raises(ValueError, match="a and b"):
        metrics.paired_difference(common, common[:5])


def test_tum_ground_truth_at_an_offset():
    seq = datasets.tum_sequence(40)
    at_zero, valid = seq.poses_at_offset(0.0)
    assert np.array_equal(at_zero, seq.poses) and np.array_equal(valid, seq.pose_valid)
    earlier, valid = seq.poses_at_offset(-0.04)
    assert valid.sum() >= 37
    # fr1/xyz moves ~0.2 m/s: 40 ms earlier every pose is a few mm back along the path, never the same
    shift = np.linalg.norm(earlier[valid, :3, 3] - seq.poses[valid, :3, 3], axis=1)
    assert 1e-4 < np.median(shift) < 0.05
    stamps, poses = seq.ground_truth
    expected, _ = datasets.interpolate_poses(stamps, poses, seq.stamps - 0.04)
    assert np.allclose(earlier, expected)
    with pytest.raises(ValueError, match="offset"):
        seq.poses_at_offset(float("nan"))
    no_truth = dataclasses.replace(seq, ground_truth=None)
    with pytest.raises(ValueError, match="groundtruth.txt"):
        no_truth.poses_at_offset(0.0)
