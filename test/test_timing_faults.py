"""Timing faults: dropped frames, duplicated stamps, stamps going backwards, a pause of several seconds, bursts
faster than processing, a reset while a frame is being processed.

The frame-level behaviour is tested on the node's processing core (line_odom.processor.OdometryProcessor with the
real engine on simulated street frames with ground truth), where DDS adds nothing; the queueing behaviour (latest
wins, drops counted, bounded memory, a reset service call during processing, a pause in the stream) is tested
through the node in its own process over DDS.
"""
from __future__ import annotations

import threading
import time

import numpy as np
import pytest

from line_odom import convert, sim
from line_odom.processor import OdometryProcessor

OVERRIDES = {"downsample": 6}  # HDL-64E at 1/36
TRANSLATION_BOUND = 0.10  # m per frame (1 m per frame, noise-free simulated street)
ROTATION_BOUND = 0.5  # deg
STAMP0 = 1000.0


@pytest.fixture(scope="module")
def street():
    """40 frames of a simulated street drive (HDL-64E, 10 Hz, ~1 m per frame): (messages by index, poses)."""
    run = sim.make("street", frames=40, seed=0)
    frames = list(run)
    return frames


def msg_of(frame, stamp=None):
    return convert.pointcloud2_from_xyz(frame.data.points, ring=frame.data.ring, frame_id="velodyne",
                                        stamp=STAMP0 + frame.stamp if stamp is None else stamp)


def processor():
    return OdometryProcessor.from_parameters("kitti_hdl64", OVERRIDES)


def rel_error(T_est, T_true):
    E = np.linalg.inv(T_true) @ T_est
    angle = np.degrees(np.arccos(np.clip((np.trace(E[:3, :3]) - 1) / 2, -1, 1)))
    return float(np.linalg.norm(E[:3, 3])), float(angle)


def check_output(out):
    assert out is not None
    assert np.isfinite(out.T_odom_base).all() and np.isfinite(out.pose_covariance).all()
    assert np.isfinite(out.twist).all() and np.isfinite(out.twist_covariance).all()


def run_frames(proc, frames, indices, stamps=None):
    """Process frames[i] for i in indices (optionally with explicit stamps); returns {i: output}."""
    outs = {}
    for n, i in enumerate(indices):
        out = proc.process_pointcloud(msg_of(frames[i], None if stamps is None else stamps[n]))
        check_output(out)
        outs[i] = out
    return outs


def check_motion(outs, frames, a, b):
    """The published motion between processed frames a and b matches the ground truth within the bounds."""
    T_est = np.linalg.inv(outs[a].T_odom_base) @ outs[b].T_odom_base
    T_true = np.linalg.inv(frames[a].pose) @ frames[b].pose
    t, r = rel_error(T_est, T_true)
    assert t < TRANSLATION_BOUND and r < ROTATION_BOUND, (a, b, t, r, outs[b].stats)
    assert not outs[b].stats["degenerate"], outs[b].stats


def test_dropped_frames_are_bridged_by_the_motion_model(street):
    """Frames lost upstream (a gap of 2 and of 3 frames): the stamp difference scales the constant-velocity
    prediction, so the motion across the gap is still found accurately, and the twist is per second."""
    proc = processor()
    order = [0, 1, 2, 3, 6, 7, 11, 12]
    outs = run_frames(proc, street, order)
    for a, b in zip(order, order[1:]):
        check_motion(outs, street, a, b)
    speed = np.linalg.norm(outs[6].twist[:3])
    true_speed = np.linalg.norm(street[6].pose[:3, 3] - street[3].pose[:3, 3]) / 0.3
    assert abs(speed - true_speed) < 0.5, (speed, true_speed)
    assert proc.counters["frames_processed"] == len(order)


def test_duplicated_stamp_is_dropped_counted_and_the_stream_continues(street):
    proc = processor()
    outs = run_frames(proc, street, [0, 1, 2])
    before = dict(proc.counters)
    # the same message again, and a different cloud carrying the previous stamp
    assert proc.process_pointcloud(msg_of(street[2])) is None
    assert proc.process_pointcloud(msg_of(street[3], stamp=STAMP0 + street[2].stamp)) is None
    assert proc.counters["frames_duplicate"] == before["frames_duplicate"] + 2
    assert "repeats the previous frame's stamp" in proc.last_error
    outs.update(run_frames(proc, street, [3, 4]))
    check_motion(outs, street, 2, 3)
    check_motion(outs, street, 3, 4)
    status = proc.diagnostics().status[0]
    assert "2 frame(s) with a repeated stamp" in status.message


