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
