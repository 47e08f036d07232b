"""DDS isolation for tests that start rclpy: one ROS domain per test process, localhost only.

Call :func:`isolate_ros_env` before ``rclpy.init`` (the middleware reads the variables when a
context starts), or use the :func:`ros_context` fixture, which also gives each test its own
``rclpy.context.Context`` so several tests can init and shut down in one process::

    from ros_env import ros_context  # noqa: F401  (pytest finds the fixture by name)

    def test_something(ros_context):
        node = MyNode(context=ros_context)
"""
from __future__ import annotations

import os
import shutil
import sys
import time
from pathlib import Path

import pytest


def ros_domain_for_process(pid: int | None = None) -> int:
    """A domain id from the process id, in 20..99 (ids above 101 may collide with
    ephemeral ports on Linux, since DDS ports are 7400 + 250 * domain + offsets)."""
    return (os.getpid() if pid is None else pid) % 80 + 20


def isolate_ros_env() -> int:
    """Set ``ROS_DOMAIN_ID`` (per process) and ``ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST``;
    return the domain id."""
    domain = ros_domain_for_process()
    os.environ['ROS_DOMAIN_ID'] = str(domain)
    os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
    os.environ.pop('ROS_LOCALHOST_ONLY', None)  # deprecated; conflicts with the range setting
    return domain


@pytest.fixture
def ros_context():
    """An initialised rclpy Context for one test, shut down afterwards."""
    isolate_ros_env()
    import rclpy
    from rclpy.context import Context

    context = Context()
    rclpy.init(context=context)
    try:
        yield context
    finally:
        rclpy.try_shutdown(context=context)


def installed_executable(name: str) -> str:
    """The path of the package's executable ``name`` beside this Python, or skip the test."""
    exe = shutil.which(name, path=str(Path(sys.executable).parent))
    if exe is None:
        pytest.skip(f'{name} is not installed in this environment (pip install -e .)')
    return exe


def spin_until(executor, predicate, timeout: float = 5.0) -> None:
    """Spin ``executor`` until ``predicate()`` holds; fail after ``timeout`` seconds."""
    deadline = time.monotonic() + timeout
    while not predicate():
        if time.monotonic() > deadline:
            raise AssertionError('timed out waiting for the node graph')
        executor.spin_once(timeout_sec=0.05)
