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