def test_stamp_going_backwards_resets_to_the_initial_pose(street):
    """A looping bag: the stamp jumps back; the odometry resets (warning, counter, reason) and restarts at
    initial_pose, then tracks again."""
    proc = OdometryProcessor.from_parameters("kitti_hdl64", {**OVERRIDES, "initial_pose": [5.0, -2.0, 0.0, 0, 0, 0.3]})
    run_frames(proc, street, [0, 1, 2, 3])
    T_init = proc.T_init.copy()
    loop = proc.process_pointcloud(msg_of(street[0], stamp=STAMP0 - 50.0))
    check_output(loop)
    assert loop.reset_reason and "backwards" in loop.reset_reason
    assert proc.counters["resets"] == 1
    np.testing.assert_allclose(loop.T_odom_base, T_init, atol=1e-12)
    np.testing.assert_array_equal(loop.twist, 0)
    outs = {0: loop}
    for i in (1, 2, 3):
        outs[i] = proc.process_pointcloud(msg_of(street[i], stamp=STAMP0 - 50.0 + street[i].stamp))
        check_output(outs[i])
    for a, b in ((0, 1), (1, 2), (2, 3)):
        check_motion(outs, street, a, b)
    # a single backwards frame in the middle of a stream (a stale message): reset once, no NaN
    stale = proc.process_pointcloud(msg_of(street[5], stamp=STAMP0 - 60.0))
    check_output(stale)
    assert proc.counters["resets"] == 2


def test_pause_of_several_seconds_while_standing_still(street):
    """The car stops and the sensor stream pauses for 5 s; when frames resume from the same place the odometry
    must not jump by velocity x 5 s (50 m): finite, a motion near zero or a flagged hold, and tracking within bounds
    again within two frames of driving on."""
    proc = processor()
    outs = run_frames(proc, street, [0, 1, 2, 3, 4])
    pause = 5.0
    resumed = proc.process_pointcloud(msg_of(street[4], stamp=STAMP0 + street[4].stamp + pause))
    check_output(resumed)
    jump = np.linalg.norm(resumed.T_odom_base[:3, 3] - outs[4].T_odom_base[:3, 3])
    if resumed.stats["degenerate"]:
        sigma = np.sqrt(np.diag(resumed.pose_covariance)[:3].max())
        assert jump < 3 * sigma + 1.0, (jump, sigma)  # a hold is only acceptable with an honest covariance
    else:
        assert jump < TRANSLATION_BOUND, (jump, resumed.stats)
    prev_out, prev_i = resumed, 4
    errors = []
    for n, i in enumerate((5, 6, 7, 8)):
        out = proc.process_pointcloud(msg_of(street[i], stamp=STAMP0 + street[i].stamp + pause))
        check_output(out)
        T_est = np.linalg.inv(prev_out.T_odom_base) @ out.T_odom_base
        errors.append(rel_error(T_est, np.linalg.inv(street[prev_i].pose) @ street[i].pose))
        prev_out, prev_i = out, i
    for t, r in errors[2:]:
        assert t < TRANSLATION_BOUND and r < ROTATION_BOUND, errors


def test_reset_from_another_thread_during_processing(street):
    """The reset service runs on the executor thread while the worker registers a frame: it waits for the frame
    (no torn state), the next frame starts at initial_pose, and nothing is NaN."""
    proc = processor()
    run_frames(proc, street, [0, 1])
    started = threading.Event()
    original = proc.engine.register_points

    def slow_register(*args, **kwargs):
        started.set()
        time.sleep(0.5)
        return original(*args, **kwargs)

    proc.engine.register_points = slow_register
    result = {}
    worker = threading.Thread(target=lambda: result.setdefault("out", proc.process_pointcloud(msg_of(street[2]))))
    worker.start()
    assert started.wait(30)
    t0 = time.monotonic()
    proc.reset("~/reset service")  # blocks until the frame in flight is done
    waited = time.monotonic() - t0
    worker.join(30)
    proc.engine.register_points = original
    check_output(result["out"])
    assert waited > 0.2, "reset must wait for the frame being processed"
    after = proc.process_pointcloud(msg_of(street[3]))
    check_output(after)
    np.testing.assert_allclose(after.T_odom_base, proc.T_init, atol=1e-12)
    assert proc.counters["resets"] == 1
    nxt = proc.process_pointcloud(msg_of(street[4]))
    check_motion({3: after, 4: nxt}, street, 3, 4)


# ------------------------------------------------------------------------------------------------ over DDS

def _rss_mb(pid):
    for line in open(f"/proc/{pid}/status"):
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024.0
    return float("nan")


