"""The node over real DDS under hostile input and operation: oversized and contradicting depth images refused before
conversion with the memory back at its level, parameters read-only at runtime (use_sim_time too) with diagnostics
going on under sim time, a burst of service calls all answered, stamps no clock gives refused in one log line, and
start-up failures as one line with exit code 2."""
from __future__ import annotations

import threading
import time
from pathlib import Path

import numpy as np
import pytest
from rcl_interfaces.msg import Parameter as ParameterMsg
from rcl_interfaces.msg import ParameterType, ParameterValue
from rcl_interfaces.srv import GetParameters, SetParameters
from sensor_msgs.msg import CameraInfo, Image, PointCloud2
from std_srvs.srv import Trigger

from node_harness import NodeProcess, use_large_message_profile
from test_node import (STARTUP_S, kitti_unorganized, ns, publish_and_wait, run_node, send_until_counted,  # noqa: F401
                       wait_diagnostics)
from line_odom import convert
from line_odom.datasets import kitti_sequence, tum_sequence

use_large_message_profile()

RSS_MARGIN_MB = 60.0  # ten refused 18 MB images: keeping even three of them would exceed it


def rss_mb(pid: int) -> float:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024.0
    raise KeyError("VmRSS")


def call_service(h, node, client, request, timeout=30.0):
    assert client.wait_for_service(timeout_sec=STARTUP_S), client.srv_name
    future = client.call_async(request)
    h.wait_for(lambda: future.done(), timeout, client.srv_name, node)
    return future.result()


def test_oversized_and_contradicting_depth_images_are_refused_before_conversion(run_node):
    seq = tum_sequence(frames=2)
    node, h = run_node({"preset": "tum_kinect", "downsample": 10, "diagnostics.period": 0.2, "qos.reliable": True,
                        "qos.depth": 2})
    pub_img = h.publisher(Image, node.topic("depth/image"), reliable=True, depth=2)
    pub_info = h.publisher(CameraInfo, node.topic("depth/camera_info"), reliable=True)
    h.wait_matched(pub_img, node, STARTUP_S)
    h.wait_for(lambda: pub_info.get_subscription_count() > 0, 30, "camera_info subscription", node)
    info = convert.camera_info_from_K(seq.K, 640, 480)
    stamp = float(seq.stamps[0])
    pub_info.publish(info)
    publish_and_wait(h, node, pub_img, convert.depth_to_image(seq.depth(0), stamp=stamp), stamp)

    # an image over max_pixels with its own (matching) CameraInfo: refused from its size alone
    pub_info.publish(convert.camera_info_from_K(seq.K, 3000, 3000))
    time.sleep(0.5)
    big = convert.depth_to_image(np.full((3000, 3000), 2.0), stamp=stamp + 1.0)  # 9 Mpixel, 18 MB: over 4 Mpixel
    send_until_counted(h, node, pub_img, big, "frames_too_large", 1)
    rss0 = rss_mb(node.proc.pid)
    assert rss0 > 50, rss0  # the node's own process
    for k in range(2, 12):
        big.header.stamp = convert.sec_to_stamp(stamp + k)
        send_until_counted(h, node, pub_img, big, "frames_too_large", k)
    time.sleep(0.5)
    grown = rss_mb(node.proc.pid) - rss0
    assert grown < RSS_MARGIN_MB, f"RSS grew {grown:.0f} MB over ten refused images"

    pub_info.publish(info)  # the depth camera's own again
    time.sleep(0.5)
    wrong_size = convert.depth_to_image(np.full((960, 1280), 2.0), stamp=stamp + 20.0)  # 640 x 480 CameraInfo
    send_until_counted(h, node, pub_img, wrong_size, "frames_malformed", 1)
    stamp1 = float(seq.stamps[1])
    publish_and_wait(h, node, pub_img, convert.depth_to_image(seq.depth(1), stamp=stamp1), stamp1)
    values = wait_diagnostics(h, node, lambda v: int(v["frames_processed"]) == 2, "two frames processed")
    assert int(values["frames_too_large"]) >= 11
    log = node.output()
    too_large = [line for line in log.splitlines() if "exceed the max_pixels limit" in line]
    assert len(too_large) == 1, too_large  # logged once, naming the limit
    assert "3000 x 3000 = 9000000 pixels exceed the max_pixels limit of 4000000" in too_large[0]
    assert "CameraInfo is 640 x 480 but the image is 1280 x 960" in log


