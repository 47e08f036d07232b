"""The named scenarios: the paper's experiments (METHOD.md, "Experiments") and harder scenes.

Each is a function ``name(seed) -> Scenario``. The layout and the paths are fixed (they
reproduce an experiment); the seed draws the details: furniture jitter and clutter, each
person's legs (radius 5-7 cm, 12-20 cm apart), the range noise, dropouts and
spurious returns, and the odometry noise and jitter. Frames: the world frame is ``map``; the
platform starts at the pose its trajectory gives at t = 0, where ``odom`` coincides with
``map``. The paper's experiments have a SICK LMS at the platform's origin;
``hokuyo_corridor_lobby`` mirrors a real robot instead: a Hokuyo-class scanner mounted off
the origin and turned (``Scenario.mount``, recorded on /tf_static), glass, and a crowd that
stops and goes; ``driving_past_people`` a robot that drives at 1 m/s along long walls past
people who walk and stand, with a scanner that loses its returns at grazing incidence, writes
them as +inf, NaN or 0, and sees parts of the robot's own body.
"""
from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from laser_tracker.tools.sim.agents import GaitConfig, PathBuilder, Person, Robot
from laser_tracker.tools.sim.lidar import HokuyoConfig, LidarConfig
from laser_tracker.tools.sim.platform import OdometryConfig
from laser_tracker.tools.sim.recorder import Scenario
from laser_tracker.tools.sim.world import World

DEG = math.pi / 180.0
# The 55 s recordings carry odometry at 25 Hz instead of 50 Hz: an Odometry message is 724
# bytes (two 36-double covariances), and 55 s at 50 Hz alone would be 2 MB of the 3 MB budget.
LONG_RUN_ODOMETRY_HZ = 25.0


def _doc(func) -> str:
    return ' '.join(func.__doc__.split())


def _scene_rng(seed: int) -> np.random.Generator:
    return np.random.default_rng([seed, 0])


def _person(rng: np.random.Generator, id: int, path: PathBuilder) -> Person:
    gait = GaitConfig(leg_radius=float(rng.uniform(0.05, 0.07)),
                      leg_spacing=float(rng.uniform(0.12, 0.20)))
    return Person(id, path.build(), gait)


def _walk(t0: float, start, *moves) -> PathBuilder:
    """A walker's path: ``moves`` are ``(x, y, speed)`` legs or a float pause (s).

    A turn of more than 45 deg between two legs without a pause is rounded off the way
    people walk it: the corner is cut 0.35 m (at most 40 % of either leg) before and after.
    """
    pts = [(float(start[0]), float(start[1]))] + [(m[0], m[1]) for m in moves
                                                 if not isinstance(m, (int, float))]
    plan, idx = [], 0
    for m in moves:
        if isinstance(m, (int, float)):
            plan.append(float(m))
            continue
        idx += 1
        plan.append((idx, m[2]))
    b = PathBuilder(t0, *start)
    for n, item in enumerate(plan):
        if isinstance(item, float):
            b.wait(item)
            continue
        i, speed = item
        nxt = plan[n + 1] if n + 1 < len(plan) else None
        p0, p1 = np.array(b.pose[:2]), np.array(pts[i])
        if isinstance(nxt, tuple):
            p2 = np.array(pts[nxt[0]])
            a, c = p1 - p0, p2 - p1
            la, lc = np.linalg.norm(a), np.linalg.norm(c)
            turn = math.acos(max(-1.0, min(1.0, float(a @ c) / (la * lc))))
            if turn > math.radians(45):
                cut = min(0.35, 0.4 * la, 0.4 * lc)
                q0, q1 = p1 - a / la * cut, p1 + c / lc * cut
                b.go(*q0, speed)
                b.go(*q1, 0.5 * (speed + nxt[1]))
                continue
        b.go(*p1, speed)
    return b


def _jitter(rng: np.random.Generator, scale: float = 0.05) -> float:
    return float(rng.uniform(-scale, scale))


def _scatter(world: World, rng: np.random.Generator, zone, count: int) -> None:
    """Small clutter (bins, bags, boxes, chairs) at random places inside ``zone``."""
    x0, y0, x1, y1 = zone
    for _ in range(count):
        x, y = float(rng.uniform(x0, x1)), float(rng.uniform(y0, y1))
        kind = int(rng.integers(4))
        if kind == 0:
            world.circle(x, y, float(rng.uniform(0.1, 0.2)))             # bin, pot
        elif kind == 1:
            world.box(x, y, float(rng.uniform(0.3, 0.6)), float(rng.uniform(0.25, 0.45)),
                      float(rng.uniform(0, math.pi)))                     # crate, bag
        elif kind == 2:
            world.chair(x, y, float(rng.uniform(0, math.pi)))
        else:
            world.circle(x, y, float(rng.uniform(0.03, 0.05)))           # coat stand, pole


def _stationary(t_end: float, pose=(0.0, 0.0, 0.0)) -> PathBuilder:
    return PathBuilder(0.0, *pose).wait(t_end)


