"""Things that move: keyframe trajectories, people (two legs, alternating gait), robots (boxes).

A :class:`Trajectory` is piecewise linear in time through keyframes ``(t, x, y, theta)``, so
velocities are piecewise constant (the paper's constant-velocity paths); build one with
:class:`PathBuilder` (``go``, ``wait``, ``turn_to``). An object exists from its first to its
last keyframe (people enter and leave the scene).

A :class:`Person`'s ground truth is the body centre on the trajectory. Its two legs (circles
of ~6 cm radius, ~0.15 m apart laterally) follow an alternating gait: during each step one
leg stands on its footfall while the other swings from the footfall before, past the standing
leg, to the one after, at twice the body's speed; the roles swap every step. Footfalls are placed on the path at
mid-step, alternately left and right of it, so on a straight path the legs' midpoint is
exactly the body centre. The gait is a function of the distance walked, and each walk
between stops is a whole number of steps, so a person who stops stands with the feet side by
side around the body centre. Step length is ``speed / cadence`` with cadence
``cadence_base_hz + cadence_per_mps * speed`` steps per second (0.34 m at 0.5 m/s, 0.75 m at
1.5 m/s), rounded to whole steps per walk.

A :class:`Robot` is a rectangle (4 segments) centred on its trajectory, its long side along the
trajectory's heading. A :class:`RobotBody` is the scanning platform's own body: segments and
circles fixed in the platform's base frame, carried along its trajectory (what a 270 deg
scanner sees of the chassis, the mast or a cable).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from laser_tracker.config import param
from laser_tracker.core.geometry import wrap_angle
from laser_tracker.tools.sim.world import box_corners

PERSON = 'person'
ROBOT = 'robot'


@dataclass(frozen=True)
class GaitConfig:
    """How simulated people walk (section ``sim.gait``)."""

    leg_radius: float = param(0.06, 'Radius of a leg at scanner height (m).', min=0.02, max=0.15)
    leg_spacing: float = param(0.15, 'Lateral distance between the legs\' centres (m).',
                               min=0.05, max=0.4)
    cadence_base_hz: float = param(1.2, 'Steps per second at zero speed (extrapolated).',
                                   min=0.2, max=3.0)
    cadence_per_mps: float = param(0.5, 'Extra steps per second per m/s of walking speed.',
                                   min=0.0, max=3.0)


class Trajectory:
    """Piecewise-linear motion through keyframes ``times`` (K,), ``poses`` (K, 3).

    Headings are continuous (not wrapped): between two keyframes the heading turns by their
    difference, so a keyframe pair (0, 4 pi) is two full turns.
    """

    def __init__(self, times, poses):
        self.times = np.asarray(times, dtype=float)
        self.poses = np.asarray(poses, dtype=float).reshape(-1, 3).copy()
        if self.times.size < 1 or self.times.size != self.poses.shape[0]:
            raise ValueError('a trajectory needs as many keyframe times as poses (at least 1)')
        if np.any(np.diff(self.times) <= 0):
            raise ValueError('keyframe times must increase')

    @property
    def t_start(self) -> float:
        return float(self.times[0])

    @property
    def t_end(self) -> float:
        return float(self.times[-1])

    def exists(self, t) -> np.ndarray:
        t = np.asarray(t, dtype=float)
        return (t >= self.t_start - 1e-9) & (t <= self.t_end + 1e-9)

    def pose(self, t) -> np.ndarray:
        """Poses (..., 3) at times ``t`` (clamped to the keyframes), theta wrapped."""
        t = np.asarray(t, dtype=float)
        out = np.stack([np.interp(t, self.times, self.poses[:, i]) for i in range(3)], axis=-1)
        out[..., 2] = wrap_angle(out[..., 2])
        return out

    def position(self, t) -> np.ndarray:
        t = np.asarray(t, dtype=float)
        return np.stack([np.interp(t, self.times, self.poses[:, i]) for i in range(2)], axis=-1)

    def _segment(self, t) -> np.ndarray:
        """Index of the keyframe interval holding ``t`` (the later one at a keyframe)."""
        k = np.searchsorted(self.times, np.asarray(t, dtype=float), side='right') - 1
        return np.clip(k, 0, max(self.times.size - 2, 0))

    def velocity(self, t) -> np.ndarray:
        """World-frame rates (..., 3) ``(vx, vy, omega)``; zero before and after the keyframes."""
        t = np.asarray(t, dtype=float)
        if self.times.size < 2:
            return np.zeros(t.shape + (3,))
        rates = np.diff(self.poses, axis=0) / np.diff(self.times)[:, None]
        out = rates[self._segment(t)]
        outside = (t < self.t_start) | (t >= self.t_end)
        return np.where(np.asarray(outside)[..., None], 0.0, out)

    def body_velocity(self, t) -> np.ndarray:
        """Rates (..., 3) in the moving frame: forward, left, omega."""
        v = self.velocity(t)
        th = self.pose(t)[..., 2]
        c, s = np.cos(th), np.sin(th)
        return np.stack([c * v[..., 0] + s * v[..., 1], -s * v[..., 0] + c * v[..., 1],
                         v[..., 2]], axis=-1)


class PathBuilder:
    """Keyframes by motion primitives: ``PathBuilder(t0, x, y, theta).go(...).wait(...)``."""

    def __init__(self, t0: float, x: float, y: float, theta: float = 0.0):
        self._t = [float(t0)]
        self._p = [(float(x), float(y), float(theta))]

    @property
    def t(self) -> float:
        return self._t[-1]

    @property
    def pose(self) -> tuple[float, float, float]:
        return self._p[-1]

    def _add(self, dt: float, pose) -> PathBuilder:
        if dt <= 0:
            raise ValueError(f'a motion must take positive time, got {dt}')
        self._t.append(self._t[-1] + dt)
        self._p.append(tuple(float(v) for v in pose))
        return self

    def go(self, x: float, y: float, speed: float) -> PathBuilder:
        """Straight to (x, y) at ``speed`` m/s, keeping the heading (a person, whose gait
        follows the direction of travel, or a holonomic platform translating)."""
        x0, y0, th = self.pose
        dist = math.hypot(x - x0, y - y0)
        if dist == 0.0:
            return self
        return self._add(dist / speed, (x, y, th))

    def drive(self, x: float, y: float, speed: float, turn_rate: float) -> PathBuilder:
        """A differential-drive move: turn in place towards (x, y), then go straight."""
        x0, y0, _ = self.pose
        self.turn_to(math.atan2(y - y0, x - x0), turn_rate)
        return self.go(x, y, speed)

    def turn_to(self, theta: float, rate: float) -> PathBuilder:
        """Rotate in place to heading ``theta`` (the short way) at ``rate`` rad/s."""
        x0, y0, th = self.pose
        delta = float(wrap_angle(theta - th))
        if abs(delta) < 1e-9:
            return self
        return self._add(abs(delta) / rate, (x0, y0, th + delta))

    def turn_by(self, delta: float, rate: float) -> PathBuilder:
        """Rotate in place by ``delta`` rad (any amount, sign = direction) at ``rate`` rad/s."""
        x0, y0, th = self.pose
        return self._add(abs(delta) / rate, (x0, y0, th + delta))

    def wait(self, dt: float) -> PathBuilder:
        return self._add(dt, self.pose)

    def wait_until(self, t: float) -> PathBuilder:
        return self.wait(t - self.t) if t > self.t + 1e-9 else self

    def build(self) -> Trajectory:
        return Trajectory(self._t, self._p)


class Person:
    """A walking person: ground truth = body centre; the scanner sees two legs."""

    kind = PERSON

    def __init__(self, id: int, trajectory: Trajectory, gait: GaitConfig | None = None):
        self.id, self.trajectory = int(id), trajectory
        self.gait = gait = gait or GaitConfig()
        tr = trajectory
        steps = np.diff(tr.poses[:, :2], axis=0)
        dist = np.hypot(steps[:, 0], steps[:, 1])
        moving = dist > 1e-9
        speed = dist / np.diff(tr.times) if dist.size else dist
        step_len = speed / (gait.cadence_base_hz + gait.cadence_per_mps * speed)
        dphase = np.zeros_like(dist)
        dphase[moving] = dist[moving] / step_len[moving]
        # Each walk between stops takes a whole number of steps, so a person who stops (or
        # starts, or ends) stands mid-step: feet side by side, centred on the body.
        i = 0
        while i < dist.size:
            if not moving[i]:
                i += 1
                continue
            j = i
            while j < dist.size and moving[j]:
                j += 1
            total = dphase[i:j].sum()
            dphase[i:j] *= max(1, round(total)) / total
            i = j
        self._arc = np.concatenate(([0.0], np.cumsum(dist)))              # at keyframes
        self._phase = 0.5 + np.concatenate(([0.0], np.cumsum(dphase)))   # gait phase
        # Direction of travel per keyframe interval (the footfalls' sideways offset); a
        # standing interval keeps the direction of arrival (the first walk's before it).
        head = np.arctan2(steps[:, 1], steps[:, 0]) if dist.size else np.zeros(0)
        if moving.any():
            last = head[int(np.argmax(moving))]
            for k in range(head.size):
                if moving[k]:
                    last = head[k]
                else:
                    head[k] = last
        self._head = head

    def phase(self, t) -> np.ndarray:
        """Gait phase at ``t``: during step k (``floor``) leg k % 2 stands (0 = left)."""
        return np.interp(np.asarray(t, dtype=float), self.trajectory.times, self._phase)

    def _footfall(self, k: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Footfalls (..., 2) of steps ``k`` and the points beside them where the other leg
        passes (..., 2). A footfall lies on the path where the body is at mid-step
        (phase k + 0.5), offset sideways: even k to the left, odd k to the right."""
        phase = np.asarray(k, dtype=float) + 0.5
        poses = self.trajectory.poses
        if self._phase[-1] > self._phase[0]:
            s = np.interp(phase, self._phase, self._arc)
            xy = np.stack([np.interp(s, self._arc, poses[:, i]) for i in range(2)], axis=-1)
            seg = np.searchsorted(self._phase, phase, side='left') - 1
            head = self._head[np.clip(seg, 0, self._head.size - 1)]
        else:
            xy = np.broadcast_to(poses[0, :2], phase.shape + (2,)).copy()
            head = np.full(phase.shape, self._head[0] if self._head.size else 0.0)
        side = np.where(np.asarray(k) % 2 == 0, 0.5, -0.5) * self.gait.leg_spacing
        offset = np.stack([-np.sin(head) * side, np.cos(head) * side], axis=-1)
        return xy + offset, xy - offset

    def legs(self, t) -> np.ndarray:
        """Leg centres (..., 2, 2) at times ``t``: index 0 = left leg, 1 = right leg.

        During step k the stance leg stays on footfall k; the other swings from footfall
        k - 1, past the stance leg (mid-step), to footfall k + 1."""
        phi = self.phase(t)
        k = np.floor(phi).astype(np.int64)
        u = (phi - k)[..., None]
        stance, beside = self._footfall(k)
        before, _ = self._footfall(k - 1)
        after, _ = self._footfall(k + 1)
        swing = np.where(u < 0.5, before + (2.0 * u) * (beside - before),
                         beside + (2.0 * u - 1.0) * (after - beside))
        even = (k % 2 == 0)[..., None]
        left = np.where(even, stance, swing)
        right = np.where(even, swing, stance)
        return np.stack([left, right], axis=-2)

    def circles(self, t) -> np.ndarray:
        """Leg circles (..., 2, 3) at times ``t``."""
        legs = self.legs(t)
        r = np.full(legs.shape[:-1] + (1,), self.gait.leg_radius)
        return np.concatenate([legs, r], axis=-1)

    def segments(self, t) -> np.ndarray:
        t = np.asarray(t, dtype=float)
        return np.zeros(t.shape + (0, 4))

    def centre(self, t) -> np.ndarray:
        return self.trajectory.position(t)

    def velocity(self, t) -> np.ndarray:
        return self.trajectory.velocity(t)[..., :2]


