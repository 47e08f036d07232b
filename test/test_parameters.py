"""One configuration path: the nodes, `replay --config` and `config --check` accept and refuse
the same files with the same one-line errors (file, node, parameter)."""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from laser_tracker import parameters
from laser_tracker.config import ConfigError, ParameterEntry
from laser_tracker.tools.cli import main

REPO = Path(__file__).resolve().parents[1]
BAG = REPO / 'bags' / 'exp1_stationary_single_walker'


def write(tmp_path, text, name='p.yaml'):
    path = tmp_path / name
    path.write_text(text)
    return path


def cli_error(capsys, argv) -> str:
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1, err          # one line, no traceback
    return err


def test_an_integer_is_a_fine_float_everywhere(tmp_path, capsys):
    path = write(tmp_path, 'tracking:\n  ros__parameters:\n    hypotheses:\n      gate: 1\n')
    loaded = parameters.load_files([path])
    assert loaded['tracking'].sections['hypotheses'].gate == 1.0
    assert isinstance(loaded['tracking'].sections['hypotheses'].gate, float)
    assert main(['config', '--check', str(path)]) == 0
    assert 'hypotheses.gate = 1.0' in capsys.readouterr().out


def test_the_same_one_line_error_from_check_and_replay(tmp_path, capsys):
    path = write(tmp_path, '/**/tracking:\n  ros__parameters:\n    hypotheses:\n'
                           '      gate: -2\n')
    expected = f'{path}: node tracking: parameter hypotheses.gate: -2.0 is below the minimum'
    check = cli_error(capsys, ['config', '--check', str(path)])
    replay = cli_error(capsys, ['replay', str(BAG), '--config', str(path), '--out',
                                str(tmp_path / 'out'), '--no-progress'])
    assert expected in check and expected in replay
    assert not (tmp_path / 'out').exists()


@pytest.mark.parametrize('text, needle', [
    ('trackign:\n  ros__parameters:\n    hypotheses:\n      gate: 0.5\n',
     "'trackign' configures none of the nodes"),
    ('tracking:\n  ros__parameters:\n    hypotheses:\n      gaet: 0.5\n',
     "node tracking: unknown parameter 'hypotheses.gaet'"),
    ('/**:\n  ros__parameters:\n    nonsense: 1\n', "unknown parameter 'nonsense'"),
    ('tracking:\n  ros__parameters:\n    kalman:\n      mode: bogus\n',
     "kalman.mode: 'bogus' is not one of"),
    ('tracking: [1, 2\n', 'not valid YAML (line'),
    ('just a string\n', 'expected a map of node names'),
])
def test_bad_files_are_refused_by_check_and_replay_alike(tmp_path, capsys, text, needle):
    path = write(tmp_path, text)
    assert needle in cli_error(capsys, ['config', '--check', str(path)])
    assert needle in cli_error(capsys, ['replay', str(BAG), '--config', str(path),
                                        '--no-progress', '--out', str(tmp_path / 'o')])


def test_wildcard_namespaced_and_builtin_keys(tmp_path):
    path = write(tmp_path, '\n'.join([
        '/**:',
        '  ros__parameters:',
        '    use_sim_time: true',
        '/**/tracking:',
        '  ros__parameters:',
        '    hypotheses: {confirm_samples: 5}',
        '/robot1/detection:',
        '  ros__parameters:',
        '    grid: {resolution: 0.05}',
        '']))
    anywhere = parameters.load_files([path])
    assert anywhere['tracking'].sections['hypotheses'].confirm_samples == 5
    assert anywhere['tracking'].builtin['use_sim_time'] is True
    assert anywhere['detection'].sections['grid'].resolution == 0.05
    robot2 = parameters.load_files([path], namespace='/robot2')
    assert robot2['detection'].sections['grid'].resolution == 0.1      # not robot1's entry
    assert robot2['tracking'].sections['hypotheses'].confirm_samples == 5
    assert parameters.load_files([path], namespace='/robot1')[
        'detection'].sections['grid'].resolution == 0.05


def test_ros_matching_rules():
    entry = ParameterEntry('tracking', {}, 'f')                 # root namespace only
    assert entry.matches('tracking', '/') and not entry.matches('tracking', '/ns')
    assert entry.matches('tracking', None)                      # offline: any namespace
    star = ParameterEntry('/*/tracking', {}, 'f')
    assert star.matches('tracking', '/a') and not star.matches('tracking', '/a/b')
    assert not star.matches('tracking', '/')
    deep = ParameterEntry('/**/tracking', {}, 'f')
    assert all(deep.matches('tracking', ns) for ns in ('/', '/a', '/a/b'))
    assert not deep.matches('detection', '/a')
    assert ParameterEntry('/**', {}, 'f').matches('detection', '/x/y')