# --------------------------------------------------------------------------------- exp1
def exp1_stationary_single_walker(seed: int = 1) -> Scenario:
    """Stationary platform in a cluttered room; one person walks 4 constant-velocity paths,
    leaves through the door for about 4 s and comes back. 30 s, 143 scans (4.77 Hz)."""
    rng = _scene_rng(seed)
    w = World()
    w.room(-0.8, -4.0, 7.0, 4.0, doors=[('north', 5.2, 0.9)])
    w.polyline([(-0.8, 4.0), (-0.8, 6.0), (10.0, 6.0)])              # corridor outside
    j = lambda: _jitter(rng)  # noqa: E731
    w.box(3.0 + j(), -3.7, 1.6, 0.6)                                 # desk, south wall
    w.chair(3.3 + j(), -2.9 + j(), 0.2 + j())
    w.table(5.8 + j(), -2.2 + j(), 1.2, 0.8)                         # meeting table
    w.chair(5.2 + j(), -1.9 + j(), 0.1 + j())
    w.chair(6.4 + j(), -1.5 + j(), 0.5 + j())
    w.chair(5.9 + j(), -3.1 + j(), 0.0 + j())
    w.box(0.8 + j(), 3.6, 1.0, 0.45)                                 # cabinet
    w.chair(1.0 + j(), 2.4 + j(), 0.4 + j())
    w.box(6.78, 1.2 + j(), 0.4, 1.8)                                 # bookshelf, east wall
    w.box(3.6 + j(), 3.4 + j(), 0.5, 0.4, 0.3)                       # boxes on the floor
    w.circle(1.2 + j(), -2.8 + j(), 0.15)                            # bin
    w.circle(6.5 + j(), 3.4 + j(), 0.2)                              # plant pot
    w.circle(0.3 + j(), -3.5 + j(), 0.04)                            # coat stand
    _scatter(w, rng, (-0.6, -3.9, 0.6, -1.5), 2)                     # beside the scanner
    _scatter(w, rng, (-0.6, 1.5, 0.6, 3.2), 2)
    duration, start = 30.0, 0.5
    end = start + duration + 1.0
    walker = _walk(0.0, (2.0, -3.0),
                   0.8,
                   (2.0, 2.8, 1.0),            # path 1: across the scanner's view, left
                   0.5,
                   (4.6, -2.4, 0.9),           # path 2: diagonal back, right
                   0.5,
                   (5.2, 4.8, 1.2),            # path 3: through the door, out of the room
                   (3.4, 5.1, 1.0),            # outside, out of sight
                   0.8,
                   (5.3, 4.9, 1.0),
                   (2.6, -3.0, 1.2))           # path 4: back in, across the room
    walker.wait_until(end)
    return Scenario(
        name='exp1_stationary_single_walker', seed=seed,
        description=_doc(exp1_stationary_single_walker),
        world=w, platform=_stationary(end).build(), agents=[_person(rng, 1, walker)],
        duration=duration, scan_start=start,
        lidar=LidarConfig(scan_rate_hz=143.0 / 30.0))


# ------------------------------------------------------------------------------- office
def _office(rng: np.random.Generator) -> World:
    """An open-plan office 16 m x 8 m: desk rows along both long walls, a central aisle."""
    w = World()
    w.room(-2.0, -4.0, 14.0, 4.0, doors=[('west', 2.5, 0.9), ('south', 13.0, 0.9),
                                         ('north', -1.0, 0.9)])
    j = lambda s=0.05: _jitter(rng, s)  # noqa: E731
    for x in (0.0, 2.0, 4.0, 6.0, 8.0, 10.0, 12.0):
        for side in (-1.0, 1.0):
            if rng.random() < 0.85:
                w.box(x + j(), side * 3.3, 1.4, 0.7)                      # desk with panels
            if rng.random() < 0.7:
                w.chair(x + j(0.3), side * (2.45 + j(0.15)), float(rng.uniform(0, math.pi)))
    w.circle(6.0, 1.8, 0.25)                                             # pillars
    w.circle(6.0, -1.8, 0.25)
    w.table(12.8 + j(), 0.0 + j(), 1.2, 0.9)                             # printer table
    w.box(-1.6, 0.0 + j(), 0.5, 1.6)                                     # cabinets, west wall
    _scatter(w, rng, (-1.5, -2.2, 13.5, -1.5), 4)
    _scatter(w, rng, (-1.5, 1.5, 13.5, 2.2), 4)
    return w


def exp2_translating_static(seed: int = 2) -> Scenario:
    """The platform translates along an office aisle (0.4 m/s, a 180 deg turn at the far
    end) for 55 s; nothing moves."""
    rng = _scene_rng(seed)
    world = _office(rng)
    duration, start = 55.0, 0.5
    path = (PathBuilder(0.0, 0.0, 0.0, 0.0).wait(start + 0.5)
            .go(10.0, 0.0, 0.4)
            .turn_by(math.pi, 45 * DEG)
            .go(0.0, 0.0, 0.4))
    path.wait_until(start + duration + 1.5)
    return Scenario(name='exp2_translating_static', seed=seed,
                    description=_doc(exp2_translating_static),
                    world=world, platform=path.build(), duration=duration, scan_start=start,
                    odometry=OdometryConfig(rate_hz=LONG_RUN_ODOMETRY_HZ))


