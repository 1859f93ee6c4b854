"""line_odom_core: the ROS-free registration engine (C++17 + Eigen behind one pybind11 module).

Conventions (docs/DESIGN.md §3): poses are 4x4 numpy arrays ``T_ab`` with ``x_a = T_ab @ x_b``; lines are Plücker
6-vectors ``(d, m)`` with unit ``d``; planes are ``(n, delta)`` with ``n·x + delta = 0`` and unit ``n``.
"""
from line_odom_core._core import __version__, build_info
from line_odom_core._core import solve_1l2p, solve_3l1p, solve_7l
from line_odom_core._core import estimate_motion
from line_odom_core._core import organize_depth, organize_points
from line_odom_core.config import Config, ConfigEntry, config_schema, load_config
from line_odom_core.features import extract_features, feature_config
from line_odom_core.odometry import FrameResult, Odometry

__all__ = ["__version__", "build_info", "solve_1l2p", "solve_3l1p", "solve_7l", "estimate_motion", "Config", "ConfigEntry", "config_schema", "load_config", "FrameResult",
           "Odometry", "organize_points", "organize_depth", "extract_features", "feature_config"]