def _set(h, node, client, name, value: ParameterValue):
    request = SetParameters.Request(parameters=[ParameterMsg(name=name, value=value)])
    return call_service(h, node, client, request).results[0]


def test_parameters_are_read_only_and_diagnostics_go_on_under_sim_time(run_node):
    """use_sim_time with no /clock: the diagnostics keep coming (a steady timer); every parameter, use_sim_time
    included, is refused at runtime naming it, and an undeclared one is refused naming it."""
    node, h = run_node({"preset": "kitti_hdl64", "downsample": 6, "use_sim_time": True, "diagnostics.period": 0.2})
    from rcl_interfaces.srv import ListParameters

    # every client before the first call: the node discovers them while the diagnostics are awaited (a response to a
    # client it has not discovered yet is dropped)
    client = h.node.create_client(SetParameters, node.topic("line_odom/set_parameters"))
    lister = h.node.create_client(ListParameters, node.topic("line_odom/list_parameters"))
    getter = h.node.create_client(GetParameters, node.topic("line_odom/get_parameters"))
    wait_diagnostics(h, node, lambda v: True, "diagnostics under sim time without /clock")
    for name, value in (("use_sim_time", ParameterValue(type=ParameterType.PARAMETER_BOOL, bool_value=False)),
                        ("downsample", ParameterValue(type=ParameterType.PARAMETER_INTEGER, integer_value=3)),
                        ("base_frame", ParameterValue(type=ParameterType.PARAMETER_STRING, string_value="x"))):
        result = _set(h, node, client, name, value)
        assert not result.successful and name in result.reason, (name, result.reason)
    # every parameter the node has, each set to its own value in one request: each refused, naming it
    listed = call_service(h, node, lister, ListParameters.Request()).result.names
    assert {"use_sim_time", "preset", "downsample", "max_pixels", "ransac.inlier_threshold"} <= set(listed)
    values = call_service(h, node, getter, GetParameters.Request(names=listed)).values
    request = SetParameters.Request(parameters=[ParameterMsg(name=n, value=v) for n, v in zip(listed, values)])
    results = call_service(h, node, client, request).results
    assert len(results) == len(listed) > 50
    for name, result in zip(listed, results):  # (rclpy's own start_type_description_service: rclpy's wording)
        assert not result.successful and name in result.reason and "read-only" in result.reason, (name, result.reason)
    result = _set(h, node, client, "no_such.parameter", ParameterValue(type=ParameterType.PARAMETER_INTEGER,
                                                                       integer_value=1))
    assert not result.successful and "'no_such.parameter'" in result.reason, result.reason
    with h.lock:
        before = sum(1 for m in h.diagnostics if m.status and m.status[0].name.startswith(node.namespace))
    time.sleep(1.5)
    with h.lock:
        after = sum(1 for m in h.diagnostics if m.status and m.status[0].name.startswith(node.namespace))
    assert after - before >= 3, (before, after)  # still publishing, still under sim time (the refused change)


def _reset_burst(h, node, clients):
    futures = [c.call_async(Trigger.Request()) for c in clients]
    h.wait_for(lambda: all(f.done() for f in futures), 60, "all 20 reset responses", node)
    assert all(f.result().success for f in futures)


