"""Shared fixtures: ``ros_context`` (an isolated rclpy context per test, see ros_env.py)."""
from ros_env import ros_context  # noqa: F401