def exp3_rotating_static(seed: int = 3) -> Scenario:
    """The platform rotates in place (25 deg/s, 500 deg) in the office for 20 s; nothing
    moves."""
    rng = _scene_rng(seed)
    world = _office(rng)
    duration, start = 20.0, 0.5
    path = (PathBuilder(0.0, 4.0, 0.0, 0.0).wait(start + 0.3)
            .turn_by(500 * DEG, 25 * DEG))
    path.wait_until(start + duration + 1.5)
    return Scenario(name='exp3_rotating_static', seed=seed,
                    description=_doc(exp3_rotating_static),
                    world=world, platform=path.build(), duration=duration, scan_start=start)


# ------------------------------------------------------------------------------ corridor
def exp4_corridor_passers(seed: int = 4) -> Scenario:
    """The platform stands at the end of a corridor; 14 people pass (0.8-1.5 m/s, two pairs
    side by side), turning into a cross corridor and office doors. 55 s."""
    rng = _scene_rng(seed)
    w = World()
    half = 1.25
    # Main corridor along x, closed behind the platform; a cross corridor at x 3.5..5.5;
    # office doors at x = 7.5 (north) and 10.5 (south).
    w.polyline([(-1.0, -half), (-1.0, half)])
    w.wall(-1.0, half, 3.5, half)
    w.wall(5.5, half, 7.05, half)
    w.wall(7.95, half, 25.0, half)
    w.wall(-1.0, -half, 3.5, -half)
    w.wall(5.5, -half, 10.05, -half)
    w.wall(10.95, -half, 25.0, -half)
    w.wall(3.5, half, 3.5, 9.0)
    w.wall(5.5, half, 5.5, 9.0)
    w.wall(3.5, -half, 3.5, -9.0)
    w.wall(5.5, -half, 5.5, -9.0)
    w.room(6.0, half, 10.0, 5.0, doors=[('south', 7.5, 0.9)])     # north office
    w.room(9.0, -5.0, 13.0, -half, doors=[('north', 10.5, 0.9)])   # south office
    j = lambda s=0.05: _jitter(rng, s)  # noqa: E731
    w.box(1.5 + j(), half - 0.25, 0.8, 0.4)                     # notice-board cabinet
    w.circle(-0.5 + j(), -half + 0.25, 0.15)                    # bin beside the platform
    w.box(8.0 + j(), 3.5 + j(), 1.4, 0.7)                       # office desks
    w.box(11.0 + j(), -3.5 + j(), 1.4, 0.7)
    w.chair(12.0 + j(), -1.9 + j(), 0.3)
    w.circle(14.0, half - 0.2, 0.12)                            # fire extinguisher
    # Lanes keep people from walking through each other: in the corridor, towards the
    # platform at y = 0.5 (pairs 0.25 / 0.85), away at y = -0.5; in the cross corridor,
    # southwards at x = 4.1 (pairs 3.85 / 4.45), northwards at x = 4.9.
    N, S = 6.5, -6.5            # out of sight in the cross corridor
    far = 11.0                  # beyond the 8 m range
    people = [
        (1.0, (far, 0.5), [(4.9, 0.5, 1.0), (4.9, N, 1.0)]),
        (4.0, (4.9, S), [(4.9, -0.5, 1.2), (far + 1, -0.5, 1.2)]),
        (8.0, (far, 0.85), [(3.85, 0.85, 1.1), (3.85, S, 1.1)]),        # side by side
        (8.0, (far, 0.25), [(4.45, 0.25, 1.1), (4.45, S, 1.1)]),
        (14.5, (4.1, N), [(4.1, S, 1.5)]),                              # fast, straight across
        (15.0, (7.5, 2.4), [(7.5, 0.5, 0.8), (2.0, 0.5, 0.8), 2.0, (4.1, 0.0, 0.8),
                            (4.1, S, 0.8)]),                            # comes up close
        (20.0, (4.9, S), [(4.9, -0.5, 1.4), (far + 1, -0.5, 1.4)]),
        (25.0, (3.85, N), [(3.85, S, 1.0)]),                            # side by side across
        (25.0, (4.45, N), [(4.45, S, 1.0)]),
        (29.0, (far, 0.5), [(2.5, 0.5, 1.3), 0.6, (4.9, 0.9, 1.3), (4.9, N, 1.3)]),
        (33.0, (10.5, -2.4), [(10.5, -0.5, 0.9), (4.9, -0.5, 0.9), (4.9, N, 0.9)]),
        (39.5, (far, 0.5), [(4.1, 0.5, 1.5), (4.1, S, 1.5)]),           # fast
        (42.0, (4.1, N), [(4.1, -0.5, 1.2), (far + 1, -0.5, 1.2)]),
        (43.0, (far, 0.5), [(4.9, 0.5, 1.0), (4.9, N, 1.0)]),           # meets the last
    ]
    agents = [_person(rng, i + 1, _walk(t0, start, *moves))
              for i, (t0, start, moves) in enumerate(people)]
    duration, start = 55.0, 0.5
    return Scenario(name='exp4_corridor_passers', seed=seed,
                    description=_doc(exp4_corridor_passers),
                    world=w, platform=_stationary(start + duration + 1.5).build(),
                    agents=agents, duration=duration, scan_start=start,
                    odometry=OdometryConfig(rate_hz=LONG_RUN_ODOMETRY_HZ))