def _parameter_burst(h, node, clients):
    futures = [c.call_async(GetParameters.Request(names=["downsample"])) for c in clients]
    h.wait_for(lambda: all(f.done() for f in futures), 60, "all 20 get_parameters responses", node)
    assert [f.result().values[0].integer_value for f in futures] == [6] * len(clients)


def test_twenty_concurrent_reset_calls_are_all_answered_idle_and_while_frames_flow(run_node):
    """~/reset: 20 callers at once all get their answer, idle and while frames flow; the parameter services too. Each
    caller's response queue holds the burst: with Fast DDS every client of a service receives every response and keeps
    its QoS depth of them (NODE.md, "Lifecycle"), so with the default depth of 10 a caller can lose its own answer
    among 20 (the node answered all 20 resets within 5 ms, and one caller timed out)."""
    from rclpy.qos import QoSProfile, ReliabilityPolicy

    seq = kitti_sequence("07", 4)
    node, h = run_node({"preset": "kitti_hdl64", "downsample": 6, "diagnostics.period": 0.2})
    pub = h.publisher(PointCloud2, node.topic("points"))
    burst_qos = QoSProfile(depth=20, reliability=ReliabilityPolicy.RELIABLE)
    clients = [h.node.create_client(Trigger, node.topic("line_odom/reset"), qos_profile=burst_qos) for _ in range(20)]
    getters = [h.node.create_client(GetParameters, node.topic("line_odom/get_parameters"), qos_profile=burst_qos)
               for _ in range(20)]
    h.wait_matched(pub, node, STARTUP_S)
    for c in clients + getters:
        assert c.wait_for_service(timeout_sec=STARTUP_S)
    _reset_burst(h, node, clients)  # idle
    _parameter_burst(h, node, getters)
    msgs = [kitti_unorganized(seq, i, 50.0 + 0.1 * i) for i in range(4)]
    flowing = {"run": True, "k": 0}

    def stream():  # 10 Hz, stamps increasing
        while flowing["run"]:
            k = flowing["k"]
            msg = msgs[k % 4]
            msg.header.stamp = convert.sec_to_stamp(50.0 + 0.1 * k)
            pub.publish(msg)
            flowing["k"] += 1
            time.sleep(0.1)

    thread = threading.Thread(target=stream, daemon=True)
    thread.start()
    try:
        h.wait_for(lambda: len(h.odom) >= 2, 60, "frames flowing", node)
        _reset_burst(h, node, clients)
        _parameter_burst(h, node, getters)
        _reset_burst(h, node, clients)
        _parameter_burst(h, node, getters)
    finally:
        flowing["run"] = False
        thread.join()
    values = wait_diagnostics(h, node, lambda v: int(v["resets"]) >= 60, "60 resets counted")
    assert int(values["resets"]) == 60


@pytest.mark.parametrize("sec, nanosec, field", [(-3, 0, "header.stamp.sec"),
                                                 (70, 1_500_000_000, "header.stamp.nanosec")])
def test_stamps_no_clock_gives_are_refused_in_one_log_line(run_node, sec, nanosec, field):
    seq = kitti_sequence("07", 1)
    node, h = run_node({"preset": "kitti_hdl64", "downsample": 6, "diagnostics.period": 0.2, "qos.reliable": True,
                        "qos.depth": 100})
    pub = h.publisher(PointCloud2, node.topic("points"), reliable=True, depth=100)
    h.wait_matched(pub, node, STARTUP_S)
    bad = kitti_unorganized(seq, 0, 1.0)
    bad.header.stamp.sec, bad.header.stamp.nanosec = sec, nanosec
    for _ in range(60):
        pub.publish(bad)
    values = wait_diagnostics(h, node, lambda v: int(v["frames_malformed"]) + int(v["frames_dropped"]) == 60,
                              "60 frames refused or dropped")
    assert int(values["frames_processed"]) == 0 and int(values["frames_malformed"]) >= 1
    good = 71.0
    publish_and_wait(h, node, pub, kitti_unorganized(seq, 0, good), good)
    lines = [line for line in node.output().splitlines() if field in line]
    assert len(lines) == 1, lines  # one line, no traceback (stop() asserts there is none)


