"""Every node executable starts with the committed parameter file and stops cleanly on Ctrl-C
(what `ros2 run laser_tracker <node> --ros-args --params-file ...` does on a robot)."""
import os
import signal
import subprocess
import threading
import time
from pathlib import Path

import pytest

from ros_env import installed_executable, isolate_ros_env

ROOT = Path(__file__).resolve().parents[1]
PARAMS = ROOT / 'config' / 'laser_tracker.yaml'
NODES = ['ego_motion', 'detection', 'tracking', 'active_head', 'laser_tracker_all']


@pytest.mark.parametrize('node', NODES)
def test_node_executable_starts_and_stops_on_sigint(node, tmp_path):
    exe = installed_executable(node)
    isolate_ros_env()
    args = [exe, '--ros-args', '--params-file', str(PARAMS)]
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


# ------------------------------------------------------------------- sick_lms_driver


class Driver:
    """A ``sick_lms_driver`` process started with the committed parameter file; its output
    is collected by a thread so a test can wait for a line (start-up takes seconds on a
    loaded machine, and a Ctrl-C before the node runs ends it before it says anything)."""

    def __init__(self, *params: str):
        exe = installed_executable('sick_lms_driver')
        isolate_ros_env()
        args = [exe, '--ros-args', '--params-file', str(PARAMS)]
        for p in params:
            args += ['-p', p]
        self.proc = subprocess.Popen(args, env=dict(os.environ), stdout=subprocess.PIPE,
                                     stderr=subprocess.STDOUT, text=True)
        self.lines: list[str] = []
        self._reader = threading.Thread(target=self._read, daemon=True)
        self._reader.start()

    def _read(self) -> None:
        for line in self.proc.stdout:
            self.lines.append(line)

    @property
    def output(self) -> str:
        return ''.join(self.lines)

    def wait_for(self, text: str, timeout: float = 30.0) -> bool:
        return wait_for(lambda: text in self.output or self.proc.poll() is not None, timeout) \
            and text in self.output

    def interrupt(self) -> float:
        """Ctrl-C; returns how long the process took to exit."""
        started = time.monotonic()
        self.proc.send_signal(signal.SIGINT)
        try:
            self.proc.wait(timeout=15)
        finally:
            self.kill()
        took = time.monotonic() - started
        self._reader.join(5.0)
        return took

    def assert_stops_on_sigint(self) -> None:
        """Ctrl-C ends the driver cleanly (status 0, no traceback) within 2 s."""
        took = self.interrupt()
        assert self.proc.returncode == 0 and 'Traceback' not in self.output, self.output
        assert took < 2.0, (took, self.output)

    def kill(self) -> None:
        if self.proc.poll() is None:
            self.proc.kill()
            self.proc.wait()


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


def test_sick_driver_without_a_scanner_keeps_retrying_and_stops_on_sigint(tmp_path):
    driver = Driver(f'port:={tmp_path / "no-such-port"}')
    try:
        assert driver.wait_for('no such serial port'), driver.output  # names the port
        assert 'no-such-port' in driver.output and 'retrying' in driver.output
        time.sleep(1.0)
        assert driver.proc.poll() is None, driver.output
        driver.assert_stops_on_sigint()
    finally:
        driver.kill()


def test_sick_driver_streams_and_stops_the_device_output_on_sigint(tmp_path):
    from laser_tracker.tools.sick_device import Lms2xxSimulator

    sim = Lms2xxSimulator(tmp_path / 'ttyLMS', baud=9600)
    sim.start()
    driver = Driver(f'port:={sim.link}', 'baud:=500000')
    try:
        assert driver.wait_for('streaming at 500000 baud'), driver.output
        assert wait_for(lambda: sim.counters.scans_sent >= 20, timeout=10.0)
        assert driver.proc.poll() is None and sim.device.streaming
        driver.assert_stops_on_sigint()
        assert not sim.device.streaming  # it stopped the device's output before leaving
    finally:
        driver.kill()
        sim.stop()


def test_sick_driver_waiting_for_a_silent_device_stops_at_once_on_sigint(silent_port):
    driver = Driver(f'port:={silent_port}')   # autostart: searching the device's rate
    try:
        assert driver.wait_for('autostart: waiting'), driver.output
        time.sleep(1.0)
        assert driver.proc.poll() is None, driver.output
        driver.assert_stops_on_sigint()
    finally:
        driver.kill()


def test_sick_driver_sigint_interrupts_a_configure_in_progress(silent_port, ros_context):
    """A lifecycle manager's configure blocks the node while the device's rate is searched
    (seconds on a silent line); Ctrl-C must still end the process at once."""
    from lifecycle_msgs.srv import ChangeState
    from rclpy.node import Node

    driver = Driver(f'port:={silent_port}', 'autostart:=false')
    node = Node('lifecycle_manager', context=ros_context)
    try:
        assert driver.wait_for('waiting for a lifecycle manager'), driver.output
        client = node.create_client(ChangeState, '/sick_lms_driver/change_state')
        request = ChangeState.Request()
        request.transition.label = 'configure'
        # ros2 lifecycle set ... configure; sent again until the node says it is configuring
        # (a request sent before the service is matched is lost)
        for _ in range(30):
            client.call_async(request)
            if driver.wait_for('configuring', timeout=1.0):
                break
        assert 'configuring' in driver.output, driver.output
        time.sleep(0.5)  # inside configure: the rate search takes seconds
        assert driver.proc.poll() is None
        driver.assert_stops_on_sigint()
    finally:
        node.destroy_node()
        driver.kill()
