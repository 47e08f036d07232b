"""The simulator's real-robot features: glass, the Hokuyo-class scanner, an off-centre turned
mount, and the hokuyo_corridor_lobby scenario's stop-and-go crowd."""
import dataclasses
import math

import numpy as np
import pytest

from laser_tracker.core.geometry import compose, transform_points
from laser_tracker.core.scan import Scan
from laser_tracker.tools.bag import read_scans
from laser_tracker.tools.data import real_recording
from laser_tracker.tools.sim.agents import PathBuilder, Person
from laser_tracker.tools.sim.lidar import Hokuyo, HokuyoConfig
from laser_tracker.tools.sim.recorder import Scenario, record
from laser_tracker.tools.sim.scenarios import REAL_ROBOT_MOUNT, build
from laser_tracker.tools.sim.world import World, cast_scene, clearance

NAME = 'hokuyo_corridor_lobby'
_CACHE = {}


def _rec():
    if NAME not in _CACHE:
        _CACHE[NAME] = record(build(NAME))
    return _CACHE[NAME]


def _rays(angles_deg, origin=(0.0, 0.0)):
    a = np.radians(np.asarray(angles_deg, dtype=float))
    return np.tile(origin, (a.size, 1)).astype(float), np.column_stack([np.cos(a), np.sin(a)])


def _static(world):
    seg, circ = world.segments, world.circles
    return [(seg, np.zeros(len(seg), dtype=np.int64))], \
        [(circ, np.zeros(len(circ), dtype=np.int64))]


# ------------------------------------------------------------------------------------ glass
def test_glass_returns_only_near_normal_incidence_and_lets_other_beams_through():
    """A pane at x = 2 in front of a wall at x = 4: within its 3 deg lobe a beam reads the
    glass, beyond it the wall behind; a person behind the glass is seen through it."""
    w = World().glass_panel(2.0, -5.0, 2.0, 5.0, lobe_deg=3.0).wall(4.0, -9.0, 4.0, 9.0)
    angles = np.array([0.0, 1.0, -2.5, 3.5, -5.0, 20.0, -40.0])
    o, d = _rays(angles)
    seg, circ = _static(w)
    r, owner, incidence = cast_scene(o, d, seg, circ, w.glass)
    cos = np.cos(np.radians(angles))
    glass = np.abs(angles) <= 3.0
    assert np.allclose(r[glass], 2.0 / cos[glass])
    assert np.allclose(r[~glass], 4.0 / cos[~glass])
    assert np.all(owner == 0)
    assert np.allclose(incidence, np.radians(np.abs(angles)))
    # A wider lobe (a dirty or coated pane) returns more of them.
    wide = World().glass_panel(2.0, -5.0, 2.0, 5.0, lobe_deg=6.0).wall(4.0, -9.0, 4.0, 9.0)
    r_wide, _, _ = cast_scene(o, d, seg, circ, wide.glass)
    assert np.allclose(r_wide[np.abs(angles) <= 6.0], 2.0 / cos[np.abs(angles) <= 6.0])
    # A leg behind the glass (owner 7), off the normal: seen through the pane.
    o, d = _rays([10.0])
    leg = np.array([[3.0, 3.0 * math.tan(math.radians(10.0)), 0.06]])
    r, owner, _ = cast_scene(o, d, seg, circ + [(leg, np.array([7]))], w.glass)
    assert owner[0] == 7 and r[0] == pytest.approx(math.hypot(*leg[0, :2]) - 0.06, abs=1e-3)
    # Without glass, cast_scene is cast.
    r0, owner0, _ = cast_scene(o, d, seg, circ, None)
    assert r0[0] == pytest.approx(4.0 / math.cos(math.radians(10.0))) and owner0[0] == 0