# ------------------------------------------------------------------------------------------------ start-up

def _startup_cases(tmp: Path):
    syntax = tmp / "syntax.yaml"
    syntax.write_text("line_odom:\n  ros__parameters:\n    downsample: [1, 2\n")
    garbage = tmp / "garbage.yaml"
    garbage.write_text("{{{ this is : not yaml ::: ]]\n")
    binary = tmp / "binary.yaml"
    binary.write_bytes(bytes(range(256)) * 4)
    a_list = tmp / "list.yaml"
    a_list.write_text("- 1\n- 2\n")
    missing = tmp / "missing.yaml"
    return [
        ({"preset": str(syntax)}, [], str(syntax)),
        ({}, ["--params-file", str(garbage)], str(garbage)),
        ({}, ["--params-file", str(binary)], str(binary)),
        ({}, ["--params-file", str(a_list)], str(a_list)),
        ({}, ["--params-file", str(missing)], str(missing)),
        ({}, ["-r", "points"], "points"),
        ({}, ["-p", "downsample"], "downsample"),
    ]


@pytest.mark.parametrize("case", range(7))
def test_startup_failures_are_one_line_and_exit_2(ros_env, tmp_path, case):
    params, extra, named = _startup_cases(tmp_path)[case]
    node = NodeProcess(ros_env, params, extra_args=extra)
    try:
        code = node.wait_exit(STARTUP_S)
    finally:
        node.kill()
    out = node.output()
    lines = [line for line in out.splitlines() if line.strip()]
    assert code == 2, out
    assert len(lines) == 1 and "Traceback" not in out and named in lines[0], out


BIG_CLOUD_PUBLISHER = """
import sys, time
import numpy as np
import rclpy
from rclpy.qos import qos_profile_sensor_data
from sensor_msgs.msg import PointCloud2
from line_odom import convert

rclpy.init()
node = rclpy.create_node("big_cloud_publisher")
pub = node.create_publisher(PointCloud2, sys.argv[1], qos_profile_sensor_data)
deadline = time.monotonic() + 60
while pub.get_subscription_count() == 0 and time.monotonic() < deadline:
    time.sleep(0.1)
time.sleep(1.0)
msg = convert.pointcloud2_from_xyz(np.zeros((2_000_000, 3), np.float32), frame_id="velodyne", stamp=5.0)
for k in range(12):
    msg.header.stamp = convert.sec_to_stamp(5.0 + 0.1 * k)
    pub.publish(msg)
    time.sleep(0.3)
print("published", flush=True)
"""


def test_clouds_lost_in_transport_are_counted(run_node, ros_env):
    """24 MB clouds over best effort between two processes with Fast DDS's defaults (no large-message profile): DDS
    drops them on the way and reports it; the node counts what it reports (frames_lost_in_transport), logs it once
    and goes WARN, where before such a cloud was counted nowhere."""
    import subprocess
    import sys

    from node_harness import with_profile

    node, h = run_node({"preset": "kitti_hdl64", "downsample": 6, "diagnostics.period": 0.2},
                       large_message_profile=False)
    wait_diagnostics(h, node, lambda v: True, "the node up")
    proc = subprocess.run([sys.executable, "-c", BIG_CLOUD_PUBLISHER, node.topic("points")],
                          env=with_profile(ros_env, False), capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0 and "published" in proc.stdout, proc.stdout + proc.stderr
    values = wait_diagnostics(h, node, lambda v: int(v["frames_lost_in_transport"]) >= 1, "a lost cloud counted")
    assert int(values["frames_lost_in_transport"]) + int(values["frames_received"]) <= 12
    lines = [line for line in node.output().splitlines() if "before they reached the node" in line]
    assert len(lines) == 1 and node.topic("points") in lines[0], lines
