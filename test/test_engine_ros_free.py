"""The engine is ROS-free: `import line_odom_core` (every module of it) works where rclpy cannot be
imported, reports how it was built, and nothing in line_odom_core imports ROS (docs/DESIGN.md §1)."""
from __future__ import annotations

import ast
import json
import re
import subprocess
import sys
from pathlib import Path

import line_odom_core

CORE_DIR = Path(line_odom_core.__file__).resolve().parent

# top-level modules of ROS 2 (client library, middleware, messages) that the engine must not need
ROS_MODULES = ("rclpy", "rcl_interfaces", "rosidl_runtime_py", "rosidl_parser", "builtin_interfaces",
               "std_msgs", "geometry_msgs", "nav_msgs", "sensor_msgs", "tf2_msgs", "tf2_ros",
               "diagnostic_msgs", "std_srvs", "ament_index_python", "launch", "launch_ros")

ROS_FREE_PROBE = r"""
import importlib, importlib.abc, json, pkgutil, sys

BLOCKED = set(sys.argv[1].split(","))

class BlockRos(importlib.abc.MetaPathFinder):
    def find_spec(self, name, path=None, target=None):
        if name.split(".")[0] in BLOCKED:
            raise ModuleNotFoundError(f"No module named {name!r} (blocked: ROS-free check)", name=name)
        return None

sys.meta_path.insert(0, BlockRos())
try:
    import rclpy  # noqa: F401
    sys.exit("the blocker did not stop `import rclpy`")
except ModuleNotFoundError:
    pass

import line_odom_core
imported = [line_odom_core.__name__]
for info in pkgutil.walk_packages(line_odom_core.__path__, prefix="line_odom_core."):
    importlib.import_module(info.name)
    imported.append(info.name)
print(json.dumps({
    "version": line_odom_core.__version__,
    "build_info": line_odom_core.build_info(),
    "imported": imported,
    "ros_loaded": sorted(m for m in sys.modules if m.split(".")[0] in BLOCKED),
    "file": line_odom_core.__file__,
}))
"""


def run_probe() -> dict:
    proc = subprocess.run([sys.executable, "-c", ROS_FREE_PROBE, ",".join(ROS_MODULES)], cwd="/",
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, f"line_odom_core failed to import without ROS:\n{proc.stdout}\n{proc.stderr}"
    return json.loads(proc.stdout.strip().splitlines()[-1])


def test_import_and_build_info_without_rclpy():
    probe = run_probe()
    assert Path(probe["file"]).resolve().parent == CORE_DIR  # the same engine these tests exercise
    assert probe["ros_loaded"] == []
    assert "line_odom_core._core" in probe["imported"]
    assert re.fullmatch(r"\d+\.\d+\.\d+", probe["version"])

    info = probe["build_info"]
    assert re.match(r"(gcc|clang|g\+\+)\s*\d+", info["compiler"], re.IGNORECASE), info
    assert "-O3" in info["flags"].split(), info
    assert re.fullmatch(r"3\.\d+\.\d+", info["eigen_version"]), info
    assert info["cxx_standard"] >= 201703, info


def test_engine_python_sources_never_import_ros():
    offenders = []
    for path in sorted(CORE_DIR.rglob("*.py")) + sorted(CORE_DIR.rglob("*.pyi")):
        tree = ast.parse(path.read_text(), filename=str(path))
        for node in ast.walk(tree):
            if isinstance(node, ast.Import):
                names = [alias.name for alias in node.names]
            elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
                names = [node.module]
            else:
                continue
            offenders += [f"{path.relative_to(CORE_DIR)}:{node.lineno}: {n}" for n in names
                          if n.split(".")[0] in ROS_MODULES]
        if re.search(r"__import__\(\s*['\"]rclpy|import_module\(\s*['\"]rclpy", path.read_text()):
            offenders.append(f"{path.relative_to(CORE_DIR)}: dynamic import of rclpy")
    assert offenders == []


def test_engine_cpp_includes_neither_ros_nor_python_outside_the_bindings():
    include = re.compile(r'^\s*#\s*include\s*[<"]([^>"]+)[>"]', re.MULTILINE)
    forbidden = re.compile(r"^(rclcpp|rcl|rclpy|rmw|rosidl_\w+|\w+_msgs|tf2\w*|ament_\w+)/|^pybind11/|^Python\.h$")
    sources = sorted(p for p in (CORE_DIR / "cpp").rglob("*") if p.suffix in {".cpp", ".hpp", ".h", ".cc"})
    modules = [CORE_DIR / "cpp" / "bindings" / "module.cpp", CORE_DIR / "cpp" / "testing" / "module.cpp"]
    assert all(m.is_file() for m in modules)
    python_side = {m.parent for m in modules}  # _core's bindings, _testing's module
    offenders = [f"{p.relative_to(CORE_DIR)}: #include <{header}>"
                 for p in sources for header in include.findall(p.read_text())
                 if forbidden.search(header)
                 and not (p.parent in python_side and (header.startswith("pybind11/") or header == "Python.h"))]
    assert offenders == []


# The engine's folders in the order of docs/DESIGN.md §1: a file includes only its own folder and those before it.
ENGINE_LAYERS = ["common", "solvers", "scan", "features", "registration", "validation", "odometry", "bindings",
                 "testing"]


def test_engine_folders_include_only_lower_layers():
    include = re.compile(r'^\s*#\s*include\s*"([^"]+)"', re.MULTILINE)
    sources = sorted(p for p in (CORE_DIR / "cpp").rglob("*") if p.suffix in {".cpp", ".hpp"})
    assert sorted({p.relative_to(CORE_DIR / "cpp").parts[0] for p in sources}) == sorted(ENGINE_LAYERS)
    offenders = []
    for p in sources:
        layer = ENGINE_LAYERS.index(p.relative_to(CORE_DIR / "cpp").parts[0])
        for header in include.findall(p.read_text()):
            folder = header.split("/")[0]
            if folder not in ENGINE_LAYERS or ENGINE_LAYERS.index(folder) > layer:
                offenders.append(f"{p.relative_to(CORE_DIR)}: #include \"{header}\"")
    assert offenders == []