def test_incidence_of_segments_and_circles():
    w = World().wall(3.0, -9.0, 3.0, 9.0).circle(0.0, 4.0, 1.0)
    o, d = _rays([0.0, 30.0, -60.0, 90.0])
    seg, circ = _static(w)
    r, _, inc = cast_scene(o, d, seg, circ)
    assert np.allclose(np.degrees(inc), [0.0, 30.0, 60.0, 0.0])     # the circle head-on
    assert r[3] == pytest.approx(3.0)
    o, d = _rays([90.0], origin=(0.99, 0.0))                          # grazing the circle
    _, _, inc = cast_scene(o, d, seg, circ)
    assert np.degrees(inc[0]) > 80.0
    o, d = _rays([180.0])                                             # nothing there
    r, owner, inc = cast_scene(o, d, seg, circ)
    assert r[0] == np.inf and owner[0] == -1 and np.isnan(inc[0])


def test_glass_patch_travels_beside_the_robot_in_the_scenario():
    """Driving along the meeting room's glass front, the scan holds a short patch of 'wall'
    (10-20 beams) on the glass at the foot of the perpendicular from the scanner, which moves
    with the robot; the rest of the pane is seen through."""
    sc = build(NAME)
    h = Hokuyo(sc.lidar)
    seg, circ = _static(sc.world)
    feet = []
    for t in (5.0, 7.0, 9.0):
        laser = compose(sc.platform.pose(t), sc.mount)
        o = np.tile(laser[:2], (h.n_beams, 1))
        a = laser[2] + h.angles
        d = np.column_stack([np.cos(a), np.sin(a)])
        with_glass, _, _ = cast_scene(o, d, seg, circ, sc.world.glass)
        without, _, _ = cast_scene(o, d, seg, circ)
        patch = np.flatnonzero(with_glass < without)
        assert 10 <= patch.size <= 20
        assert np.all(np.diff(patch) == 1)                                 # one patch
        hit = o[patch] + d[patch] * with_glass[patch, None]
        assert np.allclose(hit[:, 1], 1.275)                               # on the pane
        assert abs(hit[:, 0].mean() - laser[0]) < 0.05                      # beside the scanner
        feet.append(hit[:, 0].mean())
    assert np.allclose(np.diff(feet), 0.8 * 2.0, atol=0.05)                 # at 0.8 m/s


# ----------------------------------------------------------------------------------- Hokuyo
def test_hokuyo_geometry_and_timing():
    h = Hokuyo(HokuyoConfig())
    assert h.n_beams == 768
    assert h.angle_increment == pytest.approx(2 * math.pi / 1024)
    assert h.angle_min == pytest.approx(-3 * math.pi / 4)
    assert math.degrees(h.angles[-1] - h.angles[0]) == pytest.approx(269.6, abs=0.1)
    assert h.time_increment == pytest.approx(1 / (15 * 1024))
    assert h.beam_offsets[-1] == pytest.approx(0.05, abs=1e-3)              # 50 ms sweep
    assert h.scan_time == pytest.approx(1 / 7.5)
    stamps = h.scan_stamps(0.5, 4.0)
    assert stamps.size == 30 and np.allclose(np.diff(stamps), 2 / 15)
    assert np.allclose(stamps * 15, np.round(stamps * 15))                  # on revolutions


def test_hokuyo_geometry_matches_the_real_recordings():
    path = real_recording('leg_tracker/training/positive_1_extracted.bag')
    if not path.exists():
        pytest.skip(f'real recording {path.name} is absent (see README, real recordings)')
    real = next(s for s in read_scans(path, '/training_scan') if isinstance(s, Scan))
    h = Hokuyo(HokuyoConfig())
    assert real.n_beams == h.n_beams
    assert real.angle_min == pytest.approx(h.angle_min, abs=1e-6)
    assert real.angle_increment == pytest.approx(h.angle_increment, rel=1e-6)
    assert real.time_increment == pytest.approx(h.time_increment, rel=1e-4)
    assert real.scan_time == pytest.approx(h.scan_time, rel=1e-5)
    assert real.range_max == pytest.approx(h.config.range_max)
    assert real.range_min == pytest.approx(h.config.range_min)


