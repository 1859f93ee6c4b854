"""Over real DDS: the managed node driven through the lifecycle_msgs services (inactive: no subscription, no
publisher; activate: a fresh odometry), and rviz's initial pose (geometry_msgs/PoseWithCovarianceStamped on
initialpose) restarting the trajectory at a pose in odom_frame, a pose in another frame refused."""
from __future__ import annotations

import time

import numpy as np
from geometry_msgs.msg import PoseWithCovarianceStamped
from lifecycle_msgs.msg import State, Transition
from lifecycle_msgs.srv import ChangeState, GetState
from sensor_msgs.msg import PointCloud2

from node_harness import pose_matrix, use_large_message_profile
from test_node import (STARTUP_S, kitti_unorganized, publish_and_wait, run_node,  # noqa: F401
                       send_until_counted, wait_diagnostics)
from line_odom import frames
from line_odom.datasets import kitti_sequence

use_large_message_profile()


# rmw_fastrtps drops the response to a client whose response reader the server has not discovered yet (it waits
# 100 ms for it: "failed to send response (timeout)"), which a loaded machine reaches right after start-up. A caller
# asks again, as a lifecycle manager retries; a transition already taken is read back with get_state instead.
ANSWER_S = 10.0


def _get_state(h, node, get) -> int:
    """The node's lifecycle state (get_state is idempotent: asked again when an answer is lost)."""
    assert get.wait_for_service(timeout_sec=STARTUP_S), get.srv_name
    deadline = time.monotonic() + 60
    while True:
        future = get.call_async(GetState.Request())
        try:
            h.wait_for(lambda: future.done(), ANSWER_S, get.srv_name, node)
            return future.result().current_state.id
        except AssertionError:
            if time.monotonic() > deadline:
                raise


def _change_state(h, node, change, get, tid, goal=None) -> bool:
    """ChangeState `tid`; its success. When the answer is lost: taken if get_state says the node is in `goal` (a
    transition is not repeated), else asked again (a failed one changes no state)."""
    assert change.wait_for_service(timeout_sec=STARTUP_S), change.srv_name
    for _ in range(3):
        future = change.call_async(ChangeState.Request(transition=Transition(id=tid)))
        try:
            h.wait_for(lambda: future.done(), ANSWER_S, change.srv_name, node)
            return future.result().success
        except AssertionError:
            if goal is not None and _get_state(h, node, get) == goal:
                return True
    raise AssertionError(f"no answer to {change.srv_name} ({tid}) in 3 tries\n{node.output()[-4000:]}")


def _graph(h, node):
    """The node's own publishers and subscriptions (topic names), as the ROS graph shows them."""
    name, namespace = "line_odom", node.namespace
    pubs = {t for t, _ in h.node.get_publisher_names_and_types_by_node(name, namespace)}
    subs = {t for t, _ in h.node.get_subscriber_names_and_types_by_node(name, namespace)}
    return pubs, subs


def test_lifecycle_transitions_over_the_lifecycle_services(run_node):
    seq = kitti_sequence("07", 4)
    node, h = run_node({"preset": "kitti_hdl64", "downsample": 6, "diagnostics.period": 0.2},
                       module="line_odom.lifecycle_node")
    change = h.node.create_client(ChangeState, node.topic("line_odom/change_state"))
    get = h.node.create_client(GetState, node.topic("line_odom/get_state"))
    pub = h.publisher(PointCloud2, node.topic("points"))
    # what rcl gives every (managed) node, active or not: its log, parameter events and lifecycle transition events
    own = {"/rosout", "/parameter_events", node.topic("line_odom/transition_event")}

    def state():
        return _get_state(h, node, get)

    goals = {Transition.TRANSITION_CONFIGURE: State.PRIMARY_STATE_INACTIVE,
             Transition.TRANSITION_ACTIVATE: State.PRIMARY_STATE_ACTIVE,
             Transition.TRANSITION_DEACTIVATE: State.PRIMARY_STATE_INACTIVE,
             Transition.TRANSITION_CLEANUP: State.PRIMARY_STATE_UNCONFIGURED,
             Transition.TRANSITION_INACTIVE_SHUTDOWN: State.PRIMARY_STATE_FINALIZED}

    def transition(tid):
        assert _change_state(h, node, change, get, tid, goals[tid]), tid

    def quiet(what):  # neither subscribed to the input (nor anything else) nor publishing anything of its own
        time.sleep(1.0)
        assert pub.get_subscription_count() == 0, what
        pubs, subs = _graph(h, node)
        assert pubs <= own and subs <= {"/parameter_events"}, (what, pubs, subs)
        with h.lock:
            assert not [m for m in h.diagnostics if m.status and m.status[0].name.startswith(node.namespace)], what

    assert state() == State.PRIMARY_STATE_UNCONFIGURED
    quiet("unconfigured")
    transition(Transition.TRANSITION_CONFIGURE)
    assert state() == State.PRIMARY_STATE_INACTIVE
    quiet("inactive after configure")
    transition(Transition.TRANSITION_ACTIVATE)
    assert state() == State.PRIMARY_STATE_ACTIVE
    h.wait_matched(pub, node, STARTUP_S)
    pubs, subs = _graph(h, node)  # what quiet() checks is gone is there while active
    assert {node.topic("odom"), node.topic("path"), "/tf", "/diagnostics", node.topic("line_odom/scan"),
            node.topic("line_odom/lines")} <= pubs, pubs
    assert {node.topic("points"), node.topic("initialpose")} <= subs, subs
    stamps = [40.0 + float(t) for t in seq.times]
    for i in (0, 1, 2):
        last = publish_and_wait(h, node, pub, kitti_unorganized(seq, i, stamps[i]), stamps[i])
    assert np.linalg.norm(pose_matrix(last.pose.pose)[:3, 3]) > 0.1
    wait_diagnostics(h, node, lambda v: int(v["frames_processed"]) == 3, "three frames while active")

    transition(Transition.TRANSITION_DEACTIVATE)
    assert state() == State.PRIMARY_STATE_INACTIVE
    h.wait_for(lambda: pub.get_subscription_count() == 0, 30, "the input unsubscribed", node)
    with h.lock:
        h.diagnostics.clear()
    quiet("inactive after deactivate")
    pub.publish(kitti_unorganized(seq, 3, stamps[3]))  # not taken by an inactive node

    transition(Transition.TRANSITION_ACTIVATE)  # fresh: the next frame is at initial_pose again
    h.wait_matched(pub, node, STARTUP_S)
    odom = publish_and_wait(h, node, pub, kitti_unorganized(seq, 3, stamps[3] + 1.0), stamps[3] + 1.0)
    np.testing.assert_allclose(pose_matrix(odom.pose.pose), np.eye(4), atol=1e-9)
    values = wait_diagnostics(h, node, lambda v: int(v["frames_processed"]) == 1, "counters fresh")
    assert int(values["frames_received"]) == 1

    transition(Transition.TRANSITION_DEACTIVATE)
    transition(Transition.TRANSITION_CLEANUP)
    assert state() == State.PRIMARY_STATE_UNCONFIGURED
    transition(Transition.TRANSITION_CONFIGURE)  # configured again from the same parameters
    transition(Transition.TRANSITION_INACTIVE_SHUTDOWN)
    assert state() == State.PRIMARY_STATE_FINALIZED
    assert "Traceback" not in node.output()


