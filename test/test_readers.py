"""`line_odom replay PATH` on every recording format, each on a real file: the sensor files of
../shared/data/sensor_recordings as recorded, a ROS 1 bag and a folder of PCD scans written here from real KITTI frames,
a KITTI raw drive folder laid out here from real KITTI raw scans, the shared KITTI odometry and TUM folders."""
from __future__ import annotations

import datetime
import json
import math
import shutil
from pathlib import Path

import numpy as np
import pytest

from line_odom import bags, cli, datasets, readers
from line_odom.replay import replay

REC = datasets.SHARED_DATA / "sensor_recordings"
OS1_PCAP = REC / "OS-1-128_v2.3.0_1024x10_lb_n3.pcap"
OS1_POSES = REC / "OS-1-128_v2.3.0_1024x10_lb_n3_poses_kitti.txt"
OS2_PCAP = REC / "OS-2-32-U0_v2.0.0_1024x10.pcap"
OSF = REC / "osf_fw_3.2_10scans.osf"
VELODYNE_PCAP = REC / "vlp16_50frames.pcap"
STOP_AND_GO = datasets.SHARED_DATA / "kitti_raw_stop_and_go"
KITTI_07 = datasets.SHARED_DATA / "kitti_odometry_mini" / "sequences" / "07"
SWEEP_S = 0.1  # the HDL-64E turns at 10 Hz


def _metrics(out: Path) -> dict:
    return json.loads((out / "metrics.json").read_text())


def _estimate(out: Path) -> np.ndarray:
    return np.loadtxt(out / "trajectory_kitti.txt", ndmin=2).reshape(-1, 3, 4)


def _assert_outputs(out: Path, frames: int) -> dict:
    m = _metrics(out)
    assert m["frames"] == frames and m["frames_dropped"] == 0
    poses = _estimate(out)
    assert poses.shape == (frames, 3, 4) and np.isfinite(poses).all()
    for name in ("trajectory_tum.txt", "trajectory.png"):
        assert (out / name).stat().st_size > 0
    return m


def _kitti_times(xyz: np.ndarray) -> np.ndarray:
    """Seconds from the stamp a KITTI point was measured at, from its azimuth: the HDL-64E turns clockwise seen from
    above and the scan is stamped when it looks forward (+x)."""
    return -np.arctan2(xyz[:, 1], xyz[:, 0]) / (2 * math.pi) * SWEEP_S


# ------------------------------------------------------------------------------------------------ formats


def test_formats_are_guessed_from_the_path(tmp_path):
    assert readers.guess_format(VELODYNE_PCAP) == "velodyne"
    assert readers.guess_format(OS1_PCAP) == "ouster"
    assert readers.guess_format(OSF) == "ouster"
    assert readers.guess_format(KITTI_07) == "kitti"
    assert readers.guess_format(STOP_AND_GO / "velodyne") == "scans"
    assert readers.guess_format(datasets.SHARED_DATA / "tum_rgbd_fr1_xyz") == "tum"
    (tmp_path / "drive" / "velodyne_points" / "data").mkdir(parents=True)
    assert readers.guess_format(tmp_path / "drive") == "kitti_raw"
    (tmp_path / "old.bag").write_bytes(b"#ROSBAG V2.0\n")
    assert readers.guess_format(tmp_path / "old.bag") == "ros1"


def test_velodyne_pcap_every_rotation_with_ring_and_time(tmp_path):
    import velodyne_decoder as vd

    clouds = [len(c.points) for c in vd.read_pcap(str(VELODYNE_PCAP), vd.Config(), as_pcl_structs=True)]
    full = len(clouds) - (clouds[-1] < 0.5 * clouds[-2])  # the decoder flushes a cut-off last rotation
    out = tmp_path / "out"
    result = replay(VELODYNE_PCAP, out, progress=False)
    m = _assert_outputs(out, full)
    # HDL-32E packets (product id 0x21) despite the file's name: 32 rings, no preset of that sensor
    assert result.input["overrides"]["sensor.rows"] == 32 and result.input["preset"] == "vlp16"
    assert m["frames_with_ring"] == m["frames_with_time"] == full
    assert m["rows_from"] == "ring"
    assert m["frames_deskewed"] >= full - 1 and m["point_times_ignored"] == 0  # all but the first (no velocity yet)
    assert "ground_truth_tum.txt" not in {p.name for p in result.files}