# -------------------------------------------------------------------------------- fig8
def fig8_robot_target(seed: int = 8) -> Scenario:
    """Another robot (a 0.55 m x 0.45 m box) drives a path with turns in front of a
    stationary scanner in a lab, turning in place at the corners. 30 s."""
    rng = _scene_rng(seed)
    w = World()
    w.room(-1.0, -4.0, 9.0, 4.0, doors=[('east', 2.0, 1.0)])
    j = lambda s=0.05: _jitter(rng, s)  # noqa: E731
    w.box(2.0 + j(), 3.6, 2.0, 0.7)          # benches
    w.box(5.5 + j(), 3.6, 2.0, 0.7)
    w.box(4.0 + j(), -3.6, 3.0, 0.7)
    w.chair(2.5 + j(), 2.8 + j(), 0.2)
    w.chair(5.0 + j(), -2.8 + j(), 1.0)
    w.table(8.2 + j(), -2.5 + j(), 1.0, 1.6)
    w.circle(7.0 + j(), 3.0 + j(), 0.2)
    _scatter(w, rng, (-0.8, -3.8, 0.5, -2.0), 2)
    _scatter(w, rng, (-0.8, 2.0, 0.5, 3.8), 2)
    duration, start = 30.0, 0.5
    turn = 60 * DEG
    path = (PathBuilder(0.0, 1.5, -2.0, math.pi / 2).wait(1.5)
            .drive(1.5, 1.8, 0.5, turn)
            .drive(4.5, 1.8, 0.5, turn)
            .drive(5.5, -1.5, 0.45, turn)
            .drive(3.0, -0.8, 0.5, turn))
    path.wait_until(start + duration + 1.5)
    robot = Robot(1, path.build(), length=0.55, width=0.45)
    return Scenario(name='fig8_robot_target', seed=seed,
                    description=_doc(fig8_robot_target),
                    world=w, platform=_stationary(start + duration + 1.5).build(),
                    agents=[robot], duration=duration, scan_start=start)


# --------------------------------------------------------------------------- crossing
def crossing_walkers(seed: int = 5) -> Scenario:
    """Harder: the platform drives slowly through an atrium while six people cross in front
    of it, pass behind one another (occlusion) and walk towards it. 35 s."""
    rng = _scene_rng(seed)
    w = World()
    w.room(-4.0, -10.0, 16.0, 10.0)                              # an atrium, mostly open
    j = lambda s=0.05: _jitter(rng, s)  # noqa: E731
    for x, y in ((2.0, -3.5), (2.0, 3.5), (11.5, -3.5), (11.5, 3.5), (4.0, -7.0), (4.0, 7.0),
                 (12.5, 0.0)):
        w.circle(x + j(), y + j(), 0.3)                           # pillars
    w.box(0.25, -6.5 + j(), 6.5, 0.6)                            # reception counter
    w.box(0.5, 6.5 + j(), 5.0, 0.6)                              # display cases
    w.box(-2.5, 0.0 + j(), 0.6, 1.8)                             # benches
    w.box(4.0 + j(), 6.0, 1.8, 0.5)
    w.table(13.5 + j(), -6.0 + j(), 1.2, 0.8)
    w.circle(8.3 + j(), -5.2 + j(), 0.35)                        # planter
    w.box(-1.0 + j(), -3.0 + j(), 1.2, 0.8, 0.3)                 # information kiosk
    _scatter(w, rng, (-3.5, -5.8, -0.5, -4.5), 3)
    _scatter(w, rng, (12.5, 4.0, 15.0, 6.0), 3)
    duration, start = 35.0, 0.5
    platform = (PathBuilder(0.0, 0.0, 0.0, 0.0).wait(1.0)
                .go(2.4, 0.0, 0.3)
                .turn_by(25 * DEG, 20 * DEG)
                .go(2.4 + 2.5 * math.cos(25 * DEG), 2.5 * math.sin(25 * DEG), 0.3)
                .turn_by(-60 * DEG, 20 * DEG)
                .wait(2.0))
    platform.wait_until(start + duration + 1.5)
    # Everyone starts and ends more than 8 m from the platform (out of range).
    people = [
        (0.5, (6.0, -8.5), [(9.0, 8.5, 1.0)]),                      # X crossing, in front
        (1.99, (10.91, -6.24), [(5.6, 9.6, 1.1)]),                  # ... crossing its path
        (3.0, (13.0, 2.5), [(5.5, 2.0, 0.9), (5.5, -9.0, 0.9)]),    # towards the platform
        (3.6, (6.8, 9.5), [(7.2, -9.5, 0.7)]),                      # in front of ...
        (9.41, (9.7, 8.5), [(9.45, -8.5, 1.1)]),                    # ... this one, for ~3 s
        (19.0, (13.5, -3.0), [(7.0, -1.0, 1.2), 1.5, (8.0, 9.5, 1.2)]),
    ]
    agents = [_person(rng, i + 1, _walk(t0, s, *m)) for i, (t0, s, m) in enumerate(people)]
    return Scenario(name='crossing_walkers', seed=seed,
                    description=_doc(crossing_walkers),
                    world=w, platform=platform.build(), agents=agents, duration=duration,
                    scan_start=start)


