"""Starting the node: the command line checked before rclpy reads it (a bad parameter file or rule is one line naming
it, exit 2), then spin until Ctrl-C / SIGTERM (exit 0)."""
from __future__ import annotations

import os
import re
import sys
import tempfile

import rclpy
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.impl.implementation_singleton import rclpy_implementation as _rclpy

from line_odom.ros_parameters import ParameterSetupError, one_line

NODE_NAME = "line_odom"
EXIT_BAD_PARAMETER = 2


def _ros_arguments(argv: list[str]) -> list[str]:
    """The arguments between --ros-args and --/the end (every --ros-args section)."""
    out, inside = [], False
    for arg in argv:
        if arg == "--ros-args":
            inside = True
        elif arg == "--" and inside:
            inside = False
        elif inside:
            out.append(arg)
    return out


def check_parameter_files(argv: list[str]) -> None:
    """Each --params-file is a readable YAML mapping; ParameterSetupError naming the file otherwise (rcl's own
    error would name it too, but after a log line of its own and without saying what is wrong in plain words)."""
    args = _ros_arguments(argv)
    for i, arg in enumerate(args):
        if arg != "--params-file":
            continue
        if i + 1 >= len(args):
            raise ParameterSetupError("bad parameter file: --params-file without a file")
        path = args[i + 1]
        if not os.path.isfile(path):
            raise ParameterSetupError(f"bad parameter file: --params-file {path}: no such file")
        try:
            from line_odom_core.config import yaml_load

            with open(path, encoding="utf-8") as f:
                doc = yaml_load(f)
        except Exception as err:  # noqa: BLE001 - I/O, encoding and YAML errors alike: one line
            raise ParameterSetupError(f"bad parameter file: --params-file {path}: not a YAML file ({one_line(err)})") from None
        if not isinstance(doc, dict):
            raise ParameterSetupError(f"bad parameter file: --params-file {path}: expected a ROS 2 parameter file (a mapping "
                                      f"'<node>: ros__parameters: ...'), got {type(doc).__name__}")


def init_rclpy(argv: list[str]) -> None:
    """rclpy.init with rcl's own error log line held back: a bad command line becomes one ParameterSetupError line
    naming the argument (a bad remapping, parameter rule or params file)."""
    saved = os.dup(2)
    with tempfile.TemporaryFile() as captured:
        os.dup2(captured.fileno(), 2)
        try:
            rclpy.init(args=argv)
            error = None
        except _rclpy.RCLError as err:
            error = err
        finally:
            os.dup2(saved, 2)
            os.close(saved)
        if error is None:
            captured.seek(0)
            sys.stderr.buffer.write(captured.read())  # rcl's warnings of a good start stay visible
            sys.stderr.flush()
            return
    text = re.sub(r"^failed to initialize rcl: ", "", str(error))
    text = re.sub(r"(, at /\S+:\d+)+", "", text)
    raise ParameterSetupError(f"bad command line: {one_line(text)}")


def run(node_factory, args=None) -> int:
    """Start, spin; exit 0 on Ctrl-C / SIGTERM, 2 on a bad parameter, parameter file or remapping (one line, no
    traceback)."""
    argv = list(sys.argv if args is None else args)
    node = None
    code = 0
    try:
        check_parameter_files(argv)
        init_rclpy(argv)
        node = node_factory()
        executor = SingleThreadedExecutor()
        executor.add_node(node)
        executor.spin()
    except ParameterSetupError as err:
        text = str(err) if str(err).startswith("bad ") else f"bad parameter: {err}"
        print(f"[FATAL] [{NODE_NAME}]: {text}", file=sys.stderr, flush=True)
        code = EXIT_BAD_PARAMETER
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except _rclpy.RCLError:
        # Ctrl-C / SIGTERM: rclpy's signal handler shuts the context down from another thread, and an executor
        # building its wait set at that moment raises this instead of ExternalShutdownException (ros2/rclpy#398).
        if rclpy.ok():
            raise
    finally:
        if node is not None:
            node.shutdown()
            try:
                node.destroy_node()
            except Exception:  # noqa: BLE001 - the context may already be gone at shutdown
                pass
        if rclpy.ok():
            rclpy.shutdown()
    return code