@pytest.mark.parametrize("path, method", [(VELODYNE_PCAP, "register_points"), (OS1_PCAP, "register_organized"),
                                          (OSF, "register_organized")])
def test_rings_and_point_times_reach_the_engine(tmp_path, monkeypatch, path, method):
    """What replay hands the engine is the reader's own rings and times, and the engine deskews with them: a spy on
    line_odom_core.Odometry sees, for each frame, the reader's ring (Velodyne; an Ouster scan is organized, its rows
    are the beams) and time arrays in the call, and the engine's own stats say the sweep was corrected."""
    import line_odom_core

    frames = 4
    with readers.open_source(path, frames=frames) as source:
        read = list(source.frames())
        beams = getattr(source, "beams", None)
    calls = []
    original = getattr(line_odom_core.Odometry, method)

    def spy(self, xyz, stamp, **kwargs):
        result = original(self, xyz, stamp, **kwargs)
        calls.append((np.array(xyz), kwargs, dict(result.stats)))
        return result

    monkeypatch.setattr(line_odom_core.Odometry, method, spy)
    replay(path, tmp_path / "out", frames=frames, progress=False)
    assert len(calls) == len(read) >= 3
    for (xyz, kwargs, stats), frame in zip(calls, read):
        measured = np.isfinite(frame.xyz).all(axis=-1)  # a point without a return has no time that matters
        # the message carries times as float32 (seconds from the stamp): equal to well under a microsecond
        np.testing.assert_allclose(kwargs["time"][measured], frame.time[measured], rtol=0, atol=1e-7)
        if method == "register_points":
            np.testing.assert_array_equal(kwargs["ring"], frame.ring)
            assert len(np.unique(kwargs["ring"])) == 32  # every beam of the sensor
        else:
            assert xyz.shape == frame.xyz.shape and xyz.shape[0] == beams  # organized: rows = beams
        assert np.ptp(kwargs["time"][measured]) > 0.04  # one sweep (20 Hz Velodyne, 10 Hz Ouster)
    # the first two frames have no velocity to deskew at; from the third on every sweep is corrected
    assert [stats["deskewed"] for _, _, stats in calls[2:]] == [True] * (len(calls) - 2)


def test_ouster_os1_128_pcap_within_its_reference_poses(tmp_path):
    out = tmp_path / "out"
    result = replay(OS1_PCAP, out, ground_truth=OS1_POSES, out_bag=tmp_path / "odom_bag",
                    progress=False)  # the json beside it is found
    m = _assert_outputs(out, 3)
    with bags.BagReader(tmp_path / "odom_bag") as written:
        assert written.counts["/odom"] == 3 and written.counts[bags.GROUND_TRUTH_TOPIC] == 3
    assert result.input["preset"] == "ouster_os128"
    assert m["frames_with_time"] == 3 and m["rows_from"] == "organized" and m["frames_deskewed"] >= 1
    # the shipped poses move ~0.25 m a scan: 5 cm a frame is a fifth of the motion
    assert m["frames_with_ground_truth"] == 3
    assert m["rpe_trans_max_m"] < 0.05 and m["rpe_rot_max_deg"] < 0.3


def test_ouster_os2_32_pcap(tmp_path):
    out = tmp_path / "out"
    result = replay(OS2_PCAP, out, progress=False)
    m = _assert_outputs(out, 1)
    assert result.input["overrides"] == {"downsample": 1}  # 32 beams: every one kept
    assert m["frames_with_time"] == 1 and m["rows_from"] == "organized"


def test_ouster_osf(tmp_path):
    out = tmp_path / "out"
    replay(OSF, out, progress=False)
    m = _assert_outputs(out, 10)
    assert m["frames_with_time"] == 10 and m["point_times_ignored"] == 0
    stamps = np.loadtxt(out / "trajectory_tum.txt", ndmin=2)[:, 0]
    assert np.all(np.diff(stamps) > 0.05) and np.all(np.diff(stamps) < 0.15)  # 10 Hz scans, stamped by the sensor