# --------------------------------------------------------------------- real robot
# The real robots' Hokuyo-class scanners return mixed ranges beside a nearer edge: past the
# edge of leg_tracker's robot's body 0.7 m away, six beams read 0.25-0.4 m short of the wall
# 7 m behind (a few per cent of the range step).
HOKUYO_BEAM_WIDTH = 0.03


# The robot of hokuyo_corridor_lobby: a Hokuyo-class scanner on the front left corner,
# turned 42 deg to the left, as on the real robots where the tracker failed.
REAL_ROBOT_MOUNT = (0.85, 0.24, 42 * DEG)
REAL_ROBOT_ODOMETRY_HZ = 10.0


def _building(rng: np.random.Generator) -> World:
    """A corridor (x -4..18, 2.4 m wide, walls 0.15 m thick) with office doors and a
    glass-fronted meeting room on its north side (x 2.5..12.5), and at its east end a
    doorway (1.5 m, in a 0.2 m wall) into a lobby (x 18.2..31, y -6.5..7) whose south side is
    a glass facade onto the street. Door frames are the walls' end faces."""
    w = World()
    j = lambda s=0.05: _jitter(rng, s)  # noqa: E731
    yn, ys, t = 1.275, -1.275, 0.15                       # corridor wall centre lines
    # North side of the corridor: wall, door N1 (1..2), wall, the meeting room's glass front
    # (panes between mullions every 1.5 m), wall, door N3 (15..16), wall.
    for x0, x1 in ((-4.0, 1.0), (2.0, 2.5), (12.5, 15.0), (16.0, 18.0)):
        w.thick_wall(x0, yn, x1, yn, t)
    edges = [2.5, 4.0, 5.5, 7.0, 8.5, 10.0, 11.5, 12.5]
    for x in edges[1:-1]:
        w.box(x, yn, 0.1, t)                                  # mullions
    for x0, x1 in zip(edges[:-1], edges[1:]):
        w.glass_panel(x0 + (0.05 if x0 > edges[0] else 0.0), yn,
                      x1 - (0.05 if x1 < edges[-1] else 0.0), yn)
    # South side: doors S0 (-2..-1), S1 (3..4), S2 (10..11).
    for x0, x1 in ((-4.0, -2.0), (-1.0, 3.0), (4.0, 10.0), (11.0, 18.0)):
        w.thick_wall(x0, ys, x1, ys, t)
    w.wall(-4.0, -1.2, -4.0, 1.2)                            # west end of the corridor
    # Rooms around the corridor (closed; seen only through their doors and the glass).
    w.polyline([(-4.0, -1.35), (-4.0, -5.0), (18.0, -5.0)])  # south offices
    for x in (1.0, 8.0, 14.0):
        w.wall(x, -1.35, x, -5.0)
    w.box(-2.0 + j(), -4.4, 1.4, 0.7)                        # desks
    w.box(6.0 + j(), -4.4, 1.4, 0.7)
    w.box(12.0 + j(), -4.4, 1.4, 0.7)
    w.polyline([(-4.0, 1.35), (-4.0, 6.5), (18.0, 6.5)])     # north offices, building's back
    w.wall(1.5, 1.35, 1.5, 6.5)
    w.wall(2.5, 1.35, 2.5, 5.0)                              # meeting room, door (11.5..12.3)
    w.wall(12.5, 1.35, 12.5, 5.0)
    w.wall(2.5, 5.0, 11.5, 5.0)
    w.wall(12.3, 5.0, 12.5, 5.0)
    w.table(6.5 + j(), 3.6 + j(), 3.0, 1.2)                  # meeting table and chairs
    for cx in (5.6, 7.4):
        w.chair(cx + j(), 4.55 + j(), float(rng.uniform(0, math.pi)))
    w.box(15.0 + j(), 5.8, 1.4, 0.7)                         # office N3
    # The lobby: doorway in its west wall (y -1.05..0.45), north door (x 20.5..22.5) to the
    # stairs, east door (y -1..1) outside; the south side is glass, mullions every 1.6 m.
    w.thick_wall(18.1, -6.5, 18.1, -1.05, 0.2)
    w.thick_wall(18.1, 0.45, 18.1, 7.15, 0.2)
    w.thick_wall(18.0, 7.075, 20.5, 7.075, t)
    w.thick_wall(22.5, 7.075, 31.15, 7.075, t)
    w.thick_wall(31.075, -6.5, 31.075, -1.0, t)
    w.thick_wall(31.075, 1.0, 31.075, 7.0, t)
    w.polyline([(20.5, 7.15), (20.5, 10.0), (22.5, 10.0), (22.5, 7.15)])       # stairwell
    mullions = np.arange(18.2, 31.0, 1.6)
    for x0, x1 in zip(mullions, list(mullions[1:]) + [31.0]):
        w.glass_panel(x0 + 0.05, -6.5, x1 - 0.05, -6.5)
        if x1 < 31.0:
            w.box(x1, -6.5, 0.1, 0.1)
    w.box(27.0, 6.2 + j(), 3.5, 0.8)                         # coffee counter
    w.circle(25.0 + j(), -2.6 + j(), 0.3)                    # pillars
    w.circle(24.0 + j(), 4.2 + j(), 0.3)
    w.box(28.5 + j(), -5.6, 1.8, 0.5)                        # bench by the facade
    w.circle(18.8 + j(), -5.8 + j(), 0.25)                   # plant pots
    w.circle(30.4 + j(), 6.4 + j(), 0.25)
    return w


