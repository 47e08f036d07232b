"""The robot package and the offline tools apart: the runtime needs only numpy, scipy,
pyserial, yaml and ROS; package.xml lists exactly that; the tools fail with one clear line."""
from __future__ import annotations

import configparser
import subprocess
import sys
import xml.etree.ElementTree as ET
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
TOOL_LIBRARIES = ('rosbags', 'matplotlib', 'tqdm', 'motmetrics', 'sklearn', 'kiss_icp')
RUNTIME_MODULES = ('laser_tracker.nodes.composed', 'laser_tracker.nodes.sick_lms_driver',
                   'laser_tracker.nodes.launch', 'laser_tracker.parameters',
                   'laser_tracker.conversions', 'laser_tracker.core.pipeline',
                   'laser_tracker.sick.driver')


def _run(code: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, '-c', code], capture_output=True, text=True,
                          timeout=120, cwd=ROOT)


def test_the_runtime_imports_without_the_tool_libraries():
    blocker = (
        'import sys\n'
        'class Block:\n'
        '    def find_spec(self, name, path=None, target=None):\n'
        f'        if name.split(".")[0] in {TOOL_LIBRARIES!r}:\n'
        '            raise ImportError(f"blocked tool library {name}")\n'
        'sys.meta_path.insert(0, Block())\n')
    imports = '\n'.join(f'import {m}' for m in RUNTIME_MODULES)
    result = _run(blocker + imports + '\nprint("ok")')
    assert result.returncode == 0 and 'ok' in result.stdout, result.stderr


def test_the_tracking_node_needs_no_serial_library():
    result = _run('import sys, laser_tracker.nodes.tracking, laser_tracker.nodes.detection, '
                  'laser_tracker.nodes.ego_motion, laser_tracker.nodes.active_head\n'
                  'print(sorted(m for m in ("serial", "termios") if m in sys.modules))')
    assert result.returncode == 0, result.stderr
    assert result.stdout.strip() == '[]'


def test_package_xml_lists_exactly_the_runtime_dependencies():
    deps = {e.text for e in ET.parse(ROOT / 'package.xml').getroot().iter('exec_depend')}
    python = {d for d in deps if d.startswith('python3-')}
    cfg = configparser.ConfigParser()
    cfg.read(ROOT / 'setup.cfg')
    required = {r.strip() for r in cfg['options']['install_requires'].split('\n') if r.strip()}
    to_rosdep = {'numpy': 'python3-numpy', 'scipy': 'python3-scipy', 'numba': 'python3-numba',
                 'pyserial': 'python3-serial', 'pyyaml': 'python3-yaml'}
    assert required == set(to_rosdep)
    assert python == set(to_rosdep.values())
    # Every ROS package the runtime imports is declared.
    ros = {'rclpy', 'sensor_msgs', 'nav_msgs', 'geometry_msgs', 'visualization_msgs',
           'std_msgs', 'diagnostic_msgs', 'rcl_interfaces', 'builtin_interfaces'}
    assert ros <= deps
    imported = set()
    for path in (ROOT / 'laser_tracker').rglob('*.py'):
        if 'tools' in path.parts:
            continue
        for line in path.read_text().splitlines():
            words = line.split()
            if len(words) >= 2 and words[0] in ('import', 'from'):
                imported.add(words[1].split('.')[0])
    ros_imported = {m for m in imported if m.endswith('_msgs') or m in ('rclpy',)}
    assert ros_imported <= deps, ros_imported - deps


@pytest.mark.parametrize('case', ['under_a_file', 'proc', 'garbage_metadata', 'not_yaml'])
def test_the_cli_says_one_line_for_outputs_and_inputs_it_cannot_use(tmp_path, case):
    bag = ROOT / 'bags' / 'exp3_rotating_static'
    afile = tmp_path / 'afile'
    afile.write_text('x')
    if case == 'under_a_file':
        argv = ['replay', str(bag), '--out', str(afile / 'out'), '--no-progress']
    elif case == 'proc':
        argv = ['replay', str(bag), '--out', '/proc/laser_tracker_test', '--no-progress']
    elif case == 'garbage_metadata':
        broken = tmp_path / 'broken'
        broken.mkdir()
        (broken / 'metadata.yaml').write_text('rosbag2_bagfile_information: [\n  {garbage')
        argv = ['replay', str(broken), '--no-progress']
    else:
        argv = ['config', '--check', str(afile)]
        afile.write_text('a: [unclosed\n  b: {')
    result = subprocess.run([sys.executable, '-m', 'laser_tracker.tools.cli', *argv],
                            capture_output=True, text=True, timeout=120, cwd=tmp_path)
    assert result.returncode == 2, result.stderr
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith('laser-tracker '), result.stderr
    assert 'Traceback' not in result.stderr