class Robot:
    """Another robot platform: a ``length`` x ``width`` box along its trajectory's heading."""

    kind = ROBOT

    def __init__(self, id: int, trajectory: Trajectory, length: float = 0.5,
                 width: float = 0.45):
        self.id, self.trajectory = int(id), trajectory
        self.length, self.width = float(length), float(width)

    def segments(self, t) -> np.ndarray:
        """The box's sides (..., 4, 4) at times ``t``."""
        pose = self.trajectory.pose(t)
        hl, hw = self.length / 2.0, self.width / 2.0
        local = np.array([(hl, hw), (-hl, hw), (-hl, -hw), (hl, -hw)])
        c, s = np.cos(pose[..., 2])[..., None], np.sin(pose[..., 2])[..., None]
        x = pose[..., 0:1] + c * local[:, 0] - s * local[:, 1]
        y = pose[..., 1:2] + s * local[:, 0] + c * local[:, 1]
        x1, y1 = np.roll(x, -1, axis=-1), np.roll(y, -1, axis=-1)
        return np.stack([x, y, x1, y1], axis=-1)

    def circles(self, t) -> np.ndarray:
        t = np.asarray(t, dtype=float)
        return np.zeros(t.shape + (0, 3))

    def centre(self, t) -> np.ndarray:
        return self.trajectory.position(t)

    def velocity(self, t) -> np.ndarray:
        return self.trajectory.velocity(t)[..., :2]

    def corners(self, t: float) -> np.ndarray:
        x, y, th = self.trajectory.pose(t)
        return box_corners(x, y, self.length, self.width, th)


