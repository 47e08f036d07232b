"""The package builds with colcon and lands where `ros2 run laser_tracker <node>` looks."""
import configparser
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
NODES = ['sick_lms_driver', 'ego_motion', 'detection', 'tracking', 'active_head']
SKIP_DIRS = {'.venv', '.git', 'build', 'install', 'log', 'out', '.pytest_cache'}


def _setup_cfg():
    cfg = configparser.ConfigParser()
    cfg.read(ROOT / 'setup.cfg')
    return cfg


def _copy_package(dest: Path) -> None:
    dest.mkdir(parents=True)
    for item in ROOT.iterdir():
        if item.name in SKIP_DIRS or item.name.endswith('.egg-info'):
            continue
        if item.is_dir():
            shutil.copytree(item, dest / item.name,
                            ignore=shutil.ignore_patterns('__pycache__', '*.pyc'))
        else:
            shutil.copy2(item, dest / item.name)


def test_setup_cfg_keeps_ros_script_dir():
    cfg = _setup_cfg()
    assert cfg['develop']['script_dir'] == '$base/lib/laser_tracker'
    assert cfg['install']['install_scripts'] == '$base/lib/laser_tracker'
    assert (ROOT / 'resource' / 'laser_tracker').is_file()


def test_every_bundled_recording_is_installed():
    """Each folder in bags/ has its data_files line, so it lands in share/laser_tracker/bags."""
    data_files = _setup_cfg()['options.data_files']
    listed = {k for k in data_files if k.startswith('share/laser_tracker/bags/')}
    present = {f'share/laser_tracker/bags/{p.name}' for p in (ROOT / 'bags').iterdir() if p.is_dir()}
    assert present == listed


def test_colcon_build_installs_nodes_config_and_ament_index(tmp_path):
    colcon = shutil.which('colcon', path=str(Path(sys.executable).parent)) or shutil.which('colcon')
    if colcon is None:
        pytest.skip('colcon-core is not installed (pip install colcon-core)')
    src = tmp_path / 'src' / 'laser_tracker'
    _copy_package(src)
    env = dict(os.environ, PATH=f'{Path(sys.executable).parent}:{os.environ.get("PATH", "")}')
    result = subprocess.run([colcon, 'build', '--paths', str(src)], cwd=tmp_path, env=env,
                            capture_output=True, text=True, timeout=300)
    assert result.returncode == 0, result.stdout + result.stderr
    prefix = tmp_path / 'install' / 'laser_tracker'
    lib = prefix / 'lib' / 'laser_tracker'
    for node in NODES + ['laser-tracker']:
        assert (lib / node).is_file() and os.access(lib / node, os.X_OK), f'{node} not in {lib}'
    share = prefix / 'share' / 'laser_tracker'
    assert (share / 'package.xml').is_file()
    assert (share / 'config' / 'laser_tracker.yaml').is_file()
    for layout in ('laser_tracker.rviz', 'laser_tracker_foxglove.json'):   # RViz, Foxglove
        assert (share / 'config' / layout).is_file(), layout
    assert (prefix / 'share' / 'ament_index' / 'resource_index' / 'packages' /
            'laser_tracker').is_file()
    for bag in (ROOT / 'bags').iterdir():
        if bag.is_dir():
            assert (share / 'bags' / bag.name / 'metadata.yaml').is_file()
    # The installed command runs from the install space.
    site = next(prefix.glob('lib/python3*/site-packages'))
    run_env = dict(env, PYTHONPATH=str(site))
    out = subprocess.run([str(lib / 'laser-tracker'), '--help'], env=run_env, cwd=tmp_path,
                         capture_output=True, text=True, timeout=60)
    assert out.returncode == 0 and 'replay' in out.stdout, out.stderr
