"""The robot's own body in its scans: learnt online from returns that keep their place while
the world moves past, or given as a footprint; never hiding a person beside the robot."""
from __future__ import annotations

import math

import numpy as np
import pytest

from laser_tracker.config import ConfigError
from laser_tracker.conversions import decode_body, encode_body
from laser_tracker.core.scan import Scan, beams_jitter, geometry_of, nearest_beams
from laser_tracker.core.self_mask import SelfMask, SelfMaskConfig, footprint_polygon
from laser_tracker.tools.data import real_recording

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


def on_beams(scan: Scan, more: int, first_shift: int = 0) -> Scan:
    """``scan`` as a driver that publishes each revolution's samples as they came would:
    ``more`` beams more (or fewer) over its field, the increment recomputed to fit, the
    first ``first_shift`` beams later; each beam reads the nearest beam of ``scan``."""
    n = scan.n_beams + more
    first = scan.angle_min + first_shift * scan.angle_increment
    inc = (scan.angles[-1] - first) / (n - 1)
    angles = first + inc * np.arange(n)
    nearest = np.clip(np.rint((angles - scan.angle_min) / scan.angle_increment), 0,
                      scan.n_beams - 1).astype(int)
    return Scan(stamp=scan.stamp, ranges=scan.ranges[nearest], angle_min=first,
                angle_increment=inc, range_min=scan.range_min, range_max=scan.range_max)


