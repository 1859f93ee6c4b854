"""line_odom is a real ROS 2 package: a copy of it builds with colcon (C++ engine included) into a
fresh workspace, and `ros2 run line_odom node` - resolved the way ros2run resolves it - starts the node,
which shuts down cleanly on SIGINT (Ctrl-C).

The `ros2` CLI itself is not available as a wheel, so the test does what `ros2 run` does: package
prefix from the ament index, then the one executable named `node` under <prefix>/lib/line_odom.
"""
from __future__ import annotations

import os
import re
import shutil
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
PACKAGE = "line_odom"
BUILD_TIMEOUT_S = 1200
COLCON = Path(sys.executable).parent / "colcon"  # installed into the environment by `make setup`
# outside a git checkout: the tree minus the artefacts of a development set-up
NOT_SOURCE = shutil.ignore_patterns(".git", ".venv", "build", "install", "log", "__pycache__", "*.so", "*.o",
                                    "*.egg-info", ".pytest_cache", ".hypothesis", "out", "_deps", "demo_out")
# rclpy's console log line: [INFO] [1700000000.123456789] [logger.name]: message
ROS_LOG_LINE = re.compile(r"^\[(DEBUG|INFO|WARN|ERROR|FATAL)\] \[\d+\.\d+\] \[([^\]]+)\]: ")


class Workspace:
    def __init__(self, root: Path, env: dict[str, str], build_log: str):
        self.root, self.env, self.build_log = root, env, build_log

    def run_python(self, code: str) -> str:
        proc = subprocess.run([sys.executable, "-c", code], env=self.env, cwd=self.root,
                              capture_output=True, text=True, timeout=60)
        assert proc.returncode == 0, proc.stderr
        return proc.stdout.strip()


def copy_package_source(dest: Path) -> None:
    """The checkout's source files: in a git checkout, tracked plus untracked-but-not-ignored files
    (what the next commit could hold); otherwise the tree minus development artefacts."""
    listing = subprocess.run(["git", "ls-files", "-z", "--cached", "--others", "--exclude-standard"],
                             cwd=REPO, capture_output=True) if shutil.which("git") else None
    if listing is None or listing.returncode != 0:
        shutil.copytree(REPO, dest, ignore=NOT_SOURCE)
        return
    for rel in filter(None, listing.stdout.decode().split("\0")):
        src = REPO / rel
        if src.is_file():  # deleted-but-tracked files are listed too
            (dest / rel).parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(src, dest / rel)


def sourced_environment(setup_sh: Path, base_env: dict[str, str]) -> dict[str, str]:
    """The environment after `. install/setup.sh` (what a user does before `ros2 run`)."""
    proc = subprocess.run(["sh", "-c", '. "$0" && env -0', str(setup_sh)], env=base_env,
                          capture_output=True, timeout=60)
    assert proc.returncode == 0, proc.stderr.decode()
    return dict(item.split("=", 1) for item in proc.stdout.decode().split("\0") if "=" in item)


