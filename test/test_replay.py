"""Shared real frames -> rosbag2 (sqlite3 and mcap) -> replay through the node's processing core -> metrics, plus
missing ground truth, the output bag, determinism, the realtime mode over DDS and the demo."""
import json
import shutil
import signal
import subprocess
import sys
import time
import warnings

import numpy as np
import pytest

from line_odom import bags, datasets, demo, evaluation
from line_odom.cli import main

KITTI_00 = datasets.SHARED_DATA / "kitti_odometry_mini" / "sequences" / "00"
TUM_DIR = datasets.SHARED_DATA / "tum_rgbd_fr1_xyz"

# The pipeline's own bounds on the same frames (test/test_odometry_kitti.py, test/test_odometry_tum.py: about 2x
# what it measured), so going through a bag and the node's message path must cost no accuracy. Measured through
# replay: KITTI 00 at 1/36 0.12 m / 0.21 deg; TUM 60 frames at 1/100 6.1 mm / 0.54 deg (16UC1 millimetres; 6.4 mm
# / 0.59 deg from the PNGs directly). For scale: KITTI 00 moves
# 0.86 m per frame (identity would score ~0.86 m); KISS-ICP's figures on the same
# frames are in docs/RESULTS.md, "Accuracy".
KITTI_RPE_T, KITTI_RPE_R = 0.25, 0.40
TUM_RPE_T, TUM_RPE_R = 0.008, 1.0


@pytest.fixture(scope="module")
def kitti_bags(tmp_path_factory):
    root = tmp_path_factory.mktemp("kitti_bags")
    return {s: bags.kitti_to_bag(KITTI_00, root / s, storage=s) and root / s for s in bags.STORAGES}


@pytest.fixture(scope="module")
def tum_bags(tmp_path_factory):
    root = tmp_path_factory.mktemp("tum_bags")
    return {s: bags.tum_to_bag(TUM_DIR, root / s, storage=s, frames=60) and root / s for s in bags.STORAGES}


def _metrics(out):
    return json.loads((out / "metrics.json").read_text())