def test_later_files_and_command_line_overrides_win(tmp_path):
    a = write(tmp_path, 'tracking:\n  ros__parameters:\n    hypotheses: {gate: 0.5}\n', 'a.yaml')
    b = write(tmp_path, 'tracking:\n  ros__parameters:\n    hypotheses: {gate: 0.6}\n', 'b.yaml')
    loaded = parameters.load(parameters.read_files([a, b]), overrides={'hypotheses.gate': 0.9})
    assert loaded['tracking'].sections['hypotheses'].gate == 0.9
    assert loaded['tracking'].sources['hypotheses.gate'] == parameters.COMMAND_LINE
    assert parameters.load_files([a, b])['tracking'].sources['hypotheses.gate'] == str(b)


def test_a_node_names_the_file_its_bad_value_came_from(tmp_path):
    """The node (rclpy resolved the file for it) fails with the loader's very message."""
    from ros_env import isolate_ros_env
    isolate_ros_env()
    import rclpy
    from rclpy.context import Context

    from laser_tracker.nodes import params
    from laser_tracker.nodes.tracking import TrackingNode

    path = write(tmp_path, '/**/tracking:\n  ros__parameters:\n    hypotheses:\n'
                           '      gate: -2\n')
    with pytest.raises(ConfigError) as offline:
        parameters.load_files([path])
    context = Context()
    rclpy.init(context=context, args=['--ros-args', '--params-file', str(path)])
    params.PARAMETER_FILES[:] = [str(path)]
    try:
        with pytest.raises(ConfigError) as online:
            TrackingNode(context=context, namespace='robot1')
        assert str(online.value) == str(offline.value)
    finally:
        params.PARAMETER_FILES[:] = []
        rclpy.try_shutdown(context=context)


def late_odometry_bag(path):
    """Scans received at once, odometry received 0.3 s after its stamp."""
    from laser_tracker.conversions import PlanarOdometry, odometry_to_msg, scan_to_msg
    from laser_tracker.core.scan import Scan
    from laser_tracker.tools.bag import FACTORY, BagWriter

    angles = np.linspace(-math.pi / 2, math.pi / 2, 181)
    with BagWriter(path) as bag:
        events = []
        for k in range(60):
            t = 1.0 + 0.05 * k
            events.append((t + 0.3, '/odom', odometry_to_msg(
                FACTORY, PlanarOdometry(t, 0.1 * t, 0.0, 0.0))))
        for k in range(12):
            t = 1.2 + 0.2 * k
            r = 3.0 / np.maximum(np.abs(np.cos(angles)), 0.3)
            events.append((t + 0.01, '/scan', scan_to_msg(FACTORY, Scan(
                stamp=t, ranges=r, angle_min=-math.pi / 2, angle_increment=math.pi / 180,
                range_min=0.05, range_max=8.0))))
        for arrival, topic, msg in sorted(events, key=lambda e: e[0]):
            bag.write(topic, msg, arrival)
    return path


def test_replay_honours_odom_wait(tmp_path):
    """odom_wait is a node parameter that shapes the replay: 0 = scans never wait, so a scan
    whose odometry arrives late finds none to interpolate."""
    from laser_tracker.tools.replay import replay_bag

    bag = late_odometry_bag(tmp_path / 'late')
    no_wait = write(tmp_path, 'ego_motion:\n  ros__parameters:\n    odom_wait: 0\n')
    waited = replay_bag(bag, progress=False)
    eager = replay_bag(bag, config=parameters.load_files([no_wait]), progress=False)
    assert waited['odom_wait'] == 1.0 and eager['odom_wait'] == 0.0
    missing = 'note: no odometry'
    assert waited['events']['ego_motion'].get(missing, 0) <= 1     # the very first scan
    assert eager['events']['ego_motion'].get(missing, 0) >= 10


def test_the_committed_files_load_with_every_node():
    for name in ('laser_tracker.yaml', 'paper_reference.yaml'):
        loaded = parameters.load_files([REPO / 'config' / name])
        assert set(loaded) == set(parameters.NODE_SECTIONS)
    assert math.isfinite(parameters.load_files([])['ego_motion'].sections[''].odom_wait)
    assert np.isclose(parameters.defaults()['tracking']['hypotheses.w_inc'], 60.0)


def test_a_plain_override_reaches_the_node_that_has_it_in_a_composed_process(ros_context):
    """``-p hypotheses.gate:=1.0`` reaches every node of laser_tracker_all: the tracking node
    takes it, the others leave it; a name no node has is still refused."""
    from rclpy.parameter import Parameter

    from laser_tracker.nodes.ego_motion import EgoMotionNode
    from laser_tracker.nodes.tracking import TrackingNode

    gate = [Parameter('hypotheses.gate', value=1.0)]
    ego = EgoMotionNode(context=ros_context, parameter_overrides=gate)
    tracking = TrackingNode(context=ros_context, parameter_overrides=gate)
    try:
        assert tracking.stage.config.gate == 1.0
        assert not ego.has_parameter('hypotheses.gate')
    finally:
        ego.destroy_node()
        tracking.destroy_node()
    with pytest.raises(ConfigError, match=r"no node has a parameter 'hypotheses.gaet'; did "
                                          r"you mean hypotheses.gate \(tracking\)"):
        EgoMotionNode(context=ros_context,
                      parameter_overrides=[Parameter('hypotheses.gaet', value=1.0)])
