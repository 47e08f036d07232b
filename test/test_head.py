"""Active head: leading aim point, target choice, capture counting, head dynamics."""
import math

import numpy as np
import pytest

from laser_tracker.config import ConfigError, from_dict
from laser_tracker.core.head import HeadConfig, HeadModel, HeadPointer


def test_aims_ahead_of_a_moving_target_with_lead_capped():
    cfg = HeadConfig(command_delay=0.5, max_pan_speed=0.1, max_lead=3.0)
    pointer = HeadPointer(cfg)
    # Target 4 m to the left, walking forward at 1 m/s: the slow head needs > 3 s -> lead 3 s.
    cmd = pointer.update(0.0, (0.0, 0.0, 0.0), [(7, 0.0, 4.0, 1.0, 0.0, 80.0)])
    assert cmd.track_id == 7
    assert cmd.lead == pytest.approx(3.0)
    assert (cmd.aim_x, cmd.aim_y) == pytest.approx((3.0, 4.0))
    assert cmd.pan == pytest.approx(math.atan2(4.0, 3.0))
    # Cameras above the aim height look down.
    assert cmd.tilt < 0


def test_lead_is_delay_plus_slew_time_when_short():
    cfg = HeadConfig(command_delay=0.5, max_pan_speed=2.0)
    cmd = HeadPointer(cfg).update(0.0, (0.0, 0.0, 0.0), [(1, 3.0, 0.0, 0.0, 1.0, 50.0)])
    assert cmd.lead == pytest.approx(0.5)  # target dead ahead: no slew needed
    assert cmd.aim_y == pytest.approx(0.5)


def test_angles_are_relative_to_the_platform_heading():
    cfg = HeadConfig(command_delay=0.0)
    cmd = HeadPointer(cfg).update(0.0, (1.0, 1.0, math.pi / 2), [(1, 1.0, 3.0, 0.0, 0.0, 50.0)])
    assert cmd.pan == pytest.approx(0.0, abs=1e-9)  # straight ahead of the rotated platform


def test_keeps_target_until_captured_then_moves_on():
    cfg = HeadConfig(command_delay=0.0, capture_samples=3, selection='uncaptured_nearest')
    pointer = HeadPointer(cfg)
    near, far = (1, 2.0, 0.0, 0.0, 0.0, 50.0), (2, 5.0, 4.0, 0.0, 0.0, 90.0)
    chosen = [pointer.update(0.2 * k, (0.0, 0.0, 0.0), [near, far]).track_id for k in range(6)]
    # Three scans in view capture target 1; the head then turns to target 2 and captures it.
    assert chosen == [1, 1, 2, 2, 2, 2]
    assert pointer.captured == {1, 2}


def test_nothing_to_aim_at():
    pointer = HeadPointer()
    assert pointer.update(0.0, (0, 0, 0), []) is None
    assert pointer.update(0.0, (0, 0, 0), [(1, 50.0, 0.0, 0.0, 0.0, 90.0)]) is None  # too far
    assert pointer.update(0.0, (0, 0, 0), [(1, float('nan'), 0.0, 0.0, 0.0, 90.0)]) is None


def test_head_model_delay_and_speed_limit():
    head = HeadModel(HeadConfig(command_delay=0.5, max_pan_speed=1.0))
    head.step(0.0)
    head.command(0.0, 1.0)
    assert head.step(0.4) == pytest.approx(0.0)       # still inside the delay
    assert head.step(1.0) == pytest.approx(0.5)       # 0.5 s of slewing at 1 rad/s
    assert head.step(2.0) == pytest.approx(1.0)       # arrived, no overshoot
    assert head.sees(1.2) and not head.sees(2.0)


def test_head_config_ranges_are_enforced():
    with pytest.raises(ConfigError, match='max_lead'):
        from_dict(HeadConfig, {'max_lead': -1.0}, 'head')
    with pytest.raises(ConfigError, match='selection'):
        from_dict(HeadConfig, {'selection': 'random'}, 'head')
    assert np.isclose(from_dict(HeadConfig, {'max_lead': 2}, 'head').max_lead, 2.0)


def _walker_passing(speed=1.0, y=3.0, period=0.2, seconds=8.0):
    """A walker passing the platform from behind-left to front-left: x = -4 .. +4 at y."""
    stamps = np.arange(0.0, seconds, period)
    xs = -4.0 + speed * stamps
    tracks = [np.array([[1, x, y, speed, 0.0, 80.0]]) for x in xs]
    objects = [np.array([[7, x, y]]) for x in xs]
    return stamps, tracks, objects


def test_head_driven_by_tracks_captures_a_passing_walker():
    from laser_tracker.core.head import captured_objects, simulate_head
    stamps, tracks, objects = _walker_passing()
    poses = np.zeros((stamps.size, 3))
    pans = simulate_head(stamps, poses, tracks, HeadConfig())
    assert captured_objects(pans, poses, objects, HeadConfig()) == {7}
    # The head turned towards the walker (to the left), ahead of it.
    assert pans.max() > 0.5


def test_a_head_too_slow_to_catch_up_misses_a_fast_passer():
    from laser_tracker.core.head import captured_objects, simulate_head
    slow = HeadConfig(max_pan_speed=0.05, command_delay=1.0)
    stamps, tracks, objects = _walker_passing(speed=1.5, y=1.5, seconds=4.0)
    poses = np.zeros((stamps.size, 3))
    pans = simulate_head(stamps, poses, tracks, slow)
    # Straight ahead the camera sees only a narrow band the walker crosses in < 3 scans.
    assert captured_objects(pans, poses, objects, slow) == set()
    # No tracks: the head never moves, nothing is captured beyond what crosses the view.
    still = simulate_head(stamps, poses, [np.zeros((0, 6))] * stamps.size, HeadConfig())
    assert np.all(still == 0.0)
