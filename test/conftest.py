"""Shared pytest fixtures for line_odom's tests.

ROS 2 tests on a shared machine: `ros_env` gives each pytest process its own DDS domain and keeps
discovery on this host, so concurrent test runs (other checkouts, CI) never see each other's
topics. Subprocesses get the same settings through the returned dict (start them with
sys.executable: the ROS wheels' bootstrapper has already set LD_LIBRARY_PATH for it).
"""
from __future__ import annotations

import os

import pytest

# 1..100: Fast DDS derives UDP ports from the domain id (7400 + 250 * id + ...); ids above ~100 reach
# the ephemeral port range on Linux.
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
