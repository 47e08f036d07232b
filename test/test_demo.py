"""``laser-tracker demo``: bundled recording lookup, and the whole demo on a small bundled bag."""
from __future__ import annotations

import csv
import json
import re
from pathlib import Path

import pytest

from laser_tracker.errors import InputFileError
from laser_tracker.tools import bag as bag_io

REPO = Path(__file__).resolve().parents[1]


def test_resolve_bag_finds_a_bundled_name_in_the_bag_folders(tmp_path, monkeypatch):
    share = tmp_path / 'share' / 'laser_tracker' / 'bags'
    (share / 'exp9_example').mkdir(parents=True)
    monkeypatch.setattr(bag_io, 'bag_folders', lambda: [tmp_path / 'nothing', share])
    assert bag_io.resolve_bag('exp9_example') == share / 'exp9_example'
    assert bag_io.resolve_bag('bags/exp9_example') == share / 'exp9_example'
    existing = tmp_path / 'mine'
    existing.mkdir()
    assert bag_io.resolve_bag(existing) == existing  # a path that exists is used as given
    with pytest.raises(InputFileError, match='exp9_example') as info:
        bag_io.resolve_bag('no_such_recording')
    assert 'no_such_recording' in str(info.value)


def test_bag_folders_include_the_source_tree():
    assert REPO / 'bags' in bag_io.bag_folders()


def test_demo_on_an_unknown_recording_is_a_clear_error(capsys):
    from laser_tracker.tools.cli import main
    assert main(['demo', 'no_such_recording_anywhere']) == 2
    assert 'no_such_recording_anywhere' in capsys.readouterr().err


def _smallest_bundled_bag():
    bags = [p for p in (REPO / 'bags').glob('*') if p.is_dir() and any(p.glob('*'))]
    if not bags:
        pytest.skip('no bundled recordings in bags/ yet (`make bags` writes them)')
    return min(bags, key=lambda p: sum(f.stat().st_size for f in p.rglob('*') if f.is_file()))


def test_demo_end_to_end_on_a_small_bundled_bag(tmp_path, capsys):
    from laser_tracker.tools.cli import main

    bag = _smallest_bundled_bag()
    out = tmp_path / 'demo'
    assert main(['demo', bag.name, '--out', str(out)]) == 0
    printed = capsys.readouterr().out
    for name in ('ego_motion.csv', 'tracks.csv', 'evaluation.json'):
        assert (out / name).is_file(), name
    # every track printed as confirmed is a confirmed track of tracks.csv, and vice versa
    shown = {int(m) for m in re.findall(r'track\s+(\d+)\s+confirmed at', printed)}
    with open(out / 'tracks.csv', newline='') as fh:
        confirmed = {int(float(r['track_id'])) for r in csv.DictReader(fh)
                     if r['confirmed'].strip().lower() in ('1', 'true', '1.0')}
    assert shown == confirmed
    result = json.loads((out / 'evaluation.json').read_text())
    if bag_io.has_ground_truth(bag):
        assert result['mode'] == 'ground_truth' and 'MOTA' in printed
        assert result['frames'] > 0
    else:
        assert result['mode'] == 'unlabelled' and 'no ground truth' in printed
    listed = re.findall(r'^  (\S+\.png)$', printed, flags=re.M)
    assert listed and all(Path(p).is_file() for p in listed)
