"""Every node executable starts with the committed parameter file and stops cleanly on Ctrl-C
(what `ros2 run laser_tracker <node> --ros-args --params-file ...` does on a robot)."""
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from ros_env import isolate_ros_env

ROOT = Path(__file__).resolve().parents[1]
PARAMS = ROOT / 'config' / 'laser_tracker.yaml'
NODES = ['ego_motion', 'detection', 'tracking', 'active_head', 'laser_tracker_all',
         'sick_lms_driver']


@pytest.mark.parametrize('node', NODES)
def test_node_executable_starts_and_stops_on_sigint(node, tmp_path):
    exe = shutil.which(node, path=str(Path(sys.executable).parent))
    if exe is None:
        pytest.skip(f'{node} is not installed in this environment (pip install -e .)')
    isolate_ros_env()
    args = [exe, '--ros-args', '--params-file', str(PARAMS)]
    if node == 'sick_lms_driver':   # no scanner here: it must keep retrying, not crash
        args += ['-p', f'port:={tmp_path / "no-such-port"}']
    proc = subprocess.Popen(args, env=dict(os.environ), stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, text=True)
    try:
        time.sleep(2.0)
        assert proc.poll() is None, f'{node} exited early:\n{proc.stdout.read()}'
        proc.send_signal(signal.SIGINT)
        out, _ = proc.communicate(timeout=15)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 0, out
    assert 'Traceback' not in out, out
    if node == 'sick_lms_driver':
        assert 'no-such-port' in out          # the error names the port


# ------------------------------------------------------------------- sick_lms_driver


def start_sick_driver(*params: str) -> subprocess.Popen:
    exe = shutil.which('sick_lms_driver', path=str(Path(sys.executable).parent))
    if exe is None:
        pytest.skip('sick_lms_driver is not installed in this environment (pip install -e .)')
    isolate_ros_env()
    args = [exe, '--ros-args', '--params-file', str(PARAMS)]
    for p in params:
        args += ['-p', p]
    return subprocess.Popen(args, env=dict(os.environ), stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, text=True)


def interrupt(proc: subprocess.Popen) -> tuple[str, float]:
    """Ctrl-C; returns the output and how long the process took to exit."""
    started = time.monotonic()
    proc.send_signal(signal.SIGINT)
    try:
        out, _ = proc.communicate(timeout=15)
    finally:
        if proc.poll() is None:
            proc.kill()
    return out, time.monotonic() - started


def wait_for(predicate, timeout: float) -> bool:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline and not predicate():
        time.sleep(0.05)
    return predicate()


@pytest.fixture
def silent_port(tmp_path):
    """A serial port on which nothing ever answers (a powered-off scanner)."""
    master, slave = os.openpty()
    link = tmp_path / 'ttySilent'
    os.symlink(os.ttyname(slave), link)
    yield link
    os.close(master)
    os.close(slave)


def test_sick_driver_streams_and_stops_the_device_output_on_sigint(tmp_path):
    from laser_tracker.tools.sick_device import Lms2xxSimulator

    sim = Lms2xxSimulator(tmp_path / 'ttyLMS', baud=9600)
    sim.start()
    proc = start_sick_driver(f'port:={sim.link}', 'baud:=500000')
    try:
        assert wait_for(lambda: sim.counters.scans_sent >= 20 or proc.poll() is not None,
                        timeout=30.0), 'no scans streamed'
        assert proc.poll() is None and sim.device.streaming
        out, took = interrupt(proc)
        assert proc.returncode == 0 and 'Traceback' not in out, out
        assert took < 2.0, (took, out)
        assert not sim.device.streaming, out  # it stopped the device's output before leaving
        assert 'streaming at 500000 baud' in out
    finally:
        if proc.poll() is None:
            proc.kill()
        sim.stop()


def test_sick_driver_waiting_for_a_silent_device_stops_at_once_on_sigint(silent_port):
    proc = start_sick_driver(f'port:={silent_port}')   # autostart: searching the rate
    time.sleep(3.0)
    assert proc.poll() is None, proc.stdout.read()
    out, took = interrupt(proc)
    assert proc.returncode == 0 and 'Traceback' not in out, out
    assert took < 2.0, (took, out)


def test_sick_driver_sigint_interrupts_a_configure_in_progress(silent_port, ros_context):
    """A lifecycle manager's configure blocks the node while the device's rate is searched
    (seconds on a silent line); Ctrl-C must still end the process at once."""
    from lifecycle_msgs.srv import ChangeState
    from rclpy.node import Node

    proc = start_sick_driver(f'port:={silent_port}', 'autostart:=false')
    node = Node('lifecycle_manager', context=ros_context)
    try:
        client = node.create_client(ChangeState, '/sick_lms_driver/change_state')
        assert client.wait_for_service(timeout_sec=20.0), 'no lifecycle service'
        request = ChangeState.Request()
        request.transition.label = 'configure'
        client.call_async(request)
        time.sleep(1.0)  # the node is now inside configure
        assert proc.poll() is None
        out, took = interrupt(proc)
        assert proc.returncode == 0 and 'Traceback' not in out, out
        assert took < 2.0, (took, out)
        assert 'waiting for a lifecycle manager' in out
    finally:
        node.destroy_node()
        if proc.poll() is None:
            proc.kill()