class ColconBuild:
    """`colcon build` of a copy of the checkout in a fresh workspace, running in the background: conftest.py starts it
    when the session collects this file, so the engine compiles on one core while the other tests run (the build is
    the suite's longest step); the workspace fixture waits for it. Its exit code is written beside its log, so that
    another process of the session (a pytest-xdist worker) can wait for it too (`attach`)."""

    def __init__(self, ws: Path, compile_jobs: int = 2, started_elsewhere: bool = False):
        self.ws = ws
        self.env = dict(os.environ)
        self.env["COLCON_HOME"] = str(ws / ".colcon")  # no user defaults / mixins
        self.env.pop("AMENT_PREFIX_PATH", None)
        self.env.pop("COLCON_PREFIX_PATH", None)
        self.log_path, self.exit_path = ws / "colcon_build.log", ws / "colcon_build.exit"
        self.start = time.monotonic()
        self.proc = None
        if started_elsewhere:
            return
        copy_package_source(ws / "src" / PACKAGE)
        build_env = dict(self.env, LINE_ODOM_BUILD_JOBS=str(compile_jobs))
        with open(self.log_path, "w") as log:
            self.proc = subprocess.Popen([str(COLCON), "build", "--base-paths", "src", "--event-handlers",
                                          "console_direct+"],
                                         cwd=ws, env=build_env, stdout=log, stderr=subprocess.STDOUT,
                                         stdin=subprocess.DEVNULL, start_new_session=True)
        threading.Thread(target=self._record_exit, daemon=True).start()

    def _record_exit(self) -> None:
        code = self.proc.wait()
        tmp = self.exit_path.with_suffix(".tmp")
        tmp.write_text(str(code))
        tmp.replace(self.exit_path)

    @classmethod
    def attach(cls, ws: Path) -> "ColconBuild":
        """The build another process of this session started (or is about to start) in `ws`."""
        return cls(ws, started_elsewhere=True)

    def finish(self) -> tuple[int, str]:
        """The build's exit code and output, waiting for it up to BUILD_TIMEOUT_S from its start (from now, for an
        attached build)."""
        deadline = self.start + BUILD_TIMEOUT_S
        if self.proc is not None:
            try:
                code = self.proc.wait(timeout=max(1.0, deadline - time.monotonic()))
            except subprocess.TimeoutExpired:
                self.stop()
                code = -1
        else:
            while not self.exit_path.is_file() and time.monotonic() < deadline:
                time.sleep(0.5)
            code = int(self.exit_path.read_text()) if self.exit_path.is_file() else -1
        log = self.log_path.read_text() if self.log_path.is_file() else "(no build log: the build never started)"
        return code, log

    def stop(self) -> None:
        if self.proc is not None and self.proc.poll() is None:
            os.killpg(self.proc.pid, signal.SIGKILL)
            self.proc.wait()


COLCON_BUILD = pytest.StashKey[ColconBuild]()


@pytest.fixture(scope="module")
def workspace(request: pytest.FixtureRequest, tmp_path_factory: pytest.TempPathFactory) -> Workspace:
    assert COLCON.is_file(), "colcon is not installed in this environment: run `make setup`"
    build = request.config.stash.get(COLCON_BUILD, None) or ColconBuild(tmp_path_factory.mktemp("colcon_ws"))
    code, log = build.finish()
    assert code == 0, f"colcon build failed (exit {code}) after {time.monotonic() - build.start:.0f} s:\n{log[-6000:]}"
    assert re.search(rf"^Finished <<< {PACKAGE} ", log, re.MULTILINE), log[-3000:]
    ws, env = build.ws, build.env

    install = ws / "install"
    run_env = sourced_environment(install / "setup.sh", env)
    # The package prefix must be on AMENT_PREFIX_PATH (colcon's hook puts it there when present; make sure),
    # with this Python environment's ROS as the underlay, as /opt/ros/jazzy would be on a ROS machine.
    ament = [p for p in run_env.get("AMENT_PREFIX_PATH", "").split(os.pathsep) if p]
    prefix = str(install / PACKAGE)
    ament = [prefix] + [p for p in ament if p != prefix] + [sys.prefix]
    run_env["AMENT_PREFIX_PATH"] = os.pathsep.join(ament)
    run_env["PYTHONUNBUFFERED"] = "1"
    run_env["RCUTILS_LOGGING_BUFFERED_STREAM"] = "0"
    return Workspace(ws, run_env, log)


def ros2_run_executable(ws: Workspace, package: str, executable: str) -> Path:
    """ros2run.api.get_executable_path: <package prefix from the ament index>/lib/<package>/, walked for
    executable files (dot-directories skipped), exactly one named `executable`."""
    prefix = Path(ws.run_python(
        f"from ament_index_python.packages import get_package_prefix; print(get_package_prefix({package!r}))"))
    matches = []
    for dirpath, dirnames, filenames in os.walk(prefix / "lib" / package):
        dirnames[:] = sorted(d for d in dirnames if not d.startswith("."))
        for name in sorted(filenames):
            path = Path(dirpath) / name
            if name == executable and os.access(path, os.X_OK):
                matches.append(path)
    assert len(matches) == 1, f"ros2 run would not find exactly one {package}/{executable}: {matches}"
    return matches[0]