def hokuyo_corridor_lobby(seed: int = 9) -> Scenario:
    """A real robot's run: a Hokuyo-class scanner (768 beams over 270 deg, 11 m, 7.5 Hz)
    mounted 0.85 m forward, 0.24 m left and turned 42 deg on a robot that drives a corridor
    past office doors and a glass-fronted meeting room while someone walks alongside it,
    through a doorway into a lobby, turns right, then left along its glass facade; in the lobby
    people walk in, stand (5-20 s) and walk away, in a pair and a group of three. The beams
    beside a nearer edge return mixed ranges. 40 s."""
    rng = _scene_rng(seed)
    w = _building(rng)
    duration, start = 40.0, 0.5
    end = start + duration + 1.5
    turn = 40 * DEG
    platform = (PathBuilder(0.0, 2.0, -0.3, 0.0).wait(0.5)
                .go(20.0, -0.3, 0.8)                       # the corridor, through the doorway
                .turn_by(-math.pi / 2, turn)
                .go(20.0, -4.3, 0.7)                       # south, towards the facade
                .turn_by(math.pi / 2, turn)
                .go(25.0, -4.3, 0.7))                      # east along the glass facade
    platform.wait_until(end)
    robot = platform.build()
    # The walker comes out of office S1 behind the robot, catches up on its left and walks
    # beside it (0.85 m from its centre line) until turning off into office N3.
    lane, catch_speed, t_walker = 0.55, 1.5, 3.3
    t_lane = t_walker + 1.7 / 1.2 + math.hypot(0.5, lane + 0.9) / 1.2   # reaches the lane
    base_x = robot.position(t_lane)[0]
    x_side = 4.0 + catch_speed * (base_x - 4.0) / (catch_speed - 0.8)  # level with base_link
    people = [
        # The meeting room behind the glass: one stands 17 s and leaves; one walks up to
        # the glass, stands 9 s and leaves.
        (0.0, (3.3, 2.4), [17.0, (11.9, 2.4, 1.1), (11.9, 4.6, 1.1), (11.9, 6.0, 1.1)]),
        (0.0, (11.9, 6.0), [(11.9, 4.6, 1.0), (9.0, 2.0, 1.0), 9.0, (11.9, 4.6, 1.1),
                            (11.9, 6.0, 1.1)]),
        # Oncoming in the corridor, passing the robot on its left, into office S0.
        (0.0, (9.5, 0.6), [(-1.5, 0.6, 1.2), (-1.5, -2.2, 1.2)]),
        # Alongside the robot, between it and the glass.
        (t_walker, (3.5, -2.6), [(3.5, -0.9, 1.2), (4.0, lane, 1.2),
                                 (x_side, lane, catch_speed), (15.0, lane, 0.8),
                                 (15.5, 1.6, 0.9), (15.5, 3.5, 0.9), (14.0, 4.5, 0.9)]),
        # Lobby: in by the stairs, coffee at the counter for 15 s, out the same way.
        (12.0, (21.5, 9.0), [(21.5, 6.0, 1.1), (26.5, 5.2, 1.1), 15.0,
                             (21.8, 5.9, 1.1), (21.8, 9.2, 1.1)]),
        # In by the east door to the facade, stands there on the phone for 20 s, leaves the
        # same way.
        (9.0, (34.0, -0.3), [(30.0, -0.5, 1.0), (29.5, -4.0, 1.0), 19.5, (30.0, -0.5, 0.9),
                             (34.0, -0.3, 0.9)]),
        # In by the east door to the facade, stands 10 s, then walks ahead of the robot.
        (14.0, (34.0, 0.5), [(30.0, 0.5, 1.2), (23.5, -5.6, 1.2), 10.0, (26.5, -5.6, 1.0),
                             (29.0, -3.0, 1.0), (30.0, 0.5, 1.0), (34.0, 0.5, 1.0)]),
        # A group of three abreast, in by the east door and out by the stairs.
        (19.0, (33.5, 0.6), [(22.1, 0.6, 1.1 * 11.4 / 12.0), (22.1, 9.5, 1.1)]),
        (19.0, (33.5, 0.0), [(21.5, 0.0, 1.1), (21.5, 9.5, 1.1)]),
        (19.0, (33.5, -0.6), [(20.9, -0.6, 1.1 * 12.6 / 12.0), (20.9, 9.5, 1.1)]),
        # A pair side by side in by the east door, stands chatting for 9 s, walks back.
        (22.0, (33.5, -0.1), [(26.2, -0.1, 1.0), 9.0, (33.5, -0.1, 1.1)]),
        (22.0, (33.5, -0.7), [(26.2, -0.7, 1.0), 9.0, (33.5, -0.7, 1.1)]),
        # The street outside the facade, seen through the glass.
        (22.5, (12.0, -8.0), [(38.0, -8.0, 1.2)]),
    ]
    agents = [_person(rng, i + 1, _walk(t0, first, *moves))
              for i, (t0, first, moves) in enumerate(people)]
    return Scenario(name='hokuyo_corridor_lobby', seed=seed,
                    description=_doc(hokuyo_corridor_lobby),
                    world=w, platform=robot, agents=agents, duration=duration,
                    scan_start=start,
                    lidar=HokuyoConfig(mount_x=REAL_ROBOT_MOUNT[0], mount_y=REAL_ROBOT_MOUNT[1],
                                       mount_yaw=REAL_ROBOT_MOUNT[2],
                                       beam_width=HOKUYO_BEAM_WIDTH),
                    odometry=OdometryConfig(rate_hz=REAL_ROBOT_ODOMETRY_HZ),
                    publish_mount=True)


