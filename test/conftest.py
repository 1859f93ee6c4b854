"""Shared pytest fixtures for line_odom's tests.

ROS 2 tests on a shared machine: `ros_env` gives each pytest process its own DDS domain and keeps
discovery on this host, so concurrent test runs (other checkouts, CI) never see each other's
topics. Subprocesses get the same settings through the returned dict (start them with
sys.executable: the ROS wheels' bootstrapper has already set LD_LIBRARY_PATH for it).
"""
from __future__ import annotations

import os
import shutil
import sys
import tempfile
from pathlib import Path

import pytest

# Markers per test file (registered in setup.cfg [tool:pytest]); pytest_collection_modifyitems below puts them on
# every test of the file. `make test` runs everything; `-m "(unit or engine) and not slow"` is the fast subset.
# A test file not listed here gets no marker and runs only in the full suite: add new files here.
FILE_MARKERS: dict[str, tuple[str, ...]] = {
    # Python alone
    "test_config.py": ("unit",),
    "test_docs.py": ("unit",),
    "test_engine_ros_free.py": ("unit",),
    "test_file_sizes.py": ("unit",),
    "test_markers.py": ("unit",),
    "test_fuzz_convert.py": ("unit",),
    "test_node_launch_files.py": ("unit",),
    "test_settings_table.py": ("unit",),
    "test_static_tf.py": ("unit",),
    # the engine on synthetic inputs
    "test_candidates.py": ("engine",),
    "test_estimate_motion.py": ("engine",),
    "test_point_map.py": ("engine",),
    "test_fuzz_engine.py": ("engine",),
    "test_large_input.py": ("engine",),
    "test_node_processor.py": ("engine",),
    "test_ransac.py": ("engine",),
    "test_solvers.py": ("engine",),
    "test_stubs.py": ("engine",),
    # the engine on simulated drives
    "test_degenerate_scenes.py": ("engine", "slow"),
    "test_deskew.py": ("engine", "slow"),
    "test_odometry_sim.py": ("engine", "slow"),
    "test_sim.py": ("engine", "slow"),
    "test_timing_faults.py": ("engine", "ros", "slow"),
    # the real KITTI / TUM excerpts
    "test_bags.py": ("data",),
    "test_cli.py": ("data",),
    "test_convert.py": ("data",),
    "test_eval.py": ("data",),
    "test_features.py": ("data",),
    "test_input_layout.py": ("data",),
    "test_line_selection.py": ("data",),
    "test_motion_persistence.py": ("data",),
    "test_point_refine.py": ("data",),
    "test_range_image.py": ("data",),
    "test_range_image_downsampled.py": ("data",),
    "test_sensor_fit.py": ("data",),
    "test_threads.py": ("data",),
    "test_window.py": ("data",),
    "test_imu_rotation.py": ("data", "slow"),
    "test_motion_guess.py": ("data", "slow"),
    "test_odometry_kitti.py": ("data", "slow"),
    "test_validation.py": ("data", "slow"),
    "test_odometry_tum.py": ("data", "slow"),
    "test_recovery.py": ("data", "slow"),
    "test_turns.py": ("data", "slow"),
    # DDS, node processes, builds, benchmarks
    "test_node.py": ("ros", "data", "slow"),
    "test_replay.py": ("ros", "data", "slow"),
    "test_ros_runtime.py": ("ros",),
    "test_package_build.py": ("ros", "slow"),
    "test_bench.py": ("data", "slow"),
    "test_batch.py": ("data", "slow"),
    "test_node_hostile.py": ("ros", "slow"),
    "test_node_lifecycle.py": ("ros", "slow"),
    "test_node_scan.py": ("ros", "data", "slow"),
    "test_readers.py": ("data", "slow"),
}

# 1..100: Fast DDS derives UDP ports from the domain id (7400 + 250 * id + ...); ids above ~100 reach
# the ephemeral port range on Linux. The workers of one pytest-xdist session (`make test`) take consecutive ids from
# their controller's process id, so that no two of them share a domain.
XDIST_WORKER = os.environ.get("PYTEST_XDIST_WORKER", "")
if XDIST_WORKER.startswith("gw"):
    ROS_DOMAIN_ID = str(1 + (os.getppid() + int(XDIST_WORKER[2:])) % 100)