def test_hokuyo_readings_noise_dropouts_and_no_return():
    c = HokuyoConfig()
    h = Hokuyo(c)
    rng = np.random.default_rng(3)
    n = 20000
    true = np.full(n, 4.0)
    true[:100] = np.inf                                           # nothing there
    true[100:200] = 12.0                                          # beyond range
    r, returned = h.measure(true, rng, np.zeros(n))
    assert np.all(r[:200] == 0.0) and not returned[:200].any()    # error code, below range_min
    hit = r[200:][returned[200:]]
    assert np.std(hit - 4.0) == pytest.approx(c.noise_sigma, rel=0.05)
    assert np.allclose(hit / c.unit, np.round(hit / c.unit))      # 1 mm unit
    lost = np.mean(r[200:] == 0.0)
    assert 0.3 * c.dropout_probability < lost < 3 * c.dropout_probability
    scan = Scan(stamp=0.0, ranges=r, angle_min=h.angle_min,
                angle_increment=2 * math.pi / n, range_min=c.range_min, range_max=c.range_max)
    assert not scan.valid()[:200].any() and np.all(scan.free_ranges()[:200] == 0.0)
    # Grazing incidence loses about half the returns beyond grazing_deg, none before it.
    graze = np.full(n, math.radians(c.grazing_deg + 2.0))
    _, returned = h.measure(np.full(n, 4.0), rng, graze)
    assert 1 - returned.mean() == pytest.approx(c.grazing_dropout_probability, abs=0.03)
    steep = np.full(n, math.radians(c.grazing_deg - 2.0))
    _, returned = h.measure(np.full(n, 4.0), rng, steep)
    assert 1 - returned.mean() < 3 * (c.dropout_probability + c.spurious_probability)
    # Other conventions for a missing return.
    r, _ = Hokuyo(dataclasses.replace(c, no_return='range_max')).measure(
        np.array([np.inf]), rng)
    assert r[0] == c.range_max
    r, _ = Hokuyo(dataclasses.replace(c, no_return='inf')).measure(np.array([np.inf]), rng)
    assert r[0] == np.inf


def _exact(config: HokuyoConfig) -> HokuyoConfig:
    return dataclasses.replace(config, noise_sigma=0.0, dropout_probability=0.0,
                               spurious_probability=0.0, grazing_dropout_probability=0.0)


def test_beams_are_cast_at_their_own_time_across_the_sweep():
    """Driving at 1 m/s towards a wall, each beam sees the wall from where the scanner was
    when that beam was taken: the beam along the direction of travel, 384 steps (25 ms) into
    the sweep, reads 25 mm less than the wall's distance at the scan's stamp."""
    w = World().wall(10.0, -20.0, 10.0, 20.0)
    platform = PathBuilder(0.0, 0.0, 0.0, 0.0).go(8.0, 0.0, 1.0).build()
    sc = Scenario(name='towards_a_wall', seed=1, description='', world=w, platform=platform,
                  duration=2.0, scan_start=0.5, lidar=_exact(HokuyoConfig()))
    rec = record(sc)
    h = Hokuyo(sc.lidar)
    ahead = int(np.argmin(np.abs(h.angles)))
    for scan in rec.scans:
        t = scan.stamp + ahead * h.time_increment
        assert scan.ranges[ahead] == pytest.approx(10.0 - t, abs=1e-3)
        assert scan.ranges[ahead] < 10.0 - scan.stamp - 0.02


