"""rosbag2 conversion (KITTI, TUM; sqlite3 and mcap) read back field by field, and broken bags."""
import numpy as np
import pytest

from line_odom import bags, convert, datasets

KITTI_00 = datasets.SHARED_DATA / "kitti_odometry_mini" / "sequences" / "00"
TUM_DIR = datasets.SHARED_DATA / "tum_rgbd_fr1_xyz"


@pytest.fixture(scope="module", params=bags.STORAGES)
def kitti_bag(request, tmp_path_factory):
    path = tmp_path_factory.mktemp("kitti") / f"kitti_{request.param}"
    assert bags.kitti_to_bag(KITTI_00, path, storage=request.param, frames=3) == 3
    return path, request.param


@pytest.fixture(scope="module", params=bags.STORAGES)
def tum_bag(request, tmp_path_factory):
    path = tmp_path_factory.mktemp("tum") / f"tum_{request.param}"
    assert bags.tum_to_bag(TUM_DIR, path, storage=request.param, frames=4) == 4
    return path, request.param


def test_kitti_bag_round_trip(kitti_bag):
    path, storage = kitti_bag
    assert list(path.glob("*.mcap" if storage == "mcap" else "*.db3"))
    seq = datasets.kitti_sequence("00", 3)
    with bags.BagReader(path) as reader:
        assert reader.topics == {bags.KITTI_POINTS_TOPIC: bags.POINTCLOUD2, bags.GROUND_TRUTH_TOPIC: bags.ODOMETRY,
                                 bags.TF_STATIC_TOPIC: bags.TF_MESSAGE}
        assert reader.counts[bags.KITTI_POINTS_TOPIC] == 3 and reader.counts[bags.TF_STATIC_TOPIC] == 1
        clouds = [reader.decode(m) for m in reader.messages([bags.KITTI_POINTS_TOPIC])]
        for i, msg in enumerate(clouds):
            assert msg.header.frame_id == "velodyne"
            assert abs(convert.stamp_to_sec(msg.header.stamp) - seq.times[i]) < 1e-9
            assert [f.name for f in msg.fields] == ["x", "y", "z", "intensity", "ring"]
            assert [f.datatype for f in msg.fields] == [7, 7, 7, 7, 4]
            points = convert.read_points(msg).reshape(-1)
            raw = seq.points(i)
            for k, name in enumerate(("x", "y", "z", "intensity")):
                np.testing.assert_array_equal(points[name], raw[:, k])
            ring = points["ring"]
            assert ring[0] == 0 and ring.max() == 63 and np.all(np.diff(ring.astype(int)) >= 0)
            # ring 0 is the top beam: elevation falls from ring to ring
            elevation = np.arctan2(raw[:, 2], np.linalg.norm(raw[:, :2], axis=1))
            medians = [np.median(elevation[ring == r]) for r in range(64)]
            assert np.all(np.diff(medians) < 0)
        stamps, poses = bags.read_ground_truth(reader)
        np.testing.assert_allclose(stamps, seq.times, atol=1e-9)
        np.testing.assert_allclose(poses, seq.poses, atol=1e-6)  # LiDAR frame: inv(Tr) P Tr
        (tf,) = [reader.decode(m) for m in reader.messages([bags.TF_STATIC_TOPIC])]
        t = tf.transforms[0]
        assert (t.header.frame_id, t.child_frame_id) == ("velodyne", "camera_0")
        np.testing.assert_allclose([t.transform.translation.x, t.transform.translation.y, t.transform.translation.z],
                                   np.linalg.inv(seq.Tr)[:3, 3], atol=1e-12)


