"""``laser-tracker animate RUN``: a GIF of the scans with the tracks, from a replay folder."""
from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from laser_tracker.tools.cli import main

ROOT = Path(__file__).resolve().parents[1]


def run(*argv) -> int:
    return main([str(a) for a in argv])


@pytest.fixture(scope='module')
def replayed(tmp_path_factory):
    out = tmp_path_factory.mktemp('animate') / 'run'
    assert run('replay', 'exp1_stationary_single_walker', '--out', out, '--no-progress') == 0
    return out


def frames_of(path: Path) -> list[np.ndarray]:
    from PIL import Image, ImageSequence

    with Image.open(path) as im:
        assert im.format == 'GIF'
        return [np.asarray(f.convert('RGB')) for f in ImageSequence.Iterator(im)]


def kind_pixels(frame: np.ndarray, kind: str) -> int:
    from laser_tracker.conversions import KIND_COLOURS

    rgb = np.array(KIND_COLOURS[kind]) * 255
    return int((np.abs(frame.astype(float) - rgb).max(axis=2) < 40).sum())


def test_gif_has_one_frame_per_time_step_with_the_track_drawn(replayed, capsys):
    gif = replayed / 'walk.gif'
    assert run('animate', replayed, '--out', gif, '--start', 2, '--end', 12, '--fps', 5,
               '--size', 200) == 0
    assert 'frames at 5 fps' in capsys.readouterr().out
    frames = frames_of(gif)
    assert len(frames) == 51 and frames[0].shape == (200, 200, 3)   # 10 s at 5 frames per s
    # the walker is a person track (magenta) in most frames, and it moves between frames
    with_track = [f for f in frames if kind_pixels(f, 'person') > 20]
    assert len(with_track) > 25
    assert any((a != b).any() for a, b in zip(frames, frames[1:]))


def test_speed_and_follow_change_the_frames(replayed):
    fast, follow = replayed / 'fast.gif', replayed / 'follow.gif'
    assert run('animate', replayed, '--out', fast, '--end', 20, '--speed', 4, '--size',
               128) == 0
    assert len(frames_of(fast)) == 51                  # 20 s at 4x: 5 s of 10 frames per s
    assert run('animate', replayed, '--out', follow, '--end', 20, '--speed', 4, '--size',
               128, '--follow') == 0
    # the scanner stands still here, so only the view's orientation differs
    assert any((a != b).any() for a, b in zip(frames_of(fast), frames_of(follow)))


@pytest.mark.skipif(shutil.which('ffmpeg') is None, reason='ffmpeg is not installed')
def test_mp4_with_ffmpeg(replayed):
    mp4 = replayed / 'walk.mp4'
    assert run('animate', replayed, '--out', mp4, '--end', 3, '--size', 160) == 0
    assert mp4.read_bytes()[4:8] == b'ftyp'


def test_scans_from_a_recording_of_the_run(tmp_path):
    out, rec = tmp_path / 'run', tmp_path / 'rec'
    assert run('replay', 'exp3_rotating_static', '--out', out, '--record', rec,
               '--record-grids', 'none', '--no-progress') == 0
    summary = json.loads((out / 'summary.json').read_text())
    summary['bag'] = str(tmp_path / 'gone')             # the input moved away
    (out / 'summary.json').write_text(json.dumps(summary))
    assert run('animate', out, '--recording', rec, '--end', 2, '--size', 96) == 0
    assert len(frames_of(out / 'animation.gif')) == 21


def test_bad_inputs_are_one_line_errors(replayed, tmp_path, capsys):
    from laser_tracker.tools.bag import FACTORY, BagWriter
    from laser_tracker.conversions import PlanarOdometry, odometry_to_msg

    no_scans = tmp_path / 'odom_only'
    with BagWriter(no_scans) as bag:
        bag.write('/odom', odometry_to_msg(FACTORY, PlanarOdometry(1.0, 0, 0, 0)), 1.0)
    cases = [
        ((replayed, '--recording', no_scans), 'has no LaserScan topic to animate'),
        ((replayed, '--out', tmp_path / 'a.png'), 'a .gif or an .mp4'),
        ((replayed, '--start', 1000), 'the replay covers only'),
        ((replayed, '--fps', 0), '--fps must be positive'),
        ((replayed, '--recording', 'exp2_translating_static'), 'replayed from this recording?'),
        ((tmp_path / 'nothing',), 'no such replay folder'),
    ]
    for argv, message in cases:
        assert run('animate', *argv) == 2
        err = capsys.readouterr().err.strip()
        assert len(err.splitlines()) == 1 and message in err, err
    assert not (tmp_path / 'a.png').exists()