def test_beams_that_jitter_are_told_from_another_configuration():
    base = (float(ANGLES[0]), float(ANGLES[1] - ANGLES[0]), N)
    for more, shift in ((3, 0), (-3, 0), (1, 1), (-2, -1)):
        assert beams_jitter(base, geometry_of(on_beams(scan_at(0), more, shift)))
    assert not beams_jitter(base, (base[0], base[1] * 2, (N + 1) // 2))      # half the beams
    assert not beams_jitter(base, (base[0] + 0.3, base[1], N - 60))          # 30 deg less
    assert not beams_jitter(base, (-base[0], -base[1], N))                   # turned over
    index, inside = nearest_beams(base, (base[0] - base[1], base[1], N))     # one beam before
    assert not inside[0] and inside[1:].all() and (index[1:] == np.arange(N - 1)).all()


def test_the_body_stays_learnt_while_the_beam_count_changes_from_scan_to_scan():
    """A driver whose beam count varies by a few from scan to scan: the body learnt on one
    scan's beams is carried to the next scan's (nearest beam), not learnt afresh each time;
    a scanner set to another resolution starts afresh."""
    mask = SelfMask(SelfMaskConfig(travel=2.0))
    rng = np.random.default_rng(0)
    for k in range(40):
        more = int(rng.integers(-3, 4))
        mask.learn(on_beams(scan_at(k), more, int(rng.integers(-1, 2))), (0.1, 0.0, 0.0))
    for more in (-3, 0, 3):
        scan = on_beams(scan_at(40), more)
        masked = mask.mask(scan)
        body = scan.ranges < 0.45
        assert body.sum() >= 11 and masked[body].all()
        assert masked.sum() <= body.sum() + 6                  # the body and its edge beams
    half = scan_at(40).every_nth_beam(2)
    assert not mask.mask(half).any()                           # another configuration


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


# ------------------------------------------------------------------ mixed returns at edges

HOKUYO_STEP = math.radians(270.0 / 768)


def edge_scan(near: float, far: float, edge_at: int, n: int = 120, near_first=True) -> Scan:
    """``near`` m on one side of beam ``edge_at``, ``far`` m on the other."""
    ranges = np.full(n, far)
    if near_first:
        ranges[:edge_at] = near
    else:
        ranges[edge_at:] = near
    return Scan(stamp=0.0, ranges=ranges, angle_min=-1.0, angle_increment=HOKUYO_STEP,
                range_min=0.02, range_max=30.0)


@pytest.mark.parametrize('near_first', [True, False])
def test_returns_beside_a_near_edge_are_masked_as_far_as_the_beam_width_spans(near_first):
    """A body edge 0.7 m away, a wall 6 m behind: int(0.03 / (0.7 m x 0.352 deg)) = 6 beams on
    the wall's side are partly blocked (either side of the scan); the rest of the wall and
    the edge itself stay."""
    scan = edge_scan(0.7, 6.0, 60, near_first=near_first)
    mask = SelfMask(SelfMaskConfig(learn=False, beam_width=0.03))
    out, masked = mask.apply(scan)
    expect = np.zeros(scan.n_beams, bool)
    if near_first:
        expect[60:66] = True
    else:
        expect[54:60] = True
    np.testing.assert_array_equal(masked, expect)
    assert np.isnan(out.ranges[masked]).all() and np.isfinite(out.ranges[~masked]).all()
    # Detection masks returns up to masked_ranges (the ego_motion topic's self_mask).
    assert (scan.ranges[masked] <= mask.masked_ranges[masked]).all()
    assert np.isnan(mask.masked_ranges[~masked]).all()


def test_a_far_edge_a_smooth_surface_and_missing_returns_mask_nothing():
    mask = SelfMask(SelfMaskConfig(learn=False, beam_width=0.03))
    # An edge 5 m away: 3 cm is less than the beam spacing there.
    assert not mask.apply(edge_scan(5.0, 8.0, 60))[1].any()
    # A small range step on one surface (a grazing wall): no edge.
    smooth = edge_scan(2.0, 2.2, 60)
    assert not mask.apply(smooth)[1].any()
    # Beams without a return next to a near edge: nothing to mask, nothing raised.
    for bad in (np.nan, np.inf, -np.inf, 0.0, -1.0):
        scan = edge_scan(0.5, 6.0, 60)
        scan.ranges[60:70] = bad
        masked = mask.apply(scan)[1]
        assert not masked[:60].any() and not masked[60:70].any()
    # beam_width 0 (the paper): nothing.
    assert not SelfMask(SelfMaskConfig(learn=False, beam_width=0.0)).apply(
        edge_scan(0.7, 6.0, 60))[1].any()


@pytest.mark.parametrize('n', [1, 2, 3])
def test_mixed_returns_of_tiny_scans(n):
    scan = Scan(stamp=0.0, ranges=np.array([0.3, 5.0, 5.0][:n]), angle_min=0.0,
                angle_increment=HOKUYO_STEP, range_min=0.02, range_max=30.0)
    masked = SelfMask(SelfMaskConfig(learn=False)).apply(scan)[1]
    assert masked.shape == (n,) and masked[0] == False  # noqa: E712
    assert masked[1:].all()


def test_a_person_beside_the_body_edge_keeps_the_beams_beyond_the_beam_width():
    """A leg 0.8 m away right beside the body's edge at 0.4 m: the beam width spans
    int(0.03 / (0.4 x 0.5 deg)) = 8 of its beams; the beams beyond still see it."""
    person = {b: 0.8 for b in range(12, 40)}
    masked = SelfMask(SelfMaskConfig(learn=False)).apply(scan_at(0, person=person))[1]
    assert masked[12:20].all()
    assert not masked[20:40].any()


NEGATIVE = real_recording('leg_tracker/training/negative_2.bag')


@pytest.mark.skipif(not NEGATIVE.exists(), reason=f'{NEGATIVE} not found (real data lives '
                    'beside the repository)')
def test_the_spur_beside_the_real_robots_body_edge_is_masked():
    """leg_tracker's robot, right scanner, while it drives: its body at 0.17-0.7 m in the
    first beams, then the wall 7 m away; the first returns past the body's edge form a spur
    up to 0.4 m in front of the wall that keeps its bearing (it became a track that rode
    along the wall). Those beams are masked; the wall beyond the beam's width is not."""
    from laser_tracker.conversions import scan_from_msg
    from laser_tracker.tools.bag import iter_messages

    for k, (_, _, msg) in enumerate(iter_messages(NEGATIVE, ['/right_scan'])):
        if k == 75:
            scan = scan_from_msg(msg)
            break
    r = scan.ranges
    edge = int(np.flatnonzero(r[:40] > 3.0)[0])           # the first return past the body
    spur = np.flatnonzero(r[edge:edge + 10] < r[edge + 10] - 0.2) + edge
    assert spur.size >= 2, r[:40]
    masked = SelfMask(SelfMaskConfig(learn=False)).apply(scan)[1]
    assert masked[spur].all()
    assert not masked[edge + 30:edge + 60].any()


def _noisy(scan: Scan, sigma: float, rng) -> Scan:
    import dataclasses
    return dataclasses.replace(scan, ranges=scan.ranges + rng.normal(0.0, sigma, N))


@pytest.mark.parametrize('sigma', [0.005, 0.02, 0.05])
def test_the_range_noise_near_the_robot_is_measured_from_one_scan(sigma):
    """The second differences of consecutive returns within reach give the noise; the edges
    between surfaces (here the body's against the far posts) do not move it."""
    from laser_tracker.core.self_mask import range_noise
    rng = np.random.default_rng(1)
    ranges = np.full(N, np.inf)
    ranges[:60] = 0.4 + 0.2 * np.sin(np.linspace(0, 2, 60))     # a curved body part
    ranges[60:120] = 0.8                                         # a second one, an edge apart
    noisy = ranges + rng.normal(0.0, sigma, N)
    assert range_noise(noisy, 0.05, 1.0) == pytest.approx(sigma, rel=0.25)
    assert range_noise(noisy[:10], 0.05, 1.0) is None            # too few returns near
    assert range_noise(np.full(N, np.nan), 0.05, 1.0) is None


def test_a_noisy_scanners_body_is_learnt_and_stays_masked():
    """With 5 cm of range noise (a low-cost scanner) the body's returns jump by more than
    the 5 cm tolerance from scan to scan: the tolerance follows the measured noise (three
    sigma), so the body is learnt and masked, and a person beyond it is not."""
    from laser_tracker.core import self_mask
    rng = np.random.default_rng(2)
    mask = SelfMask(SelfMaskConfig(travel=2.0))
    for k in range(40):
        mask.learn(_noisy(scan_at(k), 0.05, rng), (0.1, 0.0, 0.0))
    assert mask.range_noise == pytest.approx(0.05, rel=0.3)
    assert mask.settings[self_mask._TOLERANCE] == pytest.approx(3 * mask.range_noise)
    masked = [mask.mask(_noisy(scan_at(40 + k), 0.05, rng))[BODY].mean() for k in range(10)]
    assert np.mean(masked) > 0.95
    person = {5: 0.9, 6: 0.9, 7: 0.92}                   # 0.5 m beyond the body
    assert not mask.mask(scan_at(50, person=person))[[5, 6, 7]].any()
    # with the tolerance held at 5 cm the same body is never learnt
    held = SelfMask(SelfMaskConfig(travel=2.0, noise_sigmas=0.0))
    rng = np.random.default_rng(2)
    for k in range(40):
        held.learn(_noisy(scan_at(k), 0.05, rng), (0.1, 0.0, 0.0))
    assert held.mask(_noisy(scan_at(40), 0.05, rng))[BODY].mean() < 0.5


def test_the_range_noise_survives_the_status_message():
    """ego_motion/status carries the range noise the self-mask measured ('' before)."""
    from laser_tracker.conversions import ego_motion_from_msgs, ego_motion_to_msgs, ros_factory
    from laser_tracker.core.difference import PoseQuality
    from laser_tracker.core.stages import StampedPose

    factory = ros_factory()
    for noise in (0.0312, None):
        pose = StampedPose(stamp=1.0, pose=np.zeros(3), motion=np.zeros(3),
                           motion_covariance=np.zeros((3, 3)), pose_covariance=np.zeros((3, 3)),
                           quality=PoseQuality(), range_noise=noise)
        back = ego_motion_from_msgs(*ego_motion_to_msgs(factory, pose))
        assert back.range_noise == noise
    odometry, status = ego_motion_to_msgs(factory, pose)
    next(kv for kv in status.status[0].values if kv.key == 'range_noise').value = 'x'
    with pytest.raises(ValueError, match='range_noise'):
        ego_motion_from_msgs(odometry, status)