# ------------------------------------------------------------------------------------ mount
def test_a_known_wall_appears_where_the_mount_puts_it_in_the_scan_frame():
    """A wall at x = 3 in front of a platform at the origin, scanner 0.85 m forward, 0.24 m
    left, turned 42 deg: the beam along the platform's x axis (scan angle -42 deg) reads
    3 - 0.85; every point lies on the wall once moved by the mount, and 0.3 m or more off it
    if the scanner were taken to be at base_link."""
    x, y, yaw = REAL_ROBOT_MOUNT
    w = World().wall(3.0, -30.0, 3.0, 30.0)
    sc = Scenario(name='wall', seed=1, description='', world=w,
                  platform=PathBuilder(0.0, 0.0, 0.0, 0.0).wait(2.0).build(), duration=0.5,
                  scan_start=0.5,
                  lidar=_exact(HokuyoConfig(mount_x=x, mount_y=y, mount_yaw=yaw)))
    scan = record(sc).scans[0]
    assert scan.frame_id == 'laser'
    h = Hokuyo(sc.lidar)
    forward = int(np.argmin(np.abs(h.angles + yaw)))
    assert h.angles[forward] == pytest.approx(-yaw, abs=h.angle_increment / 2)
    expected = (3.0 - x) / math.cos(h.angles[forward] + yaw)
    assert scan.ranges[forward] == pytest.approx(expected, abs=1e-3)
    pts = scan.points()
    assert len(pts) > 100
    assert np.allclose(transform_points((x, y, yaw), pts)[:, 0], 3.0, atol=2e-3)
    assert np.abs(pts[:, 0] - 3.0).mean() > 0.3


def test_scenario_scans_land_on_the_static_world_through_the_mount():
    """In the bundled scenario, the returns of the static world (walls, glass, furniture),
    each moved by the platform's true pose when its beam was taken and by the scanner mount,
    lie on the world's surfaces; taken at base_link instead, they do not. While the robot
    turns (40 deg/s), the pose at the scan's stamp alone smears them by 0.1 m or more."""
    rec = _rec()
    sc = rec.scenario
    assert sc.mount == pytest.approx(REAL_ROBOT_MOUNT)
    solid, circles = sc.world.solid, sc.world.circles
    h = Hokuyo(sc.lidar)
    turning = []
    for k in range(0, len(rec.scans), 5):
        scan = rec.scans[k]
        valid = scan.valid()
        static = (rec.owners[k] == 0) & valid
        base = sc.platform.pose(scan.stamp + h.beam_offsets[static])
        c, s = np.cos(base[:, 2]), np.sin(base[:, 2])
        mx, my, myaw = sc.mount
        heading = base[:, 2] + myaw + h.angles[static]
        r = scan.ranges[static]
        pts = np.column_stack([base[:, 0] + c * mx - s * my + r * np.cos(heading),
                               base[:, 1] + s * mx + c * my + r * np.sin(heading)])
        off = np.abs(clearance(pts, solid, circles))
        assert np.quantile(off, 0.99) < 0.06, f'scan {k}'
        p = rec.truth[k].platform
        at_stamp = transform_points(compose((p.x, p.y, p.theta), sc.mount),
                                    scan.points())[static[valid]]
        if abs(p.omega) > 0.5:
            turning.append(np.quantile(np.abs(clearance(at_stamp, solid, circles)), 0.99))
        naive = transform_points((p.x, p.y, p.theta), scan.points())[static[valid]]
        assert np.median(np.abs(clearance(naive, solid, circles))) > 0.2
    assert turning and max(turning) > 0.1


# --------------------------------------------------------------------------------- scenario
def _truth_tracks(rec):
    """{id: (stamps, xy, speed, visible)} from the ground truth."""
    rows = {}
    for g in rec.truth:
        for o in g.objects:
            rows.setdefault(o.id, []).append((g.stamp, o.x, o.y, math.hypot(o.vx, o.vy),
                                              o.extra['visible']))
    out = {}
    for i, r in rows.items():
        t, x, y, speed, visible = (np.array(c) for c in zip(*r))
        out[i] = (t, np.column_stack([x, y]), speed, visible)
    return out


