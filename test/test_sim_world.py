"""The simulated world and SICK LMS: ray casting, range noise, no-returns, timing."""
import math

import numpy as np
import pytest

from laser_tracker.tools.sim.agents import PathBuilder
from laser_tracker.tools.sim.lidar import MIRROR_HZ, Lidar, LidarConfig
from laser_tracker.tools.sim.recorder import Scenario, record
from laser_tracker.tools.sim.world import World, cast, clearance, ray_circle_distances


def _wall_scenario(duration=40.0, **lidar):
    world = World().wall(3.0, -10.0, 3.0, 10.0)             # a wall 3 m ahead, across
    platform = PathBuilder(0.0, 0.0, 0.0, 0.0).wait(duration + 2.0).build()
    return Scenario(name='wall', seed=7, description='', world=world, platform=platform,
                    duration=duration, lidar=LidarConfig(**lidar))


def test_beam_against_a_wall_returns_its_distance_within_the_noise():
    rec = record(_wall_scenario(dropout_probability=0.0, spurious_probability=0.0))
    ranges = np.array([s.ranges for s in rec.scans])         # (200 scans, 361 beams)
    angles = rec.scans[0].angles
    assert ranges.shape == (200, 361)
    ahead = np.abs(angles) < math.radians(60)                 # wall within 6 m
    expected = 3.0 / np.cos(angles[ahead])
    err = ranges[:, ahead] - expected
    n = err.size
    assert abs(err.mean()) < 3 * 0.01 / math.sqrt(n) + 1e-4  # unbiased (mm rounding aside)
    assert 0.0095 < err.std() < 0.0105                        # sigma = 1 cm
    centre = ranges[:, 180]
    assert angles[180] == pytest.approx(0.0)
    assert abs(centre.mean() - 3.0) < 0.003
    assert 0.007 < centre.std() < 0.013


def test_no_return_reads_exactly_range_max_and_is_invalid():
    rec = record(_wall_scenario(duration=2.0, spurious_probability=0.0))
    scan = rec.scans[0]
    far = np.abs(scan.angles) > math.radians(70)              # wall beyond 8 m there
    assert scan.range_max == 8.0
    assert np.all(scan.ranges[far] == 8.0)
    assert not scan.valid()[far].any()
    assert scan.valid()[np.abs(scan.angles) < math.radians(60)].mean() > 0.98


def test_dropouts_and_spurious_returns_happen_at_their_rates():
    rec = record(_wall_scenario(duration=40.0, dropout_probability=0.02,
                                spurious_probability=0.01))
    ranges = np.array([s.ranges for s in rec.scans])
    angles = rec.scans[0].angles
    ahead = ranges[:, np.abs(angles) < math.radians(60)]
    expected = 3.0 / np.cos(angles[np.abs(angles) < math.radians(60)])
    dropped = np.mean(ahead == 8.0)
    short = np.mean(ahead < expected - 0.1)
    assert dropped == pytest.approx(0.02, abs=0.004)
    assert short == pytest.approx(0.01 * 0.98, abs=0.003)


def test_circle_and_segment_hits_are_the_nearest_surface():
    origins = np.zeros((3, 2))
    dirs = np.array([[1.0, 0.0], [0.0, 1.0], [-1.0, 0.0]])
    d = ray_circle_distances(origins, dirs, np.array([[2.0, 0.0, 0.5], [0.0, -3.0, 0.2]]))
    assert d[0, 0] == pytest.approx(1.5)
    assert np.isinf(d[1]).all() and np.isinf(d[2]).all()
    segs = np.array([[4.0, -1.0, 4.0, 1.0], [-1.0, 2.0, 1.0, 2.0]])
    ranges, owner = cast(origins, dirs, [(segs, np.array([0, 0]))],
                         [(np.array([[2.0, 0.0, 0.5]]), np.array([7]))])
    assert ranges[0] == pytest.approx(1.5) and owner[0] == 7        # circle hides the wall
    assert ranges[1] == pytest.approx(2.0) and owner[1] == 0
    assert np.isinf(ranges[2]) and owner[2] == -1


def test_room_doors_are_gaps_and_clearance_measures_room():
    w = World().room(0.0, 0.0, 4.0, 3.0, doors=[('north', 2.0, 1.0)])
    origins = np.array([[2.0, 1.5], [1.0, 1.5]])
    dirs = np.array([[0.0, 1.0], [0.0, 1.0]])
    ranges, _ = cast(origins, dirs, [(w.segments, np.zeros(len(w.segments)))], [])
    assert np.isinf(ranges[0])                                  # through the door
    assert ranges[1] == pytest.approx(1.5)
    assert clearance(np.array([[1.0, 1.5]]), w.segments, w.circles)[0] == pytest.approx(1.0)


def test_sick_geometry_and_timing():
    lidar = Lidar()
    assert lidar.n_beams == 361
    assert lidar.angle_min == pytest.approx(-math.pi / 2)
    assert lidar.angles[-1] == pytest.approx(math.pi / 2)
    assert lidar.time_increment == pytest.approx(0.5 / 360 / MIRROR_HZ)
    assert lidar.scan_time == pytest.approx(1 / 75)
    coarse = Lidar(LidarConfig(resolution_deg=1.0, range_max=80.0))
    assert coarse.n_beams == 181 and coarse.unit == 0.01
    stamps = Lidar(LidarConfig(scan_rate_hz=143 / 30)).scan_stamps(0.5, 30.0)
    assert stamps.size == 143
    revs = stamps * MIRROR_HZ
    assert np.allclose(revs, np.round(revs))                   # on mirror revolutions
    assert set(np.round(np.diff(revs)).astype(int)) == {15, 16}


def test_readings_are_rounded_to_the_range_unit():
    rec = record(_wall_scenario(duration=1.0))
    r = rec.scans[0].ranges
    assert np.allclose(r * 1000, np.round(r * 1000), atol=1e-6)