def test_lifecycle_configure_with_a_bad_parameter_fails_naming_it(run_node):
    node, h = run_node({"preset": "kitti_hdl64", "downsample": 0}, module="line_odom.lifecycle_node")
    change = h.node.create_client(ChangeState, node.topic("line_odom/change_state"))
    get = h.node.create_client(GetState, node.topic("line_odom/get_state"))
    assert _get_state(h, node, get) == State.PRIMARY_STATE_UNCONFIGURED
    assert not _change_state(h, node, change, get, Transition.TRANSITION_CONFIGURE)
    assert _get_state(h, node, get) == State.PRIMARY_STATE_UNCONFIGURED
    h.wait_for(lambda: "configure failed: bad parameter" in node.output() and "downsample" in node.output(), 10,
               "the configure failure logged", node)


def _pose_msg(frame_id, xyz, rpy):
    T = frames.pose_from_params([*xyz, *rpy], "pose")
    msg = PoseWithCovarianceStamped()
    msg.header.frame_id = frame_id
    p, q = msg.pose.pose.position, msg.pose.pose.orientation
    p.x, p.y, p.z = xyz
    q.x, q.y, q.z, q.w = (float(v) for v in frames.quaternion_xyzw(T[:3, :3]))
    return msg, T


def test_initialpose_restarts_the_trajectory_there_and_other_frames_are_refused(run_node):
    seq = kitti_sequence("07", 5)
    node, h = run_node({"preset": "kitti_hdl64", "downsample": 6, "diagnostics.period": 0.2})
    pub = h.publisher(PointCloud2, node.topic("points"))
    pose_pub = h.publisher(PoseWithCovarianceStamped, node.topic("initialpose"), reliable=True)
    h.wait_matched(pub, node, STARTUP_S)
    h.wait_for(lambda: pose_pub.get_subscription_count() > 0, 30, "the initialpose subscription", node)
    stamps = [60.0 + float(t) for t in seq.times]
    for i in (0, 1):
        publish_and_wait(h, node, pub, kitti_unorganized(seq, i, stamps[i]), stamps[i])

    in_map, _ = _pose_msg("map", (5.0, 0.0, 0.0), (0.0, 0.0, 0.0))
    send_until_counted(h, node, pose_pub, in_map, "initial_poses_rejected", 1)
    assert "expected odom_frame 'odom' (the base's pose in it), got 'map'" in node.output()
    odom = publish_and_wait(h, node, pub, kitti_unorganized(seq, 2, stamps[2]), stamps[2])
    assert np.linalg.norm(pose_matrix(odom.pose.pose)[:3, 3] - [5.0, 0.0, 0.0]) > 1.0  # not moved there

    msg, T = _pose_msg("odom", (10.0, -4.0, 0.5), (0.0, 0.0, 1.2))
    pose_pub.publish(msg)
    wait_diagnostics(h, node, lambda v: int(v["resets"]) == 1, "the initial pose taken")
    first = publish_and_wait(h, node, pub, kitti_unorganized(seq, 3, stamps[3]), stamps[3])
    np.testing.assert_allclose(pose_matrix(first.pose.pose), T, atol=1e-9)
    second = publish_and_wait(h, node, pub, kitti_unorganized(seq, 4, stamps[4]), stamps[4])
    # tracking goes on from there: the engine's own motion from frame 3 to 4 (a fresh engine, as after the reset;
    # it is deterministic), composed onto the given pose
    import line_odom_core
    from line_odom import convert

    engine = line_odom_core.Odometry(line_odom_core.load_config("kitti_hdl64", {"downsample": 6}))
    sensor = []
    for i in (3, 4):
        cloud = convert.pointcloud2_to_arrays(kitti_unorganized(seq, i, stamps[i]))
        sensor.append(engine.register_points(cloud.xyz, convert.stamp_to_ns(convert.sec_to_stamp(stamps[i])) * 1e-9,
                                             ring=cloud.ring).pose)
    np.testing.assert_allclose(pose_matrix(second.pose.pose), T @ np.linalg.inv(sensor[0]) @ sensor[1], atol=1e-6)
