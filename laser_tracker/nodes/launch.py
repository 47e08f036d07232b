"""Entry points of the node executables (``ros2 run laser_tracker <node>``).

Deliberately light: it installs a Ctrl-C / SIGTERM handler that ends the process at once
*before* the heavy imports (rclpy, numpy, scipy take a second or more on a small computer),
so that stopping a node that is still starting is as quick and quiet as stopping a running
one. Once the node runs, ``common.run`` takes over the signals.
"""
from __future__ import annotations

import importlib
import os
import signal


def _start(module: str) -> None:
    def leave(signum, frame):
        os._exit(0)

    for s in (signal.SIGINT, signal.SIGTERM):
        signal.signal(s, leave)
    importlib.import_module(f'laser_tracker.nodes.{module}').main()


def sick_lms_driver() -> None:
    _start('sick_lms_driver')


def ego_motion() -> None:
    _start('ego_motion')


def detection() -> None:
    _start('detection')


def tracking() -> None:
    _start('tracking')


def active_head() -> None:
    _start('active_head')


def laser_tracker_all() -> None:
    _start('composed')
