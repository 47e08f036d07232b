"""Ctrl-C stops every node executable within 2 s, every time: 50 stops per executable, at
random moments from the package's first line of code (the entry point installs its signal
handlers before any heavy import) to full operation, exit status 0, no traceback. Before
that moment the Python interpreter is still starting, and a Ctrl-C ends it by Python's own
rules; the test therefore starts its clock when the process catches SIGTERM, which the
interpreter alone never does."""
from __future__ import annotations

import os
import random
import signal
import subprocess
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import pytest

from ros_env import installed_executable, isolate_ros_env

ROOT = Path(__file__).resolve().parents[1]
PARAMS = ROOT / 'config' / 'laser_tracker.yaml'
NODES = ['ego_motion', 'detection', 'tracking', 'active_head', 'laser_tracker_all',
         'sick_lms_driver']
REPEATS = 50
STOP_WITHIN = 2.0       # s from SIGINT to exit
PARALLEL = 8


def _stop_once(exe: str, delay: float, tmp: Path) -> tuple[float, int, str]:
    args = [exe, '--ros-args', '--params-file', str(PARAMS)]
    if exe.endswith('sick_lms_driver'):
        args += ['-p', f'port:={tmp / "no-such-port"}']
    proc = subprocess.Popen(args, env=dict(os.environ), stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, text=True)
    _wait_for_handlers(proc)
    time.sleep(delay)
    sent = time.monotonic()
    proc.send_signal(signal.SIGINT)
    try:
        out, _ = proc.communicate(timeout=STOP_WITHIN + 3.0)
    except subprocess.TimeoutExpired:
        proc.kill()
        out, _ = proc.communicate()
        return float('inf'), -9, out
    return time.monotonic() - sent, proc.returncode, out


def _wait_for_handlers(proc, timeout=30.0) -> None:
    """Until the process has installed a SIGTERM handler (our entry point's first act)."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline and proc.poll() is None:
        try:
            status = Path(f'/proc/{proc.pid}/status').read_text()
        except OSError:
            return
        caught = next((int(line.split()[1], 16) for line in status.splitlines()
                       if line.startswith('SigCgt:')), 0)
        if caught & (1 << (signal.SIGTERM - 1)):
            return
        time.sleep(0.01)


@pytest.mark.parametrize('node', NODES)
def test_ctrl_c_stops_the_node_within_two_seconds_every_time(node, tmp_path):
    exe = installed_executable(node)
    isolate_ros_env()
    rng = random.Random(node)                       # the same moments on every run
    delays = [rng.uniform(0.0, 2.5) for _ in range(REPEATS)]
    with ThreadPoolExecutor(PARALLEL) as pool:
        results = list(pool.map(lambda d: _stop_once(exe, d, tmp_path), delays))
    slow = [(d, r) for d, r in zip(delays, results) if r[0] > STOP_WITHIN]
    bad_status = [(d, r) for d, r in zip(delays, results) if r[1] != 0]
    traces = [(d, r) for d, r in zip(delays, results) if 'Traceback' in r[2]]
    worst = max(r[0] for r in results)
    assert not slow, f'{len(slow)} of {REPEATS} stops took longer than {STOP_WITHIN} s ' \
                     f'(worst {worst:.2f} s): {slow[:2]}'
    assert not bad_status, f'{len(bad_status)} non-zero exits: {bad_status[:2]}'
    assert not traces, f'tracebacks: {traces[:1]}'
