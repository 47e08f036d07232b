"""A user's mistakes, each through the installed executable: exit status 2 and exactly one
line on stderr that names the problem (no traceback, and no ROS log line either); and what
the nodes say at start-up, when no scan comes, and about a parameter file written for
another namespace."""
from __future__ import annotations

import os
import signal
import subprocess
import threading
import time
from pathlib import Path

import pytest

from ros_env import installed_executable, isolate_ros_env

ROOT = Path(__file__).resolve().parents[1]
EXP1 = 'exp1_stationary_single_walker'
NODE_EXECUTABLES = ['sick_lms_driver', 'ego_motion', 'detection', 'tracking', 'active_head',
                    'laser_tracker_all']


def run(name: str, *args: str, timeout: float = 120.0) -> subprocess.CompletedProcess:
    isolate_ros_env()
    return subprocess.run([installed_executable(name), *map(str, args)], env=dict(os.environ),
                          capture_output=True, text=True, timeout=timeout, cwd=ROOT)


def assert_one_line(result: subprocess.CompletedProcess, *needles: str) -> str:
    lines = result.stderr.splitlines()
    assert result.returncode == 2, (result.returncode, result.stdout, result.stderr)
    assert 'Traceback' not in result.stderr + result.stdout, result.stderr
    assert len(lines) == 1, lines
    for needle in needles:
        assert needle in lines[0], lines[0]
    return lines[0]


@pytest.fixture
def bad_yaml(tmp_path):
    path = tmp_path / 'bad.yaml'
    path.write_text('tracking:\n  ros__parameters:\n    hypotheses.gate: [1.0\n')
    return path


NODE_MISTAKES = {
    'malformed params file': (('--params-file', 'BAD'), ('bad.yaml: not valid YAML (line',
                                                         'laser-tracker config --check')),
    'missing params file': (('--params-file', 'no-such.yaml'),
                            ('--params-file no-such.yaml: cannot read: No such file',)),
    'bad -p value': (('-p', 'hypotheses.gate:=[1.0'),
                     ("-p hypotheses.gate:=[1.0: the value is not valid YAML",)),
    'unknown ROS argument': (('--bogus',), ('--bogus: not a ROS argument',)),
}


@pytest.mark.parametrize('mistake', NODE_MISTAKES)
@pytest.mark.parametrize('executable', NODE_EXECUTABLES)
def test_bad_ros_arguments_give_one_line(executable, mistake, bad_yaml):
    args, needles = NODE_MISTAKES[mistake]
    args = [str(bad_yaml) if a == 'BAD' else a for a in args]
    line = assert_one_line(run(executable, '--ros-args', *args, timeout=30.0), *needles)
    assert line.startswith(f'{executable}: ')


def test_a_parameter_no_node_has_names_the_near_ones_and_their_node():
    assert_one_line(run('laser_tracker_all', '--ros-args', '-p', 'hypotheses.gatee:=1.0',
                        timeout=30.0),
                    "no node has a parameter 'hypotheses.gatee'",
                    'did you mean hypotheses.gate (tracking)')


def test_evaluating_a_replay_against_another_recording_is_refused(tmp_path):
    from laser_tracker.tools.replay import replay_bag

    replay_bag(EXP1, out_dir=tmp_path / 'exp1', progress=False)
    assert_one_line(run('laser-tracker', 'evaluate', tmp_path / 'exp1', 'crossing_walkers',
                        '--no-figures'),
                    'is a replay of', EXP1, 'not of', 'crossing_walkers', '--force')
    assert_one_line(run('laser-tracker', 'evaluate', tmp_path / 'exp1', EXP1, '--no-figures',
                        '--scan-topic', '/odom'), '--scan-topic /odom: a nav_msgs/msg/Odometry')
    forced = run('laser-tracker', 'evaluate', tmp_path / 'exp1', 'crossing_walkers',
                 '--no-figures', '--force')
    assert forced.returncode == 0, forced.stderr
    same = run('laser-tracker', 'evaluate', tmp_path / 'exp1', EXP1, '--no-figures')
    assert same.returncode == 0, same.stderr


