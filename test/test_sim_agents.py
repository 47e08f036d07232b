"""People walk on two alternating legs; robots are boxes; trajectories are piecewise linear."""
import math

import numpy as np
import pytest

from laser_tracker.tools.sim.agents import GaitConfig, PathBuilder, Person, Robot

DT = 0.005


def _leg_speeds(person, t):
    legs = person.legs(t)                                  # (T, 2, 2)
    return np.linalg.norm(np.diff(legs, axis=0), axis=-1) / DT   # (T-1, 2)


def test_legs_alternate_one_planted_while_the_other_swings():
    gait = GaitConfig()
    person = Person(1, PathBuilder(0.0, 0.0, 0.0).go(12.0, 0.0, 1.0).build(), gait)
    t = np.arange(1.0, 11.0, DT)                           # a step away from the ends
    speed = _leg_speeds(person, t)
    slow, fast = speed.min(axis=1), speed.max(axis=1)
    step = np.floor(person.phase(t))
    steady = step[1:] == step[:-1]                         # intervals within one step
    assert steady.mean() > 0.97
    assert np.all(slow[steady] < 1e-6)                     # the stance leg does not move
    assert np.allclose(fast[steady], 2.0)                  # the swing leg moves at 2 v
    planted = np.argmin(speed, axis=1)[steady]             # which leg stands
    swaps = np.count_nonzero(np.diff(planted))
    cadence = gait.cadence_base_hz + gait.cadence_per_mps * 1.0
    assert swaps == pytest.approx(cadence * 10.0, abs=1.5)  # roles swap every step


def test_body_centre_is_the_legs_midpoint_with_legs_side_by_side():
    gait = GaitConfig(leg_spacing=0.16)
    person = Person(1, PathBuilder(0.0, 1.0, 2.0).go(1.0 + 6 * 0.6, 2.0 + 6 * 0.8, 1.2)
                    .build(), gait)
    t = np.linspace(0.0, 5.0, 401)
    legs = person.legs(t)
    assert np.allclose(legs.mean(axis=1), person.centre(t), atol=1e-9)
    sep = legs[:, 0] - legs[:, 1]
    heading = np.array([0.6, 0.8])
    lateral = np.abs(sep @ np.array([-heading[1], heading[0]]))
    assert np.allclose(lateral, 0.16)
    along = np.abs(sep @ heading)
    step = 1.2 / (gait.cadence_base_hz + gait.cadence_per_mps * 1.2)
    assert along.max() == pytest.approx(step, rel=0.1)     # stride consistent with speed
    assert np.allclose(person.velocity(2.0), 1.2 * heading)


@pytest.mark.parametrize('speed', [0.5, 1.5])
def test_step_length_grows_with_speed(speed):
    gait = GaitConfig()
    person = Person(1, PathBuilder(0.0, 0.0, 0.0).go(20.0, 0.0, speed).build(), gait)
    t = np.arange(1.0, 20.0 / speed - 1.0, DT)
    steps = np.count_nonzero(np.diff(np.floor(person.phase(t))))
    step_length = speed * (t[-1] - t[0]) / steps
    assert step_length == pytest.approx(speed / (1.2 + 0.5 * speed), rel=0.05)
    assert 0.3 < step_length < 0.8


def test_a_person_who_stops_stands_feet_together_then_walks_on_turning():
    path = PathBuilder(0.0, 0.0, 0.0).go(2.0, 0.0, 1.0).wait(3.0).go(2.0, 3.0, 1.0).build()
    person = Person(1, path)
    legs = person.legs(np.arange(2.0, 5.0, 0.1))
    assert np.allclose(legs, legs[0])                       # both feet planted
    assert np.allclose(legs[0], [[2.0, 0.075], [2.0, -0.075]])   # side by side, centred
    assert np.allclose(person.velocity(np.array([1.0, 3.0, 6.0])),
                       [[1.0, 0.0], [0.0, 0.0], [0.0, 1.0]])
    end = person.legs(np.array([8.0, 9.0]))                 # arrived: side by side again
    assert np.allclose(end, [[[1.925, 3.0], [2.075, 3.0]]] * 2)
    t = np.arange(0.0, 8.0, 0.01)                           # never far from the body
    assert np.linalg.norm(person.legs(t).mean(axis=1) - person.centre(t), axis=1).max() < 0.2


def test_existence_window():
    path = PathBuilder(5.0, 0.0, 0.0).go(3.0, 0.0, 1.0).build()
    assert list(path.exists(np.array([4.9, 5.0, 8.0, 8.1]))) == [False, True, True, False]


def test_robot_is_a_box_along_its_heading():
    path = PathBuilder(0.0, 1.0, 1.0, 0.0).drive(1.0, 3.0, 0.5, math.radians(90)).build()
    robot = Robot(2, path, length=0.6, width=0.4)
    assert path.t_end == pytest.approx(1.0 + 4.0)           # 1 s turn, 4 s drive
    seg = robot.segments(np.array([3.0]))[0]                # heading +y, centre (1, 2)
    assert robot.centre(3.0) == pytest.approx([1.0, 2.0])
    xs, ys = seg[:, [0, 2]].ravel(), seg[:, [1, 3]].ravel()
    assert xs.min() == pytest.approx(0.8) and xs.max() == pytest.approx(1.2)
    assert ys.min() == pytest.approx(1.7) and ys.max() == pytest.approx(2.3)
    assert np.allclose(robot.velocity(3.0), [0.0, 0.5])
    assert np.allclose(robot.velocity(0.5), [0.0, 0.0])     # turning in place
    assert path.velocity(0.5)[2] == pytest.approx(math.radians(90))