def test_ros1_bag_of_kitti_frames(tmp_path):
    from rosbags.rosbag1 import Writer
    from rosbags.typesys import Stores, get_typestore
    from scipy.spatial.transform import Rotation

    store = get_typestore(Stores.ROS1_NOETIC)
    T = store.types
    seq = datasets.KittiSequence.open(KITTI_07, 3)
    bag = tmp_path / "kitti.bag"
    with Writer(bag) as writer:
        points_conn = writer.add_connection("/velodyne_points", "sensor_msgs/msg/PointCloud2", typestore=store)
        gt_conn = writer.add_connection("/ground_truth", "nav_msgs/msg/Odometry", typestore=store)
        for i in range(len(seq)):
            raw = seq.points(i)
            cloud = np.zeros(len(raw), dtype=[("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("intensity", "<f4"),
                                              ("ring", "<u2"), ("time", "<f4")])
            for k, name in enumerate(("x", "y", "z", "intensity")):
                cloud[name] = raw[:, k]
            cloud["ring"] = bags.kitti_rings(raw)
            cloud["time"] = _kitti_times(raw)
            ns = round(seq.times[i] * 1e9) + 1_000_000_000
            stamp = T["builtin_interfaces/msg/Time"](sec=ns // 10**9, nanosec=ns % 10**9)
            header = T["std_msgs/msg/Header"](seq=i, stamp=stamp, frame_id="velodyne")
            fields = [T["sensor_msgs/msg/PointField"](name=n, offset=int(cloud.dtype.fields[n][1]),
                                                      datatype={"ring": 4}.get(n, 7), count=1)
                      for n in cloud.dtype.names]
            msg = T["sensor_msgs/msg/PointCloud2"](header=header, height=1, width=len(cloud), fields=fields,
                                                   is_bigendian=False, point_step=cloud.dtype.itemsize,
                                                   row_step=cloud.dtype.itemsize * len(cloud),
                                                   data=np.frombuffer(cloud.tobytes(), np.uint8), is_dense=True)
            writer.write(points_conn, ns, store.serialize_ros1(msg, "sensor_msgs/msg/PointCloud2"))
            q = Rotation.from_matrix(seq.poses[i][:3, :3]).as_quat()
            pose = T["geometry_msgs/msg/Pose"](
                position=T["geometry_msgs/msg/Point"](x=seq.poses[i][0, 3], y=seq.poses[i][1, 3], z=seq.poses[i][2, 3]),
                orientation=T["geometry_msgs/msg/Quaternion"](x=q[0], y=q[1], z=q[2], w=q[3]))
            zero = T["geometry_msgs/msg/Vector3"](x=0.0, y=0.0, z=0.0)
            odom_msg = T["nav_msgs/msg/Odometry"](
                header=T["std_msgs/msg/Header"](seq=i, stamp=stamp, frame_id="world"), child_frame_id="velodyne",
                pose=T["geometry_msgs/msg/PoseWithCovariance"](pose=pose, covariance=np.zeros(36)),
                twist=T["geometry_msgs/msg/TwistWithCovariance"](
                    twist=T["geometry_msgs/msg/Twist"](linear=zero, angular=zero), covariance=np.zeros(36)))
            writer.write(gt_conn, ns, store.serialize_ros1(odom_msg, "nav_msgs/msg/Odometry"))
    out = tmp_path / "out"
    result = replay(bag, out, overrides={"downsample": 6}, progress=False)
    m = _assert_outputs(out, 3)
    assert result.input["format"] == "ros1" and result.input["preset"] == "kitti_hdl64"
    assert m["frames_with_ring"] == m["frames_with_time"] == 3 and m["rows_from"] == "ring"
    assert m["frames_deskewed"] >= 1
    assert m["frames_with_ground_truth"] == 3
    assert m["rpe_trans_max_m"] < 0.08  # the car moves 0.09-0.17 m a frame


def test_ros1_bag_of_tum_depth_frames(tmp_path):
    from rosbags.rosbag1 import Writer
    from rosbags.typesys import Stores, get_typestore

    store = get_typestore(Stores.ROS1_NOETIC)
    T = store.types
    seq = datasets.tum_sequence(4)
    bag = tmp_path / "tum.bag"
    with Writer(bag) as writer:
        image_conn = writer.add_connection("/camera/depth/image", "sensor_msgs/msg/Image", typestore=store)
        info_conn = writer.add_connection("/camera/depth/camera_info", "sensor_msgs/msg/CameraInfo", typestore=store)
        for i in range(len(seq)):
            ns = round(seq.stamps[i] * 1e9)
            header = T["std_msgs/msg/Header"](seq=i, stamp=T["builtin_interfaces/msg/Time"](
                sec=ns // 10**9, nanosec=ns % 10**9), frame_id="camera_depth_optical_frame")
            mm = np.round(seq.depth_raw(i) * (1000.0 / datasets.TUM_DEPTH_FACTOR)).astype("<u2")
            image = T["sensor_msgs/msg/Image"](header=header, height=mm.shape[0], width=mm.shape[1], encoding="16UC1",
                                               is_bigendian=0, step=2 * mm.shape[1],
                                               data=np.frombuffer(mm.tobytes(), np.uint8))
            info = T["sensor_msgs/msg/CameraInfo"](
                header=header, height=mm.shape[0], width=mm.shape[1], distortion_model="plumb_bob", D=np.zeros(5),
                K=seq.K.reshape(-1), R=np.eye(3).reshape(-1), P=np.hstack([seq.K, np.zeros((3, 1))]).reshape(-1),
                binning_x=0, binning_y=0, roi=T["sensor_msgs/msg/RegionOfInterest"](
                    x_offset=0, y_offset=0, height=0, width=0, do_rectify=False))
            writer.write(info_conn, ns, store.serialize_ros1(info, "sensor_msgs/msg/CameraInfo"))
            writer.write(image_conn, ns, store.serialize_ros1(image, "sensor_msgs/msg/Image"))
    out = tmp_path / "out"
    result = replay(bag, out, overrides={"downsample": 10}, progress=False)
    _assert_outputs(out, 4)
    assert result.input["preset"] == "tum_kinect"
    estimate = np.loadtxt(out / "trajectory_kitti.txt", ndmin=2).reshape(-1, 3, 4)
    gt = np.linalg.inv(seq.poses[0]) @ seq.poses[3]
    moved = np.linalg.inv(np.vstack([estimate[0], [0, 0, 0, 1]])) @ np.vstack([estimate[3], [0, 0, 0, 1]])
    # under half of the ground truth's motion over the three frames (~4 cm): registered, not held
    assert np.linalg.norm(moved[:3, 3] - gt[:3, 3]) < 0.5 * np.linalg.norm(gt[:3, 3]), (moved, gt)


# ------------------------------------------------------------------------------------------------ KITTI raw

# A KITTI raw calibration of the IMU in the Velodyne frame (the form of <date>/calib_imu_to_velo.txt).
IMU_TO_VELO = ("calib_time: 25-May-2012 16:47:16\n"
               "R: 9.999976e-01 7.553071e-04 -2.035826e-03 -7.854027e-04 9.998898e-01 -1.482298e-02 "
               "2.024406e-03 1.482454e-02 9.998881e-01\n"
               "T: -8.086759e-01 3.195559e-01 -7.997231e-01\n")
ORIGIN = (49.011, 8.4168, 112.0, 0.01, -0.02, 1.2)  # lat, lon (deg), alt (m), roll, pitch, yaw (rad): Karlsruhe


def _oxts_records(velo_poses: np.ndarray, T_velo_imu: np.ndarray) -> np.ndarray:
    """OXTS records whose poses (as convertOxtsToPose defines them) put the Velodyne at `velo_poses`: each IMU pose
    placed at ORIGIN's position and heading, then latitude / longitude by inverting the scaled Mercator projection."""
    from scipy.spatial.transform import Rotation

    R = 6378137.0
    lat0, lon0, alt0, roll0, pitch0, yaw0 = ORIGIN
    scale = math.cos(math.radians(lat0))
    W0 = np.eye(4)
    W0[:3, :3] = Rotation.from_euler("ZYX", [yaw0, pitch0, roll0]).as_matrix()
    W0[:3, 3] = (scale * math.radians(lon0) * R, scale * R * math.log(math.tan(math.radians(90 + lat0) / 2)), alt0)
    records = np.zeros((len(velo_poses), 30))
    for i, V in enumerate(velo_poses):
        W = W0 @ np.linalg.inv(T_velo_imu) @ V @ T_velo_imu
        mx, my, alt = W[:3, 3]
        lon = math.degrees(mx / (scale * R))
        lat = 2 * math.degrees(math.atan(math.exp(my / (scale * R)))) - 90
        yaw, pitch, roll = Rotation.from_matrix(W[:3, :3]).as_euler("ZYX")
        records[i, :6] = (lat, lon, alt, roll, pitch, yaw)
        records[i, 23:] = (0.05, 0.02, 4, 10, 5, 5, 6)  # accuracies, navstat, satellites, modes: a good fix
    return records


def _kitti_raw_drive(root: Path, frames: int) -> tuple[Path, np.ndarray]:
    """A drive folder as the KITTI raw download lays it out, from the real stop-and-go scans. That source has no
    OXTS records or calibration, so they are made here: valid records (30 values each) whose converted poses are the
    scans' dense reference poses, and a calibration file of the KITTI raw form."""
    date = root / "2011_09_26"
    drive = date / "2011_09_26_drive_0052_sync"
    (drive / "velodyne_points" / "data").mkdir(parents=True)
    (drive / "oxts" / "data").mkdir(parents=True)
    (date / "calib_imu_to_velo.txt").write_text(IMU_TO_VELO)
    T_velo_imu = np.eye(4)
    lines = IMU_TO_VELO.splitlines()
    T_velo_imu[:3, :3] = np.array(lines[1].split()[1:], float).reshape(3, 3)
    T_velo_imu[:3, 3] = np.array(lines[2].split()[1:], float)
    reference = datasets.read_kitti_poses(STOP_AND_GO / "reference_poses.txt")[:frames]
    stamps = []
    start = datetime.datetime(2011, 9, 26, 13, 2, 25)
    for i in range(frames):
        (drive / "velodyne_points" / "data" / f"{i:010d}.bin").symlink_to(STOP_AND_GO / "velodyne" / f"{i:06d}.bin")
        nanos = 500_000_000 + i * 103_600_000  # 10.36 Hz, KITTI raw's rate
        stamps.append((start + datetime.timedelta(seconds=nanos // 10**9)).strftime("%Y-%m-%d %H:%M:%S")
                      + f".{nanos % 10**9:09d}")
    for i, record in enumerate(_oxts_records(reference, T_velo_imu)):
        (drive / "oxts" / "data" / f"{i:010d}.txt").write_text(" ".join(repr(float(v)) for v in record) + "\n")
    (drive / "velodyne_points" / "timestamps.txt").write_text("\n".join(stamps) + "\n")
    (drive / "oxts" / "timestamps.txt").write_text("\n".join(stamps) + "\n")
    return drive, reference


def test_oxts_poses_known_answers():
    from line_odom.readers import oxts

    lat = 49.0
    east = np.zeros((2, 30))
    east[:, 0] = lat
    east[1, 1] = 1e-4  # 1e-4 deg of longitude further east
    metres = math.cos(math.radians(lat)) * 6378137.0 * math.radians(1e-4)
    np.testing.assert_allclose(oxts.oxts_poses(east)[1][:3, 3], [metres, 0, 0], atol=1e-9)
    east[:, 5] = math.pi / 2  # facing north (yaw 0 is east): east is to the right, -y
    np.testing.assert_allclose(oxts.oxts_poses(east)[1][:3, 3], [0, -metres, 0], atol=1e-9)
    up = np.zeros((2, 30))
    up[1, 2], up[:, 4] = 2.0, 0.1  # 2 m up, pitched by 0.1 rad
    pose = oxts.oxts_poses(up)[1]
    np.testing.assert_allclose(pose[:3, 3], [-2 * math.sin(0.1), 0, 2 * math.cos(0.1)], atol=1e-12)


def test_kitti_raw_drive_with_oxts_ground_truth(tmp_path):
    drive, reference = _kitti_raw_drive(tmp_path, 5)
    source = readers.open_source(drive)
    assert source.format == "kitti_raw" and source.count == 5
    # the reader's convertOxtsToPose and calibration give back the poses the records were made from
    np.testing.assert_allclose(source.ground_truth.poses, reference, atol=2e-5)
    assert np.diff(source.ground_truth.stamps) == pytest.approx([0.1036] * 4, abs=1e-6)
    source.close()
    out = tmp_path / "out"
    result = replay(drive, out, overrides={"downsample": 2}, progress=False)
    m = _assert_outputs(out, 5)
    assert "OXTS" in result.input["ground_truth"] and result.input["preset"] == "kitti_hdl64"
    assert m["frames_with_ring"] == 5 and m["rows_from"] == "ring" and m["frames_with_time"] == 0
    assert m["frames_with_ground_truth"] == 5
    # the car moves 0.28 m a scan here: under half of it, the scans were registered against their ground truth
    assert m["rpe_trans_mean_m"] < 0.14


def test_kitti_raw_drive_without_calibration_has_no_ground_truth(tmp_path):
    drive, _ = _kitti_raw_drive(tmp_path, 2)
    (drive.parent / "calib_imu_to_velo.txt").unlink()
    source = readers.open_source(drive)
    assert source.ground_truth is None and any("calib_imu_to_velo.txt" in n for n in source.notes)


# ------------------------------------------------------------------------------------------------ folders


def test_pcd_folder_with_ring_and_time(tmp_path):
    import pypcd4

    seq = datasets.KittiSequence.open(KITTI_07, 3)
    folder = tmp_path / "pcd"
    folder.mkdir()
    for i in range(len(seq)):
        raw = seq.points(i)
        arrays = [raw[:, 0], raw[:, 1], raw[:, 2], raw[:, 3], bags.kitti_rings(raw), _kitti_times(raw)]
        pc = pypcd4.PointCloud.from_points(arrays, ("x", "y", "z", "intensity", "ring", "time"),
                                           (np.float32, np.float32, np.float32, np.float32, np.uint16, np.float32))
        pc.save(folder / f"scan_{i}.pcd")
    (folder / "times.txt").write_text("\n".join(f"{t:.6f}" for t in seq.times) + "\n")
    out = tmp_path / "out"
    result = replay(folder, out, overrides={"downsample": 6}, plot_features=1, progress=False)
    m = _assert_outputs(out, 3)
    assert result.input["format"] == "scans" and result.input["preset"] == "kitti_hdl64"
    assert m["frames_with_ring"] == m["frames_with_time"] == 3 and m["rows_from"] == "ring"
    assert m["frames_deskewed"] >= 1
    stamps = np.loadtxt(out / "trajectory_tum.txt", ndmin=2)[:, 0]
    np.testing.assert_allclose(stamps, seq.times, atol=1e-6)
    _assert_features_png(out / "features.png")


def test_ply_folder_without_rings_gets_the_preset_its_clouds_fit(tmp_path):
    import plyfile

    seq = datasets.KittiSequence.open(KITTI_07, 2)
    folder = tmp_path / "ply"
    folder.mkdir()
    for i in range(len(seq)):
        raw = seq.points(i)
        vertex = np.zeros(len(raw), dtype=[("x", "f4"), ("y", "f4"), ("z", "f4")])
        vertex["x"], vertex["y"], vertex["z"] = raw[:, 0], raw[:, 1], raw[:, 2]
        plyfile.PlyData([plyfile.PlyElement.describe(vertex, "vertex")]).write(str(folder / f"{i:03d}.ply"))
    out = tmp_path / "out"
    result = replay(folder, out, overrides={"downsample": 6}, progress=False)
    m = _assert_outputs(out, 2)
    assert result.input["preset"] == "kitti_hdl64" and "fits the sensor model" in result.input["sensor"]
    assert m["frames_with_ring"] == 0 and m["rows_from"] != "ring"  # the engine finds the rows itself
    assert any("0.1 s apart" in n for n in result.input["notes"])


def test_kitti_odometry_and_tum_folders(tmp_path):
    replay(KITTI_07, tmp_path / "kitti", frames=3, overrides={"downsample": 6}, progress=False)
    m = _assert_outputs(tmp_path / "kitti", 3)
    assert m["frames_with_ring"] == 3 and m["frames_with_ground_truth"] == 3 and m["rpe_trans_max_m"] < 0.08
    result = replay(datasets.SHARED_DATA / "tum_rgbd_fr1_xyz", tmp_path / "tum", frames=4,
                    overrides={"downsample": 10}, plot_features=2, progress=False)
    m = _assert_outputs(tmp_path / "tum", 4)
    assert result.input["preset"] == "tum_kinect" and m["frames_with_ground_truth"] == 4
    assert m["rpe_trans_max_m"] < 0.03  # the camera moves ~1 cm a frame
    _assert_features_png(tmp_path / "tum" / "features.png")


def test_rosbag2_through_replay_path_with_plot_features(tmp_path):
    bag = tmp_path / "bag"
    bags.kitti_to_bag(KITTI_07, bag, frames=2)
    out = tmp_path / "out"
    result = replay(next(bag.glob("*.db3")), out, overrides={"downsample": 6}, plot_features=0,
                    progress=False)  # the storage file inside the bag names the bag too
    m = _assert_outputs(out, 2)
    assert result.input["format"] == "rosbag2" and m["frames_with_ring"] == 2 and m["frames_with_ground_truth"] == 2
    _assert_features_png(out / "features.png")


def _assert_features_png(path: Path) -> None:
    """Both line colours are drawn, ~/lines' own: orange H-lines and blue V-lines, antialiased."""
    from PIL import Image

    r, g, b = np.asarray(Image.open(path).convert("RGB")).reshape(-1, 3).astype(int).T
    assert ((b > r + 60) & (b > g + 20)).sum() > 500  # blue
    assert ((r > g + 60) & (r > b + 60)).sum() > 500  # orange


# ------------------------------------------------------------------------------------------------ errors


def _cli_error(capsys, *argv) -> tuple[int, str]:
    code = cli.main(["replay", *map(str, argv)])
    err = capsys.readouterr().err.strip()
    assert code == 2 or len(err.splitlines()) == 1, err  # (a usage error prints argparse's usage above its line)
    return code, err.splitlines()[-1]


def test_errors_are_one_line(tmp_path, capsys):
    (tmp_path / "notes.txt").write_text("hello\n")
    code, err = _cli_error(capsys, tmp_path / "notes.txt", "--out", tmp_path / "o")
    assert code == 1 and "unknown recording format" in err and "--format" in err
    code, err = _cli_error(capsys, OS2_PCAP, "--format", "velodyne", "--out", tmp_path / "o")
    assert code == 1 and "not a Velodyne pcap" in err and "6464 bytes" in err
    code, err = _cli_error(capsys, VELODYNE_PCAP, "--format", "ouster", "--out", tmp_path / "o")
    assert code == 1 and "a Velodyne pcap" in err
    lonely = tmp_path / "alone" / OS1_PCAP.name
    lonely.parent.mkdir()
    shutil.copy(OS1_PCAP, lonely)
    code, err = _cli_error(capsys, lonely, "--out", tmp_path / "o")
    assert code == 1 and "metadata json" in err and "--meta" in err
    code, err = _cli_error(capsys, lonely, "--meta", tmp_path / "missing.json", "--out", tmp_path / "o")
    assert code == 1 and "missing.json" in err
    # a pcap of another sensor model than its metadata's
    code, err = _cli_error(capsys, OS1_PCAP, "--meta", REC / "OS-2-32-U0_v2.0.0_1024x10.json", "--out", tmp_path / "o")
    assert code == 1 and "no scan of the OS-2-32-U0" in err
    (tmp_path / "other.json").write_text('{"product": "none"}\n')
    code, err = _cli_error(capsys, OS2_PCAP, "--meta", tmp_path / "other.json", "--out", tmp_path / "o")
    assert code == 1 and "other.json" in err and "cannot read the metadata json" in err
    code, err = _cli_error(capsys, OSF, "--format", "lidar", "--out", tmp_path / "o")
    assert code == 2 and "--format" in err and "invalid choice" in err
    code, err = _cli_error(capsys, OSF, "--imu-topic", "/imu", "--out", tmp_path / "o")
    assert code == 1 and "rosbag2" in err and "--imu-topic" in err


@pytest.mark.parametrize("path, overrides, index", [(VELODYNE_PCAP, {}, 2), (OS1_PCAP, {}, 1),
                                                   (KITTI_07, {"downsample": 6}, 1)])
def test_plot_features_draws_the_scan_and_lines_the_node_sends_rviz(tmp_path, monkeypatch, path, overrides, index):
    """features.png draws frame N's ~/scan points and ~/lines segments as the node's processing makes them: the same
    arrays as the processor's own messages for that frame, the lines those the engine registered (last_lines)."""
    from line_odom import plot
    from line_odom.processor import OdometryProcessor
    from line_odom.replay import frame_message, node_settings

    drawn = {}
    original = plot.plot_registered_view

    def spy(png, scan, lines, **kwargs):
        drawn.update(scan=scan, lines=lines, **kwargs)
        return original(png, scan, lines, **kwargs)

    monkeypatch.setattr(plot, "plot_registered_view", spy)
    replay(path, tmp_path / "out", frames=index + 1, overrides=overrides, plot_features=index, progress=False)
    _assert_features_png(tmp_path / "out" / "features.png")
    assert drawn["depth"] is False
    with readers.open_source(path, frames=index + 1) as source:
        config, settings = node_settings("pointcloud", source.sensor.preset, {**source.sensor.overrides, **overrides})
        processor = OdometryProcessor(config, settings)
        for i, frame in enumerate(source.frames()):
            processor.scan_wanted = processor.lines_wanted = i == index
            out = processor.process_pointcloud(frame_message(frame, source.frame_id))
    h_lines, v_lines = processor.engine.last_lines()
    ends = {m.ns: np.array([[p.x, p.y, p.z] for p in m.points]) for m in drawn["lines"].markers}
    for kind, segments in (("h_lines", h_lines), ("v_lines", v_lines)):
        assert len(segments) > 50 and len(segments) == out.stats[kind], kind
        np.testing.assert_array_equal(ends[kind], segments.reshape(-1, 3))
    from line_odom import convert

    np.testing.assert_array_equal(convert.pointcloud2_to_arrays(drawn["scan"]).xyz,
                                  convert.pointcloud2_to_arrays(out.scan).xyz)


def test_plot_features_of_a_frame_past_the_end_is_one_line(tmp_path, capsys):
    code = cli.main(["replay", str(OS2_PCAP), "--out", str(tmp_path / "o"), "--plot-features", "3", "--quiet"])
    err = capsys.readouterr().err.strip()
    assert code == 1 and err == "line_odom replay: error: --plot-features 3: the recording has 1 frame(s) (0 .. 0)"


def test_rosbag2_of_another_lidar_gets_the_preset_its_clouds_suggest(tmp_path):
    with readers.open_source(VELODYNE_PCAP, frames=3) as source:
        frames = [(f.stamp_ns * 1e-9, f.xyz, f.ring, f.intensity, None) for f in source.frames()]
    bags.lidar_frames_to_bag(tmp_path / "bag", frames, topic="/velodyne_points", frame_id="velodyne")
    result = replay(tmp_path / "bag", tmp_path / "out", progress=False)
    _assert_outputs(tmp_path / "out", 3)
    assert result.input["preset"] == "vlp16" and result.input["overrides"]["sensor.rows"] == 32
    assert result.metrics["frames_with_ring"] == 3 and result.run.counters["clouds_not_fitting_sensor"] == 0