@pytest.mark.parametrize("storage", bags.STORAGES)
def test_kitti_bag_replay(tmp_path, capsys, kitti_bags, storage):
    out = tmp_path / "out"
    assert main(["replay", str(kitti_bags[storage]), "--out", str(out), "--set", "downsample=6", "--quiet"]) == 0
    m = _metrics(out)
    assert m["frames"] == 10 and m["frames_dropped"] == 0 and m["frames_with_ground_truth"] == 10
    assert m["rpe_trans_mean_m"] < KITTI_RPE_T and m["rpe_rot_mean_deg"] < KITTI_RPE_R, m
    assert m["ate_rmse_m"] < 1.0 and m["latency_mean_ms"] > 0 and m["latency_p95_ms"] >= m["latency_mean_ms"] * 0.5
    assert "kitti_t_err_pct" not in m  # ~8 m of path: no 100 m segment
    for name in ("trajectory_tum.txt", "trajectory_kitti.txt", "ground_truth_tum.txt", "trajectory.png"):
        assert (out / name).stat().st_size > 0
    assert (out / "trajectory.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    # the written files give the same numbers through `eval`
    assert main(["eval", str(out / "trajectory_tum.txt"), str(out / "ground_truth_tum.txt"),
                 "--json", str(tmp_path / "eval.json")]) == 0
    again = json.loads((tmp_path / "eval.json").read_text())
    for key in ("rpe_trans_mean_m", "rpe_rot_mean_deg", "ate_rmse_m"):
        assert again[key] == pytest.approx(m[key], abs=1e-6)
    kitti = evaluation.read_trajectory(out / "trajectory_kitti.txt")
    np.testing.assert_allclose(kitti.poses, evaluation.read_trajectory(out / "trajectory_tum.txt").poses, atol=1e-8)


@pytest.mark.parametrize("storage", bags.STORAGES)
def test_tum_bag_replay(tmp_path, tum_bags, storage):
    out = tmp_path / "out"
    assert main(["replay", str(tum_bags[storage]), "--out", str(out), "--set", "downsample=10", "--quiet"]) == 0
    m = _metrics(out)
    assert m["frames"] == 60 and m["frames_dropped"] == 0
    assert m["rpe_trans_mean_m"] < TUM_RPE_T and m["rpe_rot_mean_deg"] < TUM_RPE_R, m


def test_replay_is_deterministic_and_writes_an_output_bag(tmp_path, tum_bags):
    runs = []
    for k in range(2):
        out = tmp_path / f"run{k}"
        args = ["replay", str(tum_bags["sqlite3"]), "--out", str(out), "--set", "downsample=10", "--frames", "12",
                "--quiet"]
        if k == 0:
            args += ["--out-bag", str(tmp_path / "odom_bag"), "--storage", "mcap"]
        assert main(args) == 0
        runs.append((out / "trajectory_tum.txt").read_text())
    assert runs[0] == runs[1]
    with bags.BagReader(tmp_path / "odom_bag") as reader:
        assert reader.counts["/odom"] == 12 and reader.counts["/path"] == 1
        assert reader.counts[bags.GROUND_TRUTH_TOPIC] == 60
        (path_msg,) = [reader.decode(m) for m in reader.messages(["/path"])]
        assert len(path_msg.poses) == 12
        last = [reader.decode(m) for m in reader.messages(["/odom"])][-1]
        est = evaluation.read_trajectory(tmp_path / "run0" / "trajectory_tum.txt")
        np.testing.assert_allclose([last.pose.pose.position.x, last.pose.pose.position.y, last.pose.pose.position.z],
                                   est.poses[-1, :3, 3], atol=1e-6)
    # evo reads the output bag (`evo_ape bag odom_bag /ground_truth /odom`)
    from evo.tools import file_interface
    from rosbags.rosbag2 import Reader

    with Reader(tmp_path / "odom_bag") as evo_reader:
        odom = file_interface.read_bag_trajectory(evo_reader, "/odom")
        gt = file_interface.read_bag_trajectory(evo_reader, bags.GROUND_TRUTH_TOPIC)
    assert odom.num_poses == 12 and gt.num_poses == 60
    np.testing.assert_allclose(odom.positions_xyz, est.poses[:, :3, 3], atol=1e-6)


def test_replay_without_ground_truth_omits_the_gt_keys(tmp_path, capsys):
    seq = tmp_path / "seq"
    (seq / "velodyne").mkdir(parents=True)
    for i in range(3):
        shutil.copy(KITTI_00 / "velodyne" / f"{i:06d}.bin", seq / "velodyne")
    shutil.copy(KITTI_00 / "times.txt", seq)
    shutil.copy(KITTI_00 / "calib.txt", seq)
    assert main(["kitti2bag", str(seq), str(tmp_path / "bag"), "--quiet"]) == 0
    with bags.BagReader(tmp_path / "bag") as reader:
        assert bags.GROUND_TRUTH_TOPIC not in reader.topics
    capsys.readouterr()
    assert main(["replay", str(tmp_path / "bag"), "--out", str(tmp_path / "out"), "--set", "downsample=6"]) == 0
    m = _metrics(tmp_path / "out")
    assert m["frames"] == 3 and "latency_mean_ms" in m
    assert not set(evaluation.GT_KEYS) & set(m)
    assert "RPE" not in capsys.readouterr().out
    assert not (tmp_path / "out" / "ground_truth_tum.txt").exists()


def test_replay_parameter_errors(tmp_path, capsys, tum_bags):
    bag = str(tum_bags["sqlite3"])
    assert main(["replay", bag, "--out", str(tmp_path / "o"), "--set", "downsample=0"]) == 1
    err = capsys.readouterr().err
    assert "downsample" in err and "Traceback" not in err
    assert main(["replay", bag, "--out", str(tmp_path / "o"), "--params", str(tmp_path / "none.yaml")]) == 1
    assert "none.yaml" in capsys.readouterr().err
    assert main(["replay", bag, "--out", str(tmp_path / "o"), "--set", "novalue"]) == 1
    assert "NAME=VALUE" in capsys.readouterr().err


def test_replay_takes_the_sensor_mounting_from_the_bags_tf_static(tmp_path, capsys, kitti_bags, tum_bags):
    """A KITTI bag carries velodyne -> camera_0 on /tf_static. With base_frame camera_0 and base_to_sensor_from_tf
    the odometry is the camera's (KITTI's ground-truth frame), the same as with that transform given as
    base_to_sensor, and the sensor's own motion is unchanged."""
    from scipy.spatial.transform import Rotation

    from line_odom.replay import replay_bag

    seq = datasets.kitti_sequence("00")
    T_velo_cam = np.linalg.inv(seq.Tr)  # (Tr maps velodyne into camera_0 coordinates: T_cam_velo)
    T_cam_velo = seq.Tr
    q = Rotation.from_matrix(T_cam_velo[:3, :3]).as_quat()
    common = {"downsample": 6, "base_frame": bags.KITTI_CAMERA_FRAME}
    runs = {}
    for name, extra in (("tf", {"base_to_sensor_from_tf": True}),
                        ("parameter", {"base_to_sensor": [*T_cam_velo[:3, 3], *q]}),
                        ("none", {"base_frame": bags.KITTI_FRAME})):
        runs[name] = replay_bag(kitti_bags["sqlite3"], tmp_path / name, overrides={**common, **extra},
                                progress=False).run
    tf, parameter, none = runs["tf"], runs["parameter"], runs["none"]
    assert len(tf.odometry_msgs) == len(parameter.odometry_msgs) == 10 and tf.counters["frames_no_extrinsic"] == 0
    for (_, a), (_, b) in zip(tf.odometry_msgs, parameter.odometry_msgs):
        assert a.child_frame_id == bags.KITTI_CAMERA_FRAME
        np.testing.assert_allclose(bags.odometry_to_pose(a)[1], bags.odometry_to_pose(b)[1], atol=1e-9)
    # the sensor's poses, in an odom frame at the camera's start
    np.testing.assert_allclose(tf.estimate.poses, T_cam_velo @ none.estimate.poses, atol=1e-9)
    camera = np.array([bags.odometry_to_pose(m)[1] for _, m in tf.odometry_msgs])
    velodyne = np.array([bags.odometry_to_pose(m)[1] for _, m in none.odometry_msgs])
    np.testing.assert_allclose(camera, T_cam_velo @ velodyne @ T_velo_cam, atol=1e-9)
    # a bag without /tf_static: a one-line error, not an empty run
    assert main(["replay", str(tum_bags["sqlite3"]), "--out", str(tmp_path / "o"), "--set",
                 "base_to_sensor_from_tf=true", "--quiet"]) == 1
    err = capsys.readouterr().err
    assert "base_to_sensor_from_tf is set but the bag has no /tf_static" in err and "Traceback" not in err


def _write_scan(writer, stamp, xyz, ring, pose):
    """One scan on /points (x, y, z, ring in the velodyne frame) and its ground-truth pose, at `stamp` (ns)."""
    points = np.zeros(len(xyz), dtype=bags.KITTI_POINT_DTYPE)
    points["x"], points["y"], points["z"] = xyz[:, 0], xyz[:, 1], xyz[:, 2]
    points["ring"] = ring
    writer.write("/points", bags.POINTCLOUD2, stamp, writer.msgs.pointcloud2(stamp, "velodyne", points))
    writer.write(bags.GROUND_TRUTH_TOPIC, bags.ODOMETRY, stamp, writer.msgs.odometry(stamp, "map", "velodyne", pose))


def _replay_without_and_with(tmp_path, bag, option, topic):
    """The metrics of replaying `bag` (at 1/36, base frame velodyne) without and with `option topic`; giving the
    option the scans' topic /points must fail (its error is left on stderr)."""
    common = ["--set", "downsample=6", "--set", "base_frame=velodyne", "--quiet"]
    assert main(["replay", str(bag), "--out", str(tmp_path / "without"), *common]) == 0
    assert main(["replay", str(bag), "--out", str(tmp_path / "with"), option, topic, *common]) == 0
    assert main(["replay", str(bag), "--out", str(tmp_path / "o"), option, "/points", *common]) == 1
    return _metrics(tmp_path / "without"), _metrics(tmp_path / "with")


def _wheel_odometry_bag(path):
    """KITTI 04 from scan 2 (ring field, ground truth) with /wheel/odometry: the ground truth's x, y and yaw, 3 %
    long, at the scans' stamps. Returns the number of scans."""
    seq = datasets.kitti_sequence("04")
    poses = [np.linalg.inv(seq.poses[2]) @ seq.poses[i] for i in range(2, len(seq))]
    stamps = [100.0 + float(seq.times[i]) for i in range(2, len(seq))]
    with bags.BagWriter(path) as writer:
        for k, i in enumerate(range(2, len(seq))):
            stamp = int(round(stamps[k] * 1e9))
            raw = seq.points(i)
            yaw = np.arctan2(poses[k][1, 0], poses[k][0, 0])
            wheel = np.eye(4)
            wheel[:2, :2] = [[np.cos(yaw), -np.sin(yaw)], [np.sin(yaw), np.cos(yaw)]]
            wheel[:2, 3] = 1.03 * poses[k][:2, 3]
            # (written first: a wheel odometry's message reaches the recorder before the scan of the same stamp,
            # which the LiDAR driver sends once its sweep is complete)
            writer.write("/wheel/odometry", bags.ODOMETRY, stamp, writer.msgs.odometry(stamp, "odom", "velodyne", wheel))
            _write_scan(writer, stamp, raw[:, :3], bags.kitti_rings(raw), poses[k])
    return len(poses)


def test_replay_with_a_wheel_odometry_topic_as_the_motion_guess(tmp_path, capsys):
    # KITTI 04 from scan 2 at 1/36: without a guess the highway's forward motion is held at the points' first motion,
    # ~0.1 m a frame short (docs/NODE.md "The first motion"); with the bag's /wheel/odometry given by --guess-topic it
    # follows the wheels: measured 0.037 m (bench/motion_guess.py); bound 0.1 m and below the run without it.
    bag = tmp_path / "bag"
    n = _wheel_odometry_bag(bag)
    without, m = _replay_without_and_with(tmp_path, bag, "--guess-topic", "/wheel/odometry")
    assert without["rpe_trans_mean_m"] > m["rpe_trans_mean_m"]
    assert m["frames"] == n and m["rpe_trans_mean_m"] < 0.1, m
    err = capsys.readouterr().err
    assert "guess topic /points is sensor_msgs/msg/PointCloud2, expected nav_msgs/msg/Odometry" in err, err


def _gyro_bag(path, frames=12, imu_topic="/imu"):
    """The first scans of the yaw-flip drive (test_turns.py: HDL-64E, 10 deg a frame reversing every 3 frames) with
    imu_topic: a gyro at 200 Hz (noise, 0.5 deg/s bias) in the LiDAR's frame, each sample written at its stamp."""
    import test_turns
    from line_odom.sim.gyro import gyro_samples

    drive = list(test_turns._turning_scans("hdl64", 10.0))[:frames]
    poses = np.array([T for T, _, _ in drive])
    stamps = np.array([100.0 + s for _, _, s in drive])
    samples, rates = gyro_samples(poses, stamps, rate_hz=200.0, offset=0.0025, noise_std=0.002,
                                  bias=(0.002, -0.003, np.radians(0.5)), seed=1)
    messages = [(int(round(t * 1e9)), "imu", rate) for t, rate in zip(samples, rates)]
    messages += [(int(round(t * 1e9)), "scan", k) for k, t in enumerate(stamps)]
    with bags.BagWriter(path) as writer:
        for stamp, kind, what in sorted(messages, key=lambda m: (m[0], m[1] == "scan")):
            if kind == "imu":
                writer.write(imu_topic, bags.IMU, stamp, writer.msgs.imu(stamp, "velodyne", what))
                continue
            _, scan, _ = drive[what]
            _write_scan(writer, stamp, scan.points, scan.ring, poses[what])
    return len(drive)


def test_replay_with_an_imu_topic_as_the_rotation_guess(tmp_path, capsys):
    # The yaw-flip drive's first 12 scans: from the constant-velocity prediction scan 9 is registered 7.2 deg off
    # (docs/NODE.md "Turns"); with the bag's /imu given by --imu-topic each prediction has the gyro's turn: measured
    # 0.01 deg max; bound 0.3.
    bag = tmp_path / "bag"
    n = _gyro_bag(bag)
    without, m = _replay_without_and_with(tmp_path, bag, "--imu-topic", "/imu")
    assert without["rpe_rot_max_deg"] > 5.0
    assert m["frames"] == n and m["rpe_rot_max_deg"] < 0.3, m
    err = capsys.readouterr().err
    assert "imu topic /points is sensor_msgs/msg/PointCloud2, expected sensor_msgs/msg/Imu" in err, err


REALTIME_BOUND_S = 240.0  # the run below takes ~15 s on a loaded 2-core machine


def _replay_process(args: list[str], env: dict) -> subprocess.CompletedProcess:
    """`python -m line_odom replay ...` as a user runs it, in its own process: the DDS participants live there.
    Fast DDS 2.14's shared-memory transport has known deadlocks under load (eProsima/Fast-DDS#6485,
    ros2/rmw_fastrtps#908); a run still going after REALTIME_BOUND_S gets SIGABRT, which makes Python print every
    thread's stack (PYTHONFAULTHANDLER), and is run once more. A second hang, or any wrong result, fails."""
    hung = []
    for _ in range(2):
        proc = subprocess.Popen([sys.executable, "-m", "line_odom", "replay", *args],
                                env={**env, "PYTHONFAULTHANDLER": "1"}, stdout=subprocess.PIPE,
                                stderr=subprocess.STDOUT, text=True)
        try:
            out, _ = proc.communicate(timeout=REALTIME_BOUND_S)
            return subprocess.CompletedProcess(proc.args, proc.returncode, out)
        except subprocess.TimeoutExpired:
            proc.send_signal(signal.SIGABRT)
            try:
                out, _ = proc.communicate(timeout=20)
            except subprocess.TimeoutExpired:
                proc.kill()
                out, _ = proc.communicate()
            hung.append(out[-20000:])
            warnings.warn(f"replay --realtime still running after {REALTIME_BOUND_S:.0f} s; its stacks:\n{hung[-1]}")
    pytest.fail("replay --realtime hung twice:\n" + "\n----\n".join(hung))


def test_realtime_replay_over_dds(tmp_path, ros_env, tum_bags):
    """The node in its own process, fed over DDS with /clock by the replay in another. At a fifth of the bag's
    30 Hz even a loaded machine keeps up with most frames; the ones the node skips (latest wins) are counted as
    dropped."""
    out = tmp_path / "rt"
    run = _replay_process([str(tum_bags["sqlite3"]), "--out", str(out), "--set", "downsample=10", "--realtime",
                           "--rate", "0.2", "--frames", "30", "--quiet"], ros_env)
    assert run.returncode == 0, run.stdout
    m = _metrics(out)
    assert m["frames"] + m["frames_dropped"] == 30 and m["frames"] >= 20, m
    assert m["latency_mean_ms"] > 0 and m["latency_p95_ms"] < 5000
    assert m["rpe_trans_mean_m"] < 2 * TUM_RPE_T, m  # skipped frames make longer steps for the motion model
    assert main(["replay", str(tum_bags["sqlite3"]), "--out", str(out), "--realtime", "--rate", "0"]) == 1


def test_realtime_replay_publishes_the_guess_topic(tmp_path, ros_env):
    """--guess-topic with --realtime: the wheel odometry is published beside the clouds and the node (guess_odom
    remapped to it) registers from it. Bound as in-process with room for skipped frames (longer steps): 0.15 m."""
    bag = tmp_path / "bag"
    n = _wheel_odometry_bag(bag)
    out = tmp_path / "rt"
    run = _replay_process([str(bag), "--out", str(out), "--set", "downsample=6", "--set", "base_frame=velodyne",
                           "--guess-topic", "/wheel/odometry", "--realtime", "--rate", "0.5", "--quiet"], ros_env)
    assert run.returncode == 0, run.stdout
    m = _metrics(out)
    assert m["frames"] + m["frames_dropped"] == n and m["frames"] >= n - 2, m
    assert m["rpe_trans_mean_m"] < 0.15, m


def test_realtime_replay_publishes_the_imu_topic(tmp_path, ros_env):
    """--imu-topic with --realtime: the gyro samples are published between the clouds in the bag's order and the node
    (imu remapped to the topic, which is not its own 'imu', and imu.enabled) turns each prediction by them. Scan 9 of
    the yaw flips is 7.2 deg off without the gyro; bound as in-process (0.3 deg), which frames the node skips do not
    change (the gyro spans the gap)."""
    bag = tmp_path / "bag"
    n = _gyro_bag(bag, imu_topic="/imu/data")
    out = tmp_path / "rt"
    run = _replay_process([str(bag), "--out", str(out), "--set", "downsample=6", "--set", "base_frame=velodyne",
                           "--imu-topic", "/imu/data", "--realtime", "--rate", "0.5", "--quiet"], ros_env)
    assert run.returncode == 0, run.stdout
    m = _metrics(out)
    assert m["frames"] + m["frames_dropped"] == n and m["frames"] >= n - 2, m
    assert m["rpe_rot_max_deg"] < 0.3, m

def test_realtime_replay_names_the_input_the_node_does_not_subscribe_to(tmp_path, ros_env, monkeypatch):
    """A node that never subscribes to the gyro's topic (imu.enabled false behind the replay's back) stops the
    realtime replay with an error naming that topic (it named the clouds' topic, whatever was missing)."""
    from line_odom import replay_realtime
    from line_odom.replay import select_input

    bag = tmp_path / "bag"
    _gyro_bag(bag, frames=2, imu_topic="/imu/data")
    monkeypatch.setattr(replay_realtime, "STARTUP_TIMEOUT_S", 5.0)
    with bags.BagReader(bag) as reader:
        with pytest.raises(RuntimeError, match=r"not connected within 5 s \(.*no subscription to /imu/data"):
            replay_realtime.run_realtime(reader, select_input(reader), overrides={"downsample": 6,
                                                                                  "imu.enabled": False},
                                         imu_topic="/imu/data")

def test_realtime_replay_latches_the_bags_tf_static(tmp_path, ros_env, kitti_bags):
    """--realtime with base_to_sensor_from_tf: the bag's /tf_static is published latched for the node, which takes
    the camera's mounting from it; the sensor poses written are those of the in-process replay (bound: the
    in-process run's error, with room for frames the node skips)."""
    args = ["--set", "downsample=6", "--set", "base_to_sensor_from_tf=true", "--set", "base_frame=camera_0", "--quiet"]
    assert main(["replay", str(kitti_bags["sqlite3"]), "--out", str(tmp_path / "in"), *args]) == 0
    run = _replay_process([str(kitti_bags["sqlite3"]), "--out", str(tmp_path / "rt"), "--realtime", "--rate", "0.5",
                           *args], ros_env)
    assert run.returncode == 0, run.stdout
    offline, live = _metrics(tmp_path / "in"), _metrics(tmp_path / "rt")
    assert live["frames"] + live["frames_dropped"] == 10 and live["frames"] >= 8, live
    # (without the latched transform the node drops every frame; with another mounting than the replay's, each
    # 0.86 m step would come out turned into the camera's axes: ~1 m off)
    assert live["rpe_trans_mean_m"] < 1.5 * offline["rpe_trans_mean_m"] + 0.05, (live, offline)


DIE_WITH_PARENT_PARENT = r"""
import subprocess, sys, time
from line_odom.replay_realtime import die_with_parent
child = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(120)"], preexec_fn=die_with_parent)
print(child.pid, flush=True)
time.sleep(120)
"""


def test_the_node_child_of_a_killed_replay_does_not_outlive_it():
    """replay --realtime starts the node with die_with_parent: SIGKILL of the replay (no cleanup runs) ends it."""
    parent = subprocess.Popen([sys.executable, "-c", DIE_WITH_PARENT_PARENT], stdout=subprocess.PIPE, text=True)
    try:
        child_pid = int(parent.stdout.readline())
        assert _alive(child_pid)
        parent.kill()
        parent.wait(timeout=10)
        deadline = time.monotonic() + 10
        while _alive(child_pid) and time.monotonic() < deadline:
            time.sleep(0.05)
        assert not _alive(child_pid), "the child outlived its SIGKILLed parent"
    finally:
        parent.kill()
        parent.wait()


def _alive(pid: int) -> bool:
    """Running (not a zombie): a dead orphan is reaped by init, a dead child of a live parent is a zombie."""
    try:
        with open(f"/proc/{pid}/stat") as f:
            return f.read().rsplit(")", 1)[1].split()[0] != "Z"
    except FileNotFoundError:
        return False


def test_demo_small(tmp_path, capsys):
    scenarios = tuple(demo.Scenario(s.name, s.title, s.kind, 25 if s.kind == "street" else 20, s.sensor, s.noise_std,
                                    s.overrides) for s in demo.SCENARIOS)
    results = demo.run_demo(tmp_path / "demo", progress=False, scenarios=scenarios)
    out = capsys.readouterr().out
    assert "summary" in out and "street" in out and "room" in out
    assert results["street"]["frames"] == 25 and results["room"]["frames"] == 20
    for name in ("street", "room"):
        assert (tmp_path / "demo" / name / "trajectory.png").exists()
        assert results[name]["rpe_trans_mean_m"] < (0.2 if name == "street" else 0.02), results[name]


def test_demo_command_end_to_end(tmp_path, capsys):
    """The README's main job, as a user runs it: both simulated runs through the node, with the KITTI metric on the
    120 m drive."""
    out = tmp_path / "demo_out"
    assert main(["demo", "--out", str(out), "--quiet"]) == 0
    printed = capsys.readouterr().out
    assert "KITTI t_err" in printed and "summary" in printed
    street = json.loads((out / "street" / "metrics.json").read_text())
    room = json.loads((out / "room" / "metrics.json").read_text())
    assert street["frames"] == 120 and street["frames_dropped"] == 0 and street["path_length_m"] > 100
    assert street["kitti_t_err_pct"] < 2.0 and street["rpe_trans_mean_m"] < 0.05, street
    assert room["frames"] == 90 and room["rpe_trans_mean_m"] < 0.01, room
    for name in ("street", "room"):
        assert (out / name / "trajectory.png").stat().st_size > 10_000
        assert (out / name / "input_bag" / "metadata.yaml").exists()


def test_replay_and_replay_realtime_import_each_other_not():
    """replay_realtime takes what it shares with replay from replay_common: importing it loads no replay."""
    code = ("import sys, line_odom.replay_realtime; "
            "assert 'line_odom.replay' not in sys.modules, 'replay_realtime imports replay'")
    subprocess.run([sys.executable, "-c", code], check=True, timeout=120)


def test_realtime_replay_of_an_ouster_pcap(tmp_path, ros_env):
    """--realtime on a recording that is no bag: its frames become a temporary bag published to the node; the
    poses are the in-process run's (3 scans, each one registered)."""
    rec = datasets.SHARED_DATA / "sensor_recordings"
    args = [str(rec / "OS-1-128_v2.3.0_1024x10_lb_n3.pcap"), "--ground-truth",
            str(rec / "OS-1-128_v2.3.0_1024x10_lb_n3_poses_kitti.txt"), "--quiet"]
    assert main(["replay", *args, "--out", str(tmp_path / "in")]) == 0
    run = _replay_process([*args, "--out", str(tmp_path / "rt"), "--realtime", "--rate", "0.5", "--plot-features", "1"],
                          ros_env)
    assert run.returncode == 0, run.stdout
    # the node ran in its own process: features.png from the same frames through its processing core here
    assert (tmp_path / "rt" / "features.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    offline, live = _metrics(tmp_path / "in"), _metrics(tmp_path / "rt")
    assert live["input"]["format"] == "ouster" and live["input"]["preset"] == "ouster_os128"
    assert live["frames"] == 3 and live["frames_with_ground_truth"] == 3, live
    assert live["rpe_trans_max_m"] < offline["rpe_trans_max_m"] + 0.01, (live, offline)
