"""The robot's own body in its scans: learnt online from returns that keep their place while
the world moves past, or given as a footprint; never hiding a person beside the robot."""
from __future__ import annotations

import math

import numpy as np
import pytest

from laser_tracker.config import ConfigError
from laser_tracker.conversions import decode_body, encode_body
from laser_tracker.core.scan import Scan
from laser_tracker.core.self_mask import SelfMask, SelfMaskConfig, footprint_polygon

N = 541                                       # 270 deg at 0.5 deg
ANGLES = np.linspace(-3 * math.pi / 4, 3 * math.pi / 4, N)
BODY = slice(0, 12)                            # the chassis, at the right end of the view


def scan_at(step: int, body=True, person=None, wall=None) -> Scan:
    """A robot driving 0.1 m per scan along x past posts every 1.5 m, 2 m to its left; its
    body at 0.4 m in the first 12 beams; optionally a person (range by beam) or a wall."""
    x = 0.1 * step
    ranges = np.full(N, np.inf)
    posts = np.arange(-30, 30) * 1.5 - x                # post positions relative to the robot
    for px in posts:
        r = math.hypot(px, 2.0)
        b = int(round((math.atan2(2.0, px) - ANGLES[0]) / (ANGLES[1] - ANGLES[0])))
        if 0 <= b < N and r < 8:
            ranges[max(b - 1, 0):b + 2] = r
    if wall is not None:                                 # a wall parallel to the motion
        side = ANGLES < -0.2
        ranges[side] = np.minimum(ranges[side], wall / np.abs(np.sin(ANGLES[side])))
    if body:
        ranges[BODY] = 0.4 + 0.002 * np.cos(step)       # a few mm of noise
    if person is not None:
        for b, r in person.items():
            ranges[b] = r
    return Scan(stamp=0.1 * step, ranges=ranges, angle_min=float(ANGLES[0]),
                angle_increment=float(ANGLES[1] - ANGLES[0]), range_min=0.05, range_max=20.0)


def drive(mask: SelfMask, steps: int, speed=0.1, **kw) -> None:
    for k in range(steps):
        mask.learn(scan_at(k, **kw), (speed, 0.0, 0.0))


def test_the_body_is_learnt_once_the_world_moved_past_it():
    mask = SelfMask(SelfMaskConfig(travel=2.0))
    drive(mask, 10)                                      # 1 m: not yet
    assert not mask.mask(scan_at(10))[BODY].any()
    drive(mask, 30)                                      # 3 m: learnt
    masked = mask.mask(scan_at(40))
    assert masked[BODY].all()
    assert masked.sum() <= 12 + 3                        # the body and its edge beams only
    out, _ = mask.apply(scan_at(40))
    assert np.isnan(out.ranges[BODY]).all()


def test_a_standing_robot_learns_nothing():
    mask = SelfMask(SelfMaskConfig(travel=0.5))
    for k in range(50):
        mask.learn(scan_at(0), (0.0, 0.0, 0.0))
    assert not mask.mask(scan_at(0)).any()


def test_a_person_next_to_the_robot_is_never_hidden():
    """Beyond the body in the same beams (a person standing beside the robot), and in beams
    where no body was seen, returns stay."""
    mask = SelfMask(SelfMaskConfig(travel=1.0))
    drive(mask, 30)
    person = {5: 0.6, 6: 0.6, 7: 0.62, 100: 0.5, 101: 0.5}
    masked = mask.mask(scan_at(31, person=person))
    assert not masked[[5, 6, 7, 100, 101]].any()


def test_a_wall_the_robot_drives_along_is_not_learnt():
    """A wall 0.5 m to the right keeps its ranges while the robot drives along it, but it
    runs out of reach: it is the world, not the body."""
    mask = SelfMask(SelfMaskConfig(travel=1.0))
    drive(mask, 40, body=False, wall=0.5)
    assert not mask.mask(scan_at(40, body=False, wall=0.5)).any()


def test_a_footprint_masks_returns_inside_it():
    config = SelfMaskConfig(learn=False,
                            footprint='[[0.3, 0.3], [-0.5, 0.3], [-0.5, -0.3], [0.3, -0.3]]')
    mask = SelfMask(config, mount=(0.2, 0.0, 0.0))        # the scanner 0.2 m ahead of base
    scan = scan_at(0, body=False)
    ranges = scan.ranges.copy()
    back = np.argmin(np.abs(ANGLES - 3 * math.pi / 4))    # a beam pointing back over the body
    ranges[back] = 0.3
    ranges[back - 1] = 1.2                                # beyond the footprint
    scan.ranges = ranges
    masked = mask.mask(scan)
    assert masked[back] and not masked[back - 1]


@pytest.mark.parametrize('text', ['[[0, 0], [1, 0]]', 'not a polygon', '[[0, 0], [1, 1], [2, 2]]',
                                  '[[0, 0], [1, 0], [nan, 1]]', '[1, 2, 3]'])
def test_a_malformed_footprint_is_refused_naming_the_parameter(text):
    with pytest.raises(ConfigError, match='self_mask.footprint'):
        SelfMaskConfig(footprint=text)
    assert footprint_polygon('') is None


def test_the_body_survives_the_status_message():
    body = np.full(768, np.nan)
    body[3:9] = [0.1204, 0.12, 0.5, 0.51, 0.52, 0.7]
    body[760:] = 0.72
    decoded = decode_body(encode_body(body))
    assert decoded.shape == body.shape
    assert np.array_equal(np.isnan(decoded), np.isnan(body))
    ok = ~np.isnan(body)
    assert np.all(decoded[ok] >= body[ok]) and np.all(decoded[ok] - body[ok] < 0.001)
    assert encode_body(np.full(10, np.nan)) == '' and decode_body('') is None
    with pytest.raises(ValueError):
        decode_body('10|8:1 2 3 4')


def test_the_body_leaves_the_scan_match_before_it_is_learnt():
    """After a few tenths of a metre the body's returns are left out of the scan match (they
    would pull it towards standing still), long before they are masked for everyone."""
    mask = SelfMask(SelfMaskConfig(travel=2.0))
    drive(mask, 4)
    out = mask.unlearnt(scan_at(4))
    assert out[BODY].all() and out.sum() == 12
    assert not mask.mask(scan_at(4))[BODY].any()
    drive(mask, 30)
    assert not mask.unlearnt(scan_at(30)).any()           # learnt: masked instead