def test_replay_topics_that_are_absent_or_of_another_type(tmp_path):
    assert_one_line(run('laser-tracker', 'replay', EXP1, '--odom-topic', '/wheel_odom',
                        '--out', tmp_path / 'a'),
                    '--odom-topic /wheel_odom: no such topic; its Odometry topics: '
                    '/ground_truth/platform, /odom')
    assert_one_line(run('laser-tracker', 'replay', EXP1, '--scan-topic', '/odom',
                        '--out', tmp_path / 'b'),
                    '--scan-topic /odom: a nav_msgs/msg/Odometry topic, not '
                    'sensor_msgs/msg/LaserScan; its LaserScan topics: /scan')
    assert_one_line(run('laser-tracker', 'sick-sim', '--recording', ROOT / 'bags' / EXP1,
                        '--topic', '/ground_truth', '--link', tmp_path / 'tty'),
                    '--topic /ground_truth: a visualization_msgs/msg/MarkerArray topic')
    assert not (tmp_path / 'a').exists() and not (tmp_path / 'b').exists()


def _carmen_log(path: Path) -> Path:
    """A small CARMEN log whose second line is stamped negative (reading it would warn)."""
    lines = []
    for k, stamp in enumerate((1.0, -1.0, 1.4, 1.6)):
        ranges = ' '.join(['3.00'] * 181)
        lines.append(f'FLASER 181 {ranges} 0 0 0 0 0 0 {stamp} host {stamp}')
    path.write_text('\n'.join(lines) + '\n')
    return path


def test_files_that_are_not_recordings_are_named_for_what_they_are(tmp_path):
    from laser_tracker.tools.replay import replay_bag

    log = _carmen_log(tmp_path / 'lab.clf')
    assert_one_line(run('laser-tracker', 'summarize', log), 'a CARMEN log, not a recording',
                    f'laser-tracker import-carmen {log} OUT')
    assert_one_line(run('laser-tracker', 'replay', log, '--out', tmp_path / 'r'),
                    'laser-tracker import-carmen')
    metadata = ROOT / 'bags' / EXP1 / 'metadata.yaml'
    assert_one_line(run('laser-tracker', 'summarize', metadata),
                    f'give the rosbag2 folder that holds this file: {metadata.parent}')
    replay_bag(EXP1, out_dir=tmp_path / 'replayed', progress=False)
    assert_one_line(run('laser-tracker', 'play', tmp_path / 'replayed'),
                    'a `laser-tracker replay` output, not a recording')


def test_outputs_are_checked_before_any_work(tmp_path):
    log = _carmen_log(tmp_path / 'lab.clf')
    full = '/dev/full/x'
    assert_one_line(run('laser-tracker', 'import-carmen', log, full),
                    f'{full}: cannot be written: /dev/full is not a folder')
    assert_one_line(run('laser-tracker', 'import-carmen', log, tmp_path),
                    f'{tmp_path}: already exists (use --overwrite')
    assert_one_line(run('laser-tracker', 'import-bag', ROOT / 'bags' / EXP1, tmp_path),
                    'already exists (use --overwrite')
    assert_one_line(run('laser-tracker', 'simulate', EXP1, tmp_path),
                    'already exists (use --overwrite')
    assert_one_line(run('laser-tracker', 'replay', EXP1, '--out', full), 'not a folder')
    assert_one_line(run('laser-tracker', 'config', '--write', full), 'not a folder')
    assert_one_line(run('laser-tracker', 'train-detector', '--output', full, '--positive',
                        ROOT / 'bags' / EXP1), 'not a folder')
    assert_one_line(run('laser-tracker', 'evaluate', tmp_path, EXP1, '--json', full),
                    'not a folder')