def test_stop_and_go_people_have_zero_speed_while_standing():
    """People walk in, stand (5-20 s: speed exactly 0, position fixed, in the ground truth and
    visible for part of it), and walk away."""
    rec = _rec()
    stops = 0
    for i, (t, xy, speed, visible) in _truth_tracks(rec).items():
        standing = speed == 0.0
        if not (standing.any() and (~standing).any()):
            continue
        edges = np.flatnonzero(np.diff(standing.astype(int)))
        runs = np.split(np.arange(t.size), edges + 1)
        for run in runs:
            if not standing[run[0]] or run[0] == 0 or run[-1] == t.size - 1:
                continue                                   # walk -> stand -> walk only
            assert np.ptp(xy[run], axis=0).max() == 0.0, f'person {i} drifts while standing'
            length = t[run[-1]] - t[run[0]]
            assert 4.0 < length < 21.0
            assert speed[run[0] - 1] > 0.5 and speed[run[-1] + 1] > 0.5
            if visible[run].any():
                stops += 1
    assert stops >= 4


def test_groups_walk_abreast_and_someone_walks_alongside_the_robot():
    sc = build(NAME)
    people = [a for a in sc.agents if isinstance(a, Person)]
    # Groups: people who enter together and walk side by side (0.5-0.9 m apart, same heading).
    groups = {}
    for a in people:
        groups.setdefault(a.trajectory.t_start, []).append(a)
    sizes = []
    for t0, members in groups.items():
        if len(members) < 2:
            continue
        t = t0 + 4.0
        xy = np.array([m.centre(t) for m in members])
        v = np.array([m.velocity(t) for m in members])
        gaps = np.sort(np.linalg.norm(xy[:, None] - xy[None], axis=-1)[np.triu_indices(len(xy), 1)])
        if gaps[0] < 0.9 and np.all(np.linalg.norm(v - v.mean(axis=0), axis=1) < 0.1):
            sizes.append(len(members))
    assert sorted(sizes)[-2:] == [2, 3]
    # Alongside: someone within 1.2 m of the platform, at its velocity, for 5 s or more.
    t = np.arange(0.0, sc.scan_start + sc.duration, 0.1)
    robot_v = sc.platform.velocity(t)[:, :2]
    best = 0.0
    for a in people:
        near = (np.linalg.norm(a.centre(t) - sc.platform.position(t), axis=1) < 1.2) & \
            (np.linalg.norm(a.velocity(t) - robot_v, axis=1) < 0.05) & \
            (np.linalg.norm(robot_v, axis=1) > 0.5) & a.trajectory.exists(t)
        best = max(best, near.sum() * 0.1)
    assert best >= 5.0


def test_people_keep_clear_of_the_robot_and_the_robot_of_the_walls():
    sc = build(NAME)
    t = np.arange(0.0, sc.scan_start + sc.duration, 0.05)
    base = sc.platform.pose(t)
    laser = np.array([compose(p, sc.mount) for p in base])
    assert clearance(laser[:, :2], sc.world.solid, sc.world.circles).min() > 0.4
    for a in sc.agents:
        ok = a.trajectory.exists(t)
        assert np.linalg.norm(a.centre(t[ok]) - base[ok, :2], axis=1).min() > 0.8
        assert np.linalg.norm(a.centre(t[ok]) - laser[ok, :2], axis=1).min() > 0.6


def test_scenario_drives_corridor_doorway_and_turns():
    sc = build(NAME)
    rec = _rec()
    theta = sc.platform.poses[:, 2]
    assert np.ptp(theta) >= math.pi / 2 - 1e-9                             # turns
    travelled = np.sum(np.linalg.norm(np.diff(sc.platform.poses[:, :2], axis=0), axis=1))
    assert travelled > 20.0
    assert 7.4 < 1.0 / np.mean(np.diff([s.stamp for s in rec.scans])) < 7.6
    assert all(s.n_beams == 768 and s.range_max == 11.0 for s in rec.scans)
    assert len(sc.world.glass) >= 10