def test_tum_bag_round_trip(tum_bag):
    path, _ = tum_bag
    seq = datasets.tum_sequence(4)
    with bags.BagReader(path) as reader:
        assert reader.topics[bags.TUM_DEPTH_TOPIC] == bags.IMAGE
        assert reader.topics[bags.TUM_INFO_TOPIC] == bags.CAMERA_INFO
        images = [reader.decode(m) for m in reader.messages([bags.TUM_DEPTH_TOPIC])]
        infos = [reader.decode(m) for m in reader.messages([bags.TUM_INFO_TOPIC])]
        assert len(images) == len(infos) == 4
        for i, (img, info) in enumerate(zip(images, infos)):
            assert img.encoding == "16UC1" and (img.height, img.width) == (480, 640)
            depth = convert.image_to_depth(img)
            expected = np.round(seq.depth_raw(i) / 5.0) / 1000.0  # metres*5000 -> millimetres
            np.testing.assert_allclose(depth, expected, atol=1e-6)
            np.testing.assert_allclose(convert.camera_info_to_K(info, depth.shape), seq.K)
            assert img.header.stamp == info.header.stamp
        stamps, poses = bags.read_ground_truth(reader)
        np.testing.assert_allclose(stamps, seq.stamps[seq.pose_valid], atol=1e-6)
        np.testing.assert_allclose(poses, seq.poses[seq.pose_valid], atol=1e-9)


def test_tum_intrinsics_by_name_or_values(tmp_path):
    assert bags.parse_intrinsics("fr2")[1][0, 0] == datasets.TUM_INTRINSICS["fr2"][0]
    name, K = bags.parse_intrinsics("500,501,320.5,240.5")
    assert name == "custom" and K[1, 1] == 501 and K[0, 2] == 320.5
    for bad in ("fr9", "1,2,3", "-5,5,1,1"):
        with pytest.raises(ValueError, match="camera"):
            bags.parse_intrinsics(bad)
    assert bags.tum_camera_from_path(tmp_path / "rgbd_dataset_freiburg3_long_office") == "fr3"
    bags.tum_to_bag(TUM_DIR, tmp_path / "fr3", frames=1, camera="fr3")
    with bags.BagReader(tmp_path / "fr3") as reader:
        (info,) = [reader.decode(m) for m in reader.messages([bags.TUM_INFO_TOPIC])]
        assert info.k[0] == datasets.TUM_INTRINSICS["fr3"][0]


def test_writer_refuses_to_overwrite(tmp_path, kitti_bag):
    path, _ = kitti_bag
    with pytest.raises(FileExistsError, match="exists"):
        bags.kitti_to_bag(KITTI_00, path, frames=1)
    out = tmp_path / "again"
    bags.kitti_to_bag(KITTI_00, out, frames=1)
    bags.kitti_to_bag(KITTI_00, out, frames=2, overwrite=True)
    with bags.BagReader(out) as reader:
        assert reader.counts[bags.KITTI_POINTS_TOPIC] == 2


def _copy_bag(src, dst):
    import shutil

    shutil.copytree(src, dst)
    return dst


def test_truncated_and_corrupt_bags_raise_bag_error(tmp_path, kitti_bag):
    path, storage = kitti_bag
    truncated = _copy_bag(path, tmp_path / "truncated")
    (data,) = [p for p in truncated.iterdir() if p.suffix in (".db3", ".mcap")]
    data.write_bytes(data.read_bytes()[: data.stat().st_size // 2])
    with pytest.raises(bags.BagError, match="corrupt, truncated"):
        with bags.BagReader(truncated) as reader:
            for m in reader.messages():
                reader.decode(m)
    garbage = _copy_bag(path, tmp_path / "garbage")
    (data,) = [p for p in garbage.iterdir() if p.suffix in (".db3", ".mcap")]
    data.write_bytes(b"\x00not a bag\xff" * 100)
    with pytest.raises(bags.BagError, match="garbage.*corrupt"):
        with bags.BagReader(garbage) as reader:
            list(reader.messages())
    no_metadata = _copy_bag(path, tmp_path / "no_metadata")
    (no_metadata / "metadata.yaml").unlink()
    with pytest.raises(bags.BagError, match="no_metadata"):
        bags.BagReader(no_metadata)
    with pytest.raises(bags.BagError, match="no such bag"):
        bags.BagReader(tmp_path / "missing")


def test_kitti_rings_ignore_jitter_at_the_wrap():
    # two rings of 400 points; the second one jitters across azimuth 0 right after it starts
    az = np.concatenate([np.linspace(0.001, 2 * np.pi - 0.001, 400), np.linspace(0.001, 2 * np.pi - 0.001, 400)])
    az[401], az[402] = -0.0005, 0.0004
    pts = np.column_stack([np.cos(az), np.sin(az), np.zeros_like(az)])
    ring = bags.kitti_rings(pts)
    assert ring[:400].max() == 0 and ring[400:].min() == 1 and ring.max() == 1