# ------------------------------------------------------------------- driving past people
# The scanner of driving_past_people: a 270 deg scanner on the front right corner, turned
# 45 deg to the right, whose field of view grazes the robot's own side and front bumper.
DRIVING_MOUNT = (0.40, -0.28, -45 * DEG)
# The robot's own parts at scanner height, in base_link: its right side and the end of its
# front bumper (seen at the two ends of the field of view) and a cable loop by the scanner.
DRIVING_BODY = (((0.32, -0.30, -0.45, -0.30), (0.48, 0.0, 0.48, 0.32)),
                ((0.30, -0.38, 0.015),))


def driving_past_people(seed: int = 10) -> Scenario:
    """A robot drives at 1 m/s along a 40 m corridor (3.6 m wide, 0.7 m from its right
    wall) towards a hall, pausing 4 s on the way, past people who walk towards it, overtake it,
    step out of doors ahead of it, cross its path far ahead and stand: against the far wall,
    next to the robot where it pauses, by the wall it drives along. Its 270 deg scanner (768 beams, 11 m,
    7.5 Hz, on the front right corner, turned 45 deg) loses most returns beyond 70 deg of
    incidence at 3 m and beyond (more grazing ones nearer), writes a missing return as +inf
    (NaN or 0 for some), and sees the robot's own side, bumper and a cable; the beams just
    past the body's edge (and any nearer edge) return mixed ranges, short of the wall behind.
    40 s."""
    rng = _scene_rng(seed)
    j = lambda s=0.05: _jitter(rng, s)  # noqa: E731
    w = World()
    ys, yn, t = -1.8, 1.8, 0.15
    # The corridor: doors on the north side (x 6..7, 16.5..17.5, 23.5..24.5, 31..32), one on
    # the south side (x 13..14); it opens into a hall at x = 40.
    for x0, x1 in ((-4.0, 6.0), (7.0, 16.5), (17.5, 23.5), (24.5, 31.0), (32.0, 40.0)):
        w.thick_wall(x0, yn, x1, yn, t)
    for x0, x1 in ((-4.0, 13.0), (14.0, 40.0)):
        w.thick_wall(x0, ys, x1, ys, t)
    w.wall(-4.0, ys, -4.0, yn)
    for x in (-4.0, 8.0, 20.0, 28.0, 40.0):          # offices behind the doors
        w.wall(x, yn + 0.1, x, 6.0)
        w.wall(x, ys - 0.1, x, -6.0)
    w.wall(-4.0, 6.0, 40.0, 6.0)
    w.wall(-4.0, -6.0, 40.0, -6.0)
    for x in (3.0, 11.0, 22.0, 30.0, 36.0):         # desks and cabinets in the offices
        w.box(x + j(), 5.3 + j(), 1.4, 0.7)
        w.box(x + 1.0 + j(), -5.3 + j(), 1.2, 0.6)
    w.box(9.5 + j(), 1.55, 1.2, 0.3)                  # a bench and a radiator in the corridor
    w.box(21.0 + j(), -1.6, 1.0, 0.2)
    # The hall (x 40..56, y -9..9), with pillars, a counter and chairs.
    w.polyline([(40.0, yn + 0.075), (40.0, 9.0), (56.0, 9.0), (56.0, -9.0), (40.0, -9.0),
                (40.0, ys - 0.075)])
    for x, y in ((46.0, -4.0), (46.0, 4.5), (51.0, 0.0)):
        w.circle(x + j(), y + j(), 0.3)
    w.box(53.5 + j(), 6.5, 3.0, 0.8)
    for x, y in ((48.0, -6.5), (48.6, -6.4), (49.2, -6.6)):
        w.chair(x + j(), y + j(), float(rng.uniform(0, math.pi)))
    duration, start = 40.0, 0.5
    platform = (PathBuilder(0.0, 0.0, -0.8, 0.0).wait(0.5)
                .go(14.0, -0.8, 1.0)
                .wait(4.0)
                .go(36.0, -0.8, 1.0))
    platform.wait_until(start + duration + 1.5)
    people = [
        # Out of the door at x = 24 towards the robot on its left; passes it where it
        # pauses, into the door at x = 6.5.
        (8.0, (24.0, 2.6), [(24.0, 0.95, 1.2), (6.5, 0.95, 1.2), (6.5, 2.6, 1.2)]),
        # Stands by the far wall (a notice board) 20 s, then into the door at x = 24.
        (0.0, (12.0, 1.45), [20.0, (24.0, 1.45, 1.0), (24.0, 2.6, 1.0)]),
        # Overtakes the robot on its left while it pauses.
        (3.0, (-3.5, -0.1), [(38.0, -0.1, 1.5), (44.0, -3.0, 1.5)]),
        # Out of the door at x = 17, stands where the robot will pause (1.2 m to its left)
        # until after it has left, then walks on east.
        (6.0, (17.0, 3.0), [(17.0, 1.2, 1.0), (14.6, 0.35, 1.0), 18.0, (39.0, 0.5, 1.1)]),
        # Stands close to the right wall the robot drives along; the robot passes 0.5 m away.
        (0.0, (26.0, -1.45), [34.0, (36.0, -1.3, 0.8)]),
        # Out of the door at x = 31 ahead of the robot, walks east slower than it.
        (27.0, (31.5, 3.0), [(31.5, 0.9, 0.9), (41.5, 1.5, 0.9), (44.0, 7.0, 0.9)]),
        # At the corridor's far end: one crosses the hall past its opening from north to
        # south; one walks in from the hall and stands by the right wall; one steps out
        # of the door at x = 31 and stands by the far wall.
        (31.5, (41.0, 4.0), [(41.0, -5.0, 1.1)]),
        (25.0, (42.0, -3.0), [(41.0, -0.8, 1.0), (37.5, -1.25, 1.0), 20.0]),
        (20.0, (31.5, 3.0), [(31.5, 1.3, 0.8), (30.5, 1.3, 0.8), 25.0]),
    ]
    # Legs in trousers, as the real robots' training recordings show them (a visible radius
    # of 6-9 cm).
    agents = [Person(i + 1, _walk(t0, first, *moves).build(),
                     GaitConfig(leg_radius=float(rng.uniform(0.06, 0.09)),
                                leg_spacing=float(rng.uniform(0.14, 0.22))))
              for i, (t0, first, moves) in enumerate(people)]
    return Scenario(name='driving_past_people', seed=seed,
                    description=_doc(driving_past_people),
                    world=w, platform=platform.build(), agents=agents, duration=duration,
                    scan_start=start,
                    lidar=HokuyoConfig(mount_x=DRIVING_MOUNT[0], mount_y=DRIVING_MOUNT[1],
                                       mount_yaw=DRIVING_MOUNT[2], frame_id='right_laser',
                                       noise_sigma=0.01,
                                       grazing_deg=68.0, grazing_ramp_deg=12.0,
                                       grazing_dropout_probability=0.97,
                                       grazing_reference_range=3.0,
                                       no_return='mixed', no_return_nan=0.12,
                                       no_return_zero=0.10, beam_width=HOKUYO_BEAM_WIDTH),
                    odometry=OdometryConfig(rate_hz=REAL_ROBOT_ODOMETRY_HZ),
                    publish_mount=True, body=DRIVING_BODY)


@dataclass(frozen=True)
class ScenarioInfo:
    build: Callable[[int], Scenario]
    default_seed: int
    summary: str


SCENARIOS: dict[str, ScenarioInfo] = {
    f.__name__: ScenarioInfo(f, f.__defaults__[0], _doc(f))
    for f in (exp1_stationary_single_walker, exp2_translating_static, exp3_rotating_static,
              exp4_corridor_passers, fig8_robot_target, crossing_walkers,
              hokuyo_corridor_lobby, driving_past_people)
}


def build(name: str, seed: int | None = None) -> Scenario:
    """The scenario ``name`` with ``seed`` (its default seed when None)."""
    info = SCENARIOS[name]
    return info.build(info.default_seed if seed is None else int(seed))

