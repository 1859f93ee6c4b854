"""The managed (lifecycle) variant of the node: ``ros2 run line_odom lifecycle_node`` (or
``python -m line_odom.lifecycle_node``), driven through the lifecycle_msgs services (``~/change_state``,
``~/get_state``, ...) as ``ros2 lifecycle set`` and Nav2's lifecycle manager do.

- configure: declares and checks the parameters (a bad one fails the transition, naming it) and the engine settings;
- activate: a fresh odometry (the next frame starts at initial_pose) with its subscriptions, publishers, ``~/reset``
  service and diagnostics;
- deactivate / cleanup / shutdown: all of those are destroyed: an inactive node subscribes to nothing and publishes
  nothing.
"""
from __future__ import annotations

import sys

from rclpy.lifecycle import LifecycleNode, LifecycleState, TransitionCallbackReturn

from line_odom.node import NODE_NAME, OdometryNodeBase, ParameterSetupError, run


class LifecycleLineOdomNode(OdometryNodeBase, LifecycleNode):
    def __init__(self, **kwargs):
        LifecycleNode.__init__(self, NODE_NAME, **kwargs)
        self.get_logger().info("line_odom (managed) unconfigured: waiting for the configure transition")

    def on_configure(self, state: LifecycleState) -> TransitionCallbackReturn:
        try:
            self.declare_and_load()
            self.make_processor()  # the engine checks its settings here, not at activate
        except ParameterSetupError as err:
            self.get_logger().error(f"configure failed: bad parameter: {err}")
            return TransitionCallbackReturn.FAILURE
        self.log_parameters()
        return TransitionCallbackReturn.SUCCESS

    def on_activate(self, state: LifecycleState) -> TransitionCallbackReturn:
        self.processor = self.make_processor()
        self.log_ready(self.start_odometry())
        return TransitionCallbackReturn.SUCCESS

    def on_deactivate(self, state: LifecycleState) -> TransitionCallbackReturn:
        self.stop_odometry()
        self.get_logger().info("line_odom inactive: no subscription, no publisher")
        return TransitionCallbackReturn.SUCCESS

    def on_cleanup(self, state: LifecycleState) -> TransitionCallbackReturn:
        self.stop_odometry()
        self.processor = None
        return TransitionCallbackReturn.SUCCESS

    def on_shutdown(self, state: LifecycleState) -> TransitionCallbackReturn:
        self.stop_odometry()
        self.processor = None
        return TransitionCallbackReturn.SUCCESS

    def on_error(self, state: LifecycleState) -> TransitionCallbackReturn:
        self.stop_odometry()
        return TransitionCallbackReturn.SUCCESS

    def shutdown(self) -> None:
        self.stop_odometry()


def main(args=None) -> int:
    """Console script ``lifecycle_node``."""
    return run(LifecycleLineOdomNode, args)


if __name__ == "__main__":
    sys.exit(main())
