"""The `line_odom` command line: conversions through main([...]), and every failure as one line on stderr with
a non-zero return code (never a traceback)."""
import subprocess
import sys

import pytest

from line_odom import bags, datasets
from line_odom.cli import main

KITTI_00 = datasets.SHARED_DATA / "kitti_odometry_mini" / "sequences" / "00"
TUM_DIR = datasets.SHARED_DATA / "tum_rgbd_fr1_xyz"


def _one_error_line(capsys, *needles):
    err = capsys.readouterr().err
    assert "Traceback" not in err
    lines = [ln for ln in err.strip().splitlines() if ln.strip()]
    assert len(lines) == 1, err
    for needle in needles:
        assert needle in lines[0], lines[0]
    return lines[0]


@pytest.mark.parametrize("storage", bags.STORAGES)
def test_kitti2bag_and_tum2bag(tmp_path, capsys, storage):
    out = tmp_path / "kitti"
    assert main(["kitti2bag", str(KITTI_00), str(out), "--frames", "2", "--storage", storage]) == 0
    assert "wrote 2 scans" in capsys.readouterr().out
    with bags.BagReader(out) as reader:
        assert reader.counts[bags.KITTI_POINTS_TOPIC] == 2
    out = tmp_path / "tum"
    assert main(["tum2bag", str(TUM_DIR), str(out), "--frames", "3", "--storage", storage, "--camera", "fr1"]) == 0
    assert "wrote 3 depth frames" in capsys.readouterr().out
    with bags.BagReader(out) as reader:
        assert reader.counts[bags.TUM_DEPTH_TOPIC] == 3


def test_conversion_errors(tmp_path, capsys):
    assert main(["kitti2bag", str(tmp_path / "nowhere"), str(tmp_path / "b")]) == 1
    _one_error_line(capsys, "kitti2bag", "no velodyne/ directory")
    assert not (tmp_path / "b").exists()
    assert main(["tum2bag", str(KITTI_00), str(tmp_path / "b")]) == 1
    _one_error_line(capsys, "no depth.txt")
    assert main(["tum2bag", str(TUM_DIR), str(tmp_path / "b"), "--camera", "kinect9"]) == 1
    _one_error_line(capsys, "camera: expected one of")
    assert main(["kitti2bag", str(KITTI_00), str(tmp_path / "b"), "--frames", "1"]) == 0
    capsys.readouterr()
    assert main(["kitti2bag", str(KITTI_00), str(tmp_path / "b"), "--frames", "1"]) == 1
    _one_error_line(capsys, "exists", "--overwrite")


def test_corrupt_scan_file_leaves_no_half_bag(tmp_path, capsys):
    seq = tmp_path / "seq"
    (seq / "velodyne").mkdir(parents=True)
    (seq / "velodyne" / "000000.bin").write_bytes((KITTI_00 / "velodyne" / "000000.bin").read_bytes())
    (seq / "velodyne" / "000001.bin").write_bytes(b"\x00" * 10)  # not a multiple of 16 bytes
    assert main(["kitti2bag", str(seq), str(tmp_path / "out")]) == 1
    _one_error_line(capsys, "000001.bin", "multiple of 16")
    assert not (tmp_path / "out").exists()


def test_usage_errors_return_2(capsys):
    assert main([]) == 2
    assert main(["kitti2bag", "a", "b", "--storage", "zip"]) == 2
    assert main(["kitti2bag", "a", "b", "--frames", "0"]) == 2
    assert main(["no-such-command"]) == 2
    assert "Traceback" not in capsys.readouterr().err


def _truncated_copy(src, dst):
    import shutil

    shutil.copytree(src, dst)
    (data,) = [p for p in dst.iterdir() if p.suffix in (".db3", ".mcap")]
    data.write_bytes(data.read_bytes()[: data.stat().st_size // 3])
    return dst


@pytest.mark.parametrize("storage", bags.STORAGES)
def test_replay_rejects_broken_bags(tmp_path, capsys, storage):
    good = tmp_path / "good"
    bags.kitti_to_bag(KITTI_00, good, frames=2, storage=storage)
    bad = _truncated_copy(good, tmp_path / "truncated")
    assert main(["replay", str(bad), "--out", str(tmp_path / "out")]) == 1
    _one_error_line(capsys, "replay", "truncated")
    assert main(["replay", str(tmp_path / "missing"), "--out", str(tmp_path / "out")]) == 1
    _one_error_line(capsys, "no such bag")
    # a bag with only ground truth: no PointCloud2 or depth Image to replay
    gt_only = tmp_path / "gt_only"
    with bags.BagWriter(gt_only, storage) as writer:
        writer.write(bags.GROUND_TRUTH_TOPIC, bags.ODOMETRY, 0,
                     writer.msgs.odometry(0, "world", "velodyne", __import__("numpy").eye(4)))
    assert main(["replay", str(gt_only), "--out", str(tmp_path / "out")]) == 1
    _one_error_line(capsys, "no PointCloud2", "/ground_truth")
    assert main(["replay", str(good), "--out", str(tmp_path / "out"), "--topic", "/velodyne_points"]) == 1
    _one_error_line(capsys, "/velodyne_points", "/kitti/points")


def test_python_dash_m_entry_point(tmp_path):
    proc = subprocess.run([sys.executable, "-m", "line_odom", "eval", str(tmp_path / "a.txt"), str(tmp_path / "b.txt")],
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 1
    assert "Traceback" not in proc.stderr and "a.txt" in proc.stderr
    proc = subprocess.run([sys.executable, "-m", "line_odom", "--help"], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0
    for command in ("kitti2bag", "tum2bag", "replay", "eval", "demo"):
        assert command in proc.stdout


def test_replay_corrupt_message_and_malformed_cloud(tmp_path, capsys):
    import numpy as np

    garbage = tmp_path / "garbage_msg"
    with bags.BagWriter(garbage) as writer:
        writer.write_raw(bags.KITTI_POINTS_TOPIC, bags.POINTCLOUD2, 0, b"\x00\x01\x00\x00" + b"\xff" * 7)
    assert main(["replay", str(garbage), "--out", str(tmp_path / "o1")]) == 1
    _one_error_line(capsys, "cannot decode", bags.KITTI_POINTS_TOPIC)

    # well-formed CDR, but the cloud's data is shorter than width x point_step: the node drops it (counted)
    seq = datasets.kitti_sequence("00", 2)
    malformed = tmp_path / "malformed"
    with bags.BagWriter(malformed) as writer:
        points = np.zeros(len(seq.points(0)), dtype=bags.KITTI_POINT_DTYPE)
        for k, name in enumerate(("x", "y", "z", "intensity")):
            points[name] = seq.points(0)[:, k]
        msg = writer.msgs.pointcloud2(0, "velodyne", points)
        msg.data = msg.data[:100]
        writer.write(bags.KITTI_POINTS_TOPIC, bags.POINTCLOUD2, 0, msg)
    assert main(["replay", str(malformed), "--out", str(tmp_path / "o2")]) == 1
    _one_error_line(capsys, "no pose from 1 frame", "frames_malformed")