else:
    ROS_DOMAIN_ID = str(1 + os.getpid() % 100)


@pytest.fixture
def ros_env(monkeypatch: pytest.MonkeyPatch) -> dict[str, str]:
    """Sets ROS_DOMAIN_ID / ROS_AUTOMATIC_DISCOVERY_RANGE for this process (read by rclpy.init)
    and returns a copy of the environment for subprocesses."""
    monkeypatch.setenv("ROS_DOMAIN_ID", ROS_DOMAIN_ID)
    monkeypatch.setenv("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    monkeypatch.delenv("ROS_LOCALHOST_ONLY", raising=False)
    monkeypatch.delenv("ROS_STATIC_PEERS", raising=False)
    env = dict(os.environ)
    env["PYTHONUNBUFFERED"] = "1"
    env["RCUTILS_LOGGING_BUFFERED_STREAM"] = "0"
    return env


def pytest_configure(config: pytest.Config) -> None:
    # rosidl's parser imports lark, which imports the deprecated sre_* modules: not ours to fix
    config.addinivalue_line("filterwarnings", "ignore:module 'sre_(parse|constants)' is deprecated:DeprecationWarning")


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    for item in items:
        for name in FILE_MARKERS.get(Path(str(item.fspath)).name, ()):
            item.add_marker(getattr(pytest.mark, name))


# The colcon build of test_package_build.py starts as soon as the session knows it runs that file, in the background,
# so that it compiles on one core while other tests run: in a plain session when it has collected, under pytest-xdist
# in the controller when the first worker has collected (a worker that runs the file waits for that build).
COLCON_WS = "line_odom_colcon_ws"  # the workerinput key of the build's workspace
COLCON_WS_PATH = pytest.StashKey[Path]()  # the controller's: the workspace it gives the workers


def in_build_file(test_files: list[str]) -> list[bool]:
    return [Path(f).name == "test_package_build.py" for f in test_files]


def start_colcon_build(config: pytest.Config, test_files: list[str], ws: Path | None = None) -> None:
    in_build = in_build_file(test_files)
    if config.option.collectonly or not any(in_build):
        return
    import test_package_build as package_build

    if not package_build.COLCON.is_file():
        return  # the fixture reports it
    ws = ws or Path(tempfile.mkdtemp(prefix="line_odom_colcon_ws_"))
    config.stash[package_build.COLCON_BUILD] = package_build.ColconBuild(ws, 2 if all(in_build) else 1)


def pytest_collection_finish(session: pytest.Session) -> None:
    files = [str(item.fspath) for item in session.items]
    worker_input = getattr(session.config, "workerinput", None)
    if worker_input is None:
        start_colcon_build(session.config, files)
    elif COLCON_WS in worker_input and any(in_build_file(files)):
        import test_package_build as package_build

        session.config.stash[package_build.COLCON_BUILD] = package_build.ColconBuild.attach(
            Path(worker_input[COLCON_WS]))


@pytest.hookimpl(optionalhook=True)
def pytest_configure_node(node) -> None:
    ws = node.config.stash.get(COLCON_WS_PATH, None)
    if ws is None:
        ws = node.config.stash[COLCON_WS_PATH] = Path(tempfile.mkdtemp(prefix="line_odom_colcon_ws_"))
    node.workerinput[COLCON_WS] = str(ws)


@pytest.hookimpl(optionalhook=True)
def pytest_xdist_node_collection_finished(node, ids: list[str]) -> None:
    import test_package_build as package_build

    if package_build.COLCON_BUILD not in node.config.stash:
        start_colcon_build(node.config, [i.split("::")[0] for i in ids], node.config.stash[COLCON_WS_PATH])


def pytest_sessionfinish(session: pytest.Session) -> None:
    package_build = sys.modules.get("test_package_build")
    build = session.config.stash.get(package_build.COLCON_BUILD, None) if package_build else None
    if build is not None and build.proc is not None:  # the process that started it (a worker only waited for it)
        build.stop()  # a run stopped early (-x, Ctrl-C) leaves no compiler behind
        shutil.rmtree(build.ws, ignore_errors=True)
    ws = session.config.stash.get(COLCON_WS_PATH, None)
    if ws is not None:
        shutil.rmtree(ws, ignore_errors=True)