def test_play_refuses_a_recording_without_scans_and_unknown_topics(tmp_path):
    from laser_tracker.conversions import PlanarOdometry, odometry_to_msg
    from laser_tracker.tools.bag import FACTORY, BagWriter

    bag = tmp_path / 'odometry_only'
    with BagWriter(bag) as w:
        w.write('/odom', odometry_to_msg(FACTORY, PlanarOdometry(1.0, 0.0, 0.0, 0.0)), 1.0)
    assert_one_line(run('laser-tracker', 'play', bag), 'no LaserScan topic to play',
                    '/odom (nav_msgs/msg/Odometry)')
    assert_one_line(run('laser-tracker', 'play', EXP1, '--topics', '/scan', '/wheel_odom'),
                    '--topics: no topic /wheel_odom; it has:')


class Process:
    """An executable whose output (stdout and stderr) is collected by a thread."""

    def __init__(self, name: str, *args: str):
        isolate_ros_env()
        self.proc = subprocess.Popen([installed_executable(name), *args], env=dict(os.environ),
                                     stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                                     text=True, cwd=ROOT)
        self.lines: list[str] = []
        self.reader = threading.Thread(target=lambda: self.lines.extend(self.proc.stdout),
                                       daemon=True)
        self.reader.start()

    def wait_for(self, text: str, timeout: float) -> bool:
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline and self.proc.poll() is None:
            if any(text in line for line in self.lines):
                return True
            time.sleep(0.05)
        return any(text in line for line in self.lines)

    def stop(self) -> list[str]:
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGINT)
        try:
            self.proc.wait(timeout=15)
        finally:
            if self.proc.poll() is None:
                self.proc.kill()
        self.reader.join(5.0)
        return self.lines


def test_ctrl_c_during_a_replay_to_a_new_folder_leaves_nothing(tmp_path):
    out = tmp_path / 'new' / 'run'
    replay = Process('laser-tracker', 'replay', 'hokuyo_corridor_lobby', '--out', str(out),
                     '--no-progress')
    deadline = time.monotonic() + 60.0
    while not out.exists() and replay.proc.poll() is None and time.monotonic() < deadline:
        time.sleep(0.01)
    assert out.exists(), replay.stop()
    text = ''.join(replay.stop())                # Ctrl-C while the replay runs
    assert replay.proc.returncode == 130, text
    assert 'Traceback' not in text and not out.exists()
    assert (tmp_path / 'new').exists()      # made for the output, empty: harmless


def test_nodes_say_their_topics_and_warn_when_no_scan_comes(tmp_path):
    """laser_tracker_all in a namespace with a remapped scan topic and a parameter file
    written for the root namespace: a start-up line per node with the resolved topics, one
    warning for the ignored entry, one (not one per node) for the silent scan topic."""
    params = tmp_path / 'robot.yaml'
    params.write_text('ego_motion:\n  ros__parameters:\n    odom_wait: 0.5\n'
                      '/**/tracking:\n  ros__parameters:\n    hypotheses.gate: 1.0\n')
    node = Process('laser_tracker_all', '--ros-args', '-r', '__ns:=/robot1', '-r',
                   'scan:=front_scan', '--params-file', str(params))
    try:
        assert node.wait_for('no scan on', timeout=30.0), node.lines
        time.sleep(1.5)
    finally:
        lines = node.stop()
    text = ''.join(lines)
    assert node.proc.returncode == 0 and 'Traceback' not in text, text
    started = [line for line in lines if 'started as /robot1/' in line]
    assert len(started) == 4, text
    assert any('subscribes /robot1/odom, /robot1/front_scan; publishes /robot1/ego_motion, '
               '/robot1/ego_motion/status' in line for line in started), started
    ignored = [line for line in lines if "entry 'ego_motion' does not configure" in line]
    assert len(ignored) == 1, text
    assert "write '/**/ego_motion:' (any namespace) or '/robot1/ego_motion:'" in ignored[0]
    assert "'/**/tracking'" not in text          # that entry applies
    silent = [line for line in lines if 'no scan on /robot1/front_scan for ' in line]
    assert len(silent) == 1 and '-r scan:=YOUR_TOPIC' in silent[0], text