class RobotBody:
    """The scanning platform's own parts, fixed in its base frame: ``segments`` (S, 4) and
    ``circles`` (C, 3) in metres, carried along the platform's ``trajectory``."""

    def __init__(self, trajectory: Trajectory, segments=(), circles=()):
        self.trajectory = trajectory
        self.local_segments = np.asarray(segments, dtype=float).reshape(-1, 4)
        self.local_circles = np.asarray(circles, dtype=float).reshape(-1, 3)

    def _place(self, t, xy: np.ndarray) -> np.ndarray:
        """Points (P, 2) of the base frame at the platform poses at ``t`` -> (..., P, 2)."""
        pose = self.trajectory.pose(t)
        c, s = np.cos(pose[..., 2])[..., None], np.sin(pose[..., 2])[..., None]
        x = pose[..., 0:1] + c * xy[:, 0] - s * xy[:, 1]
        y = pose[..., 1:2] + s * xy[:, 0] + c * xy[:, 1]
        return np.stack([x, y], axis=-1)

    def segments(self, t) -> np.ndarray:
        """The parts' segments (..., S, 4) at times ``t``."""
        seg = self.local_segments
        return np.concatenate([self._place(t, seg[:, :2]), self._place(t, seg[:, 2:])], axis=-1)

    def circles(self, t) -> np.ndarray:
        """The parts' circles (..., C, 3) at times ``t``."""
        cir = self.local_circles
        centre = self._place(t, cir[:, :2])
        r = np.broadcast_to(cir[:, 2:3], centre.shape[:-1] + (1,))
        return np.concatenate([centre, r], axis=-1)