def test_colcon_build_installs_package_and_engine(workspace: Workspace):
    install_prefix = workspace.root / "install" / PACKAGE
    assert (install_prefix / "share/ament_index/resource_index/packages" / PACKAGE).is_file()
    assert (install_prefix / "share" / PACKAGE / "package.xml").is_file()
    # the installed copy (with its colcon-built extension) is what the workspace environment imports
    files = workspace.run_python(
        "import line_odom, line_odom_core, line_odom_core._core as c; "
        "print(line_odom.__file__); print(c.__file__); print(line_odom_core.build_info()['compiler'])").splitlines()
    assert all(Path(f).resolve().is_relative_to(install_prefix.resolve()) for f in files[:2]), files
    assert files[2]


@pytest.mark.parametrize("executable", ["node", "lifecycle_node"])
def test_ros2_run_node_starts_and_exits_cleanly_on_sigint(workspace: Workspace, ros_env: dict[str, str],
                                                          executable: str):
    exe = ros2_run_executable(workspace, PACKAGE, executable)
    assert exe.parent == workspace.root / "install" / PACKAGE / "lib" / PACKAGE

    env = dict(workspace.env)
    env.update({k: ros_env[k] for k in ("ROS_DOMAIN_ID", "ROS_AUTOMATIC_DISCOVERY_RANGE")})
    node = subprocess.Popen([str(exe)], env=env, cwd=workspace.root, stdin=subprocess.DEVNULL,
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    lines: list[str] = []
    started = threading.Event()

    def read_output():
        for line in node.stdout:
            lines.append(line)
            if ROS_LOG_LINE.match(line):
                started.set()

    reader = threading.Thread(target=read_output, daemon=True)
    reader.start()
    try:
        started.wait(timeout=60)
        assert started.is_set(), f"no ROS log line from the node within 60 s (exit {node.poll()}):\n{''.join(lines)}"
        time.sleep(1.0)
        assert node.poll() is None, f"the node exited by itself (code {node.returncode}):\n{''.join(lines)}"
        node.send_signal(signal.SIGINT)
        code = node.wait(timeout=30)
    finally:
        if node.poll() is None:
            node.kill()
            node.wait()
    reader.join(timeout=10)
    output = "".join(lines)
    assert code == 0, f"exit code {code} after SIGINT:\n{output}"
    assert "Traceback" not in output, output
    assert not re.search(r"^\[(ERROR|FATAL)\]", output, re.MULTILINE), output


def test_a_changed_header_recompiles_every_engine_object(tmp_path):
    """setup.py's needs_recompile (build_support.py): pybind11's naive_recompile compares an object with its .cpp
    only, so after a header change the objects of untouched .cpp files were linked stale beside new ones (seen: a
    segfault after switching commits with a changed struct). An object is rebuilt when its .cpp or any engine header
    is newer; otherwise kept."""
    sys.path.insert(0, str(REPO))
    try:
        from build_support import HeaderAwareRecompile
    finally:
        sys.path.remove(str(REPO))
    src, header, other_header, obj = (tmp_path / n for n in ("a.cpp", "types.hpp", "ransac.hpp", "a.o"))
    for path, mtime in ((src, 100), (header, 100), (other_header, 100), (obj, 200)):
        path.write_text("x")
        os.utime(path, (mtime, mtime))
    needs = HeaderAwareRecompile([str(header), str(other_header)])
    assert not needs(str(obj), str(src))
    os.utime(other_header, (300, 300))  # a header a.cpp may include, edited after a.o was built
    assert needs(str(obj), str(src))
    os.utime(other_header, (100, 100))
    os.utime(src, (300, 300))
    assert needs(str(obj), str(src))
    assert needs(str(tmp_path / "missing.o"), str(src))
    # setup.py uses it for the engine and lists the headers as the extension's dependencies
    setup_text = (REPO / "setup.py").read_text()
    assert "needs_recompile=HeaderAwareRecompile(engine_headers)" in setup_text and "depends=engine_headers" in setup_text
