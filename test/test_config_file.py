"""``laser-tracker config`` and the committed config/laser_tracker.yaml (declared once: the
file is the rendering of the code's defaults)."""
from __future__ import annotations

from pathlib import Path

import yaml

from laser_tracker.tools.cli import main
from laser_tracker.config import read_parameter_file
from laser_tracker.core.pipeline import NODES, PipelineConfig
from laser_tracker.parameters import NODE_SECTIONS
from laser_tracker.tools.config_file import check, render_defaults

REPO = Path(__file__).resolve().parents[1]
COMMITTED = REPO / 'config' / 'laser_tracker.yaml'


def test_committed_file_equals_the_defaults_rendering():
    assert COMMITTED.exists(), 'config/laser_tracker.yaml is missing'
    assert COMMITTED.read_text() == render_defaults(), (
        'config/laser_tracker.yaml differs from the code defaults: regenerate it with '
        '`laser-tracker config --write config/laser_tracker.yaml`')


def test_committed_paper_reference_equals_its_rendering(tmp_path):
    paper = REPO / 'config' / 'paper_reference.yaml'
    assert paper.read_text() == render_defaults(paper=True), (
        'regenerate with `laser-tracker config --write config/paper_reference.yaml --paper`')
    config = check(paper)
    assert config.difference.memory == 0 and config.grid.free_erosion == 0
    assert config.blobs.position == 'changed'
    # The paper's constants are the same in both modes: only the listed additions differ.
    from laser_tracker.parameters import PAPER_REFERENCE
    default = PipelineConfig()
    listed = {name.split('.', 1)[1] for node in PAPER_REFERENCE.values() for name in node}
    for section in ('hypotheses', 'kalman', 'grid', 'difference', 'blobs'):
        for key, value in vars(getattr(config, section)).items():
            if value != getattr(getattr(default, section), key):
                assert key in listed, f'{section}.{key} differs but is not a listed addition'
    assert config.hypotheses.w_inc == 60.0 and config.hypotheses.confirm_samples == 4


def test_rendering_is_a_ros_parameter_file_that_loads_back_to_the_defaults(tmp_path):
    text = render_defaults()
    doc = yaml.safe_load(text)
    assert list(doc) == list(NODE_SECTIONS)
    for node, sections in NODES.items():
        assert list(doc[node]) == ['ros__parameters']
        assert set(sections) <= set(doc[node]['ros__parameters'])
    assert doc['sick_lms_driver']['ros__parameters']['baud'] == 38400
    assert doc['active_head']['ros__parameters']['head']['max_lead'] == 3.0
    path = tmp_path / 'p.yaml'
    path.write_text(text)
    assert PipelineConfig.load(path) == PipelineConfig()
    assert check(path) == PipelineConfig()
    entries = {e.key: e.params for e in read_parameter_file(path)}
    assert entries['tracking']['hypotheses.w_inc'] == 60.0


def test_write_and_check_on_the_command_line(tmp_path, capsys):
    out = tmp_path / 'written.yaml'
    assert main(['config', '--write', str(out)]) == 0
    assert out.read_text() == render_defaults()
    assert main(['config', '--check', str(out)]) == 0
    assert 'all defaults' in capsys.readouterr().out
    changed = out.read_text().replace('w_inc: 60.0', 'w_inc: 55.0')
    out.write_text(changed)
    assert main(['config', '--check', str(out)]) == 0
    assert 'hypotheses.w_inc = 55.0' in capsys.readouterr().out


def test_check_refuses_bad_files_with_the_reason(tmp_path, capsys):
    cases = {
        'range': ('gate: 0.7', 'gate: 70.0', 'hypotheses.gate'),
        'type': ('confirm_samples: 4', 'confirm_samples: four', 'confirm_samples'),
        'unknown': ('w_inc: 60.0', 'w_inc: 60.0\n      w_extra: 1.0', 'w_extra'),
        'choice': ("mode: paper", "mode: particle", 'kalman.mode'),
    }
    for name, (old, new, needle) in cases.items():
        path = tmp_path / f'{name}.yaml'
        text = render_defaults()
        assert old in text, old
        path.write_text(text.replace(old, new))
        assert main(['config', '--check', str(path)]) == 2, name
        assert needle in capsys.readouterr().err, name
    empty = tmp_path / 'other.yaml'
    empty.write_text('someone_else:\n  ros__parameters:\n    x: 1\n')
    assert main(['config', '--check', str(empty)]) == 2
    assert 'configures none of the nodes' in capsys.readouterr().err
    assert main(['config', '--check', str(tmp_path / 'missing.yaml')]) == 2


def test_a_binary_or_missing_file_is_a_clear_error(tmp_path, capsys):
    binary = tmp_path / 'image.yaml'
    binary.write_bytes(bytes(range(256)) * 4)
    assert main(['config', '--check', str(binary)]) == 2
    assert 'not a text file' in capsys.readouterr().err
    assert main(['config', '--check', str(tmp_path / 'missing.yaml')]) == 2
    assert 'cannot read' in capsys.readouterr().err