def test_node_burst_pause_backwards_and_reset_during_processing(ros_env, street):
    """Over DDS with the node in its own process: a burst of 30 frames published at 200 Hz (much faster than
    processing) -> the newest frame wins, every frame is either processed or counted as dropped (received =
    processed + dropped), memory stays bounded; a 4 s pause -> the node keeps publishing diagnostics and
    processes the next frame; a stamp going backwards -> reset, still running; ~/reset called while a frame is
    being processed -> success and the next frame at the initial pose."""
    from node_harness import Harness, NodeProcess, pose_matrix, use_large_message_profile
    from sensor_msgs.msg import PointCloud2
    from std_srvs.srv import Trigger

    use_large_message_profile()
    node = NodeProcess(ros_env, {"preset": "kitti_hdl64", "downsample": 6, "diagnostics.period": 0.5,
                                 "qos.reliable": True, "initial_pose": [1.0, 2.0, 0.0, 0.0, 0.0, 0.0]})
    h = Harness(node.namespace)
    try:
        pub = h.publisher(PointCloud2, node.topic("points"), reliable=True, depth=50)
        client = h.node.create_client(Trigger, node.topic("line_odom/reset"))
        h.wait_matched(pub, node, 90)
        rss0 = _rss_mb(node.proc.pid)
        msgs = [msg_of(f) for f in street[:30]]
        for m in msgs:
            pub.publish(m)
            time.sleep(0.005)
        last_ns = convert.stamp_to_ns(msgs[-1].header.stamp)
        h.wait_for(lambda: h.odom_at(last_ns), 120, "the newest frame of the burst", node)

        def settled(values):  # every received frame is processed or counted as dropped (a reliable reader of
            # depth qos.depth may itself lose a few under load: those never reach the node)
            return values and 0 < int(values.get("frames_received", 0)) <= 30 and int(
                values["frames_processed"]) + int(values["frames_dropped"]) == int(values["frames_received"])

        # The newest frame's Odometry is out, so the burst's counters are final; a diagnostics message received
        # before it (or in flight with it) may predate them: skip two periods' worth.
        with h.lock:
            diagnostics_before = len(h.diagnostics)
        values = h.wait_for(lambda: len(h.diagnostics) >= diagnostics_before + 2 and settled(
            h.diagnostics_values()[1]) and h.diagnostics_values()[1], 30, "diagnostics accounting for the burst", node)
        assert int(values["frames_dropped"]) > 0, values  # processing (~0.1-0.3 s/frame) cannot keep up at 200 Hz
        with h.lock:
            n_odom = len(h.odom)
        assert n_odom == int(values["frames_processed"]), (n_odom, values)
        assert _rss_mb(node.proc.pid) - rss0 < 150, "a burst must not queue up frames in memory"

        # a pause: nothing for 4 s; diagnostics keep coming, the node stays alive
        with h.lock:
            n_diag = len(h.diagnostics)
        time.sleep(4.0)
        assert node.proc.poll() is None
        with h.lock:
            assert len(h.diagnostics) >= n_diag + 4
        resume = msg_of(street[30])
        pub.publish(resume)
        h.wait_for(lambda: h.odom_at(convert.stamp_to_ns(resume.header.stamp)), 60, "a frame after the pause", node)

        # stamps going backwards (a looping bag): reset, back at the initial pose
        back = msg_of(street[0], stamp=STAMP0 - 100.0)
        pub.publish(back)
        odom = h.wait_for(lambda: h.odom_at(convert.stamp_to_ns(back.header.stamp)), 60, "the backwards frame", node)
        np.testing.assert_allclose(pose_matrix(odom.pose.pose)[:3, 3], [1.0, 2.0, 0.0], atol=1e-9)

        # ~/reset while a frame is being processed
        h.wait_for(lambda: client.service_is_ready(), 30, "the reset service", node)
        inflight = msg_of(street[1], stamp=STAMP0 - 100.0 + street[1].stamp)
        pub.publish(inflight)
        time.sleep(0.05)
        future = client.call_async(Trigger.Request())
        h.wait_for(lambda: future.done(), 60, "the reset response", node)
        assert future.result().success
        h.wait_for(lambda: h.odom_at(convert.stamp_to_ns(inflight.header.stamp)), 60, "the in-flight frame", node)
        after = msg_of(street[2], stamp=STAMP0 - 100.0 + street[2].stamp)
        pub.publish(after)
        odom = h.wait_for(lambda: h.odom_at(convert.stamp_to_ns(after.header.stamp)), 60, "the frame after reset",
                          node)
        np.testing.assert_allclose(pose_matrix(odom.pose.pose)[:3, 3], [1.0, 2.0, 0.0], atol=1e-9)
        values = h.wait_for(lambda: (v := h.diagnostics_values()[1]) and int(v.get("resets", 0)) >= 2 and v, 30,
                            "resets in diagnostics", node)
        with h.lock:
            for o in h.odom:
                assert np.isfinite(pose_matrix(o.pose.pose)).all() and np.isfinite(o.pose.covariance).all()
    finally:
        h.close()
        try:
            node.stop()
        finally:
            node.kill()
