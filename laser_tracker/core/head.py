"""Active head (paper Sec. 10.3): aim pan/tilt cameras at tracked targets, leading them.

The head is slow ("significant delays"), so the cameras aim where the target *will* be: the
track's position plus its velocity times a lead time of up to ``max_lead`` (3 s in the paper).
Our lead time is the time the head needs to get there: its command delay plus the slew time
at its maximum pan speed, capped at ``max_lead``.

:class:`HeadPointer` chooses the target and the pan/tilt angles; :class:`HeadModel` simulates
the head's dynamics (delay, rate limit) so that a recording can be scored for "targets
captured by the camera" (the target inside the camera's field of view for ``capture_samples``
consecutive scans) as in the paper's Table 4.
"""
from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass

import numpy as np

from laser_tracker.config import param
from laser_tracker.core.geometry import inverse, transform_points, wrap_angle


@dataclass(frozen=True)
class HeadConfig:
    max_lead: float = param(3.0, 'Longest time (s) the cameras lead a target (paper: 3 s).',
                            min=0.0, max=10.0)
    command_delay: float = param(0.5, 'Delay (s) between a head command and the head moving.',
                                 min=0.0, max=5.0)
    max_pan_speed: float = param(1.0, 'Maximum pan speed of the head (rad/s).', min=0.01,
                                 max=20.0)
    pan_min: float = param(-2.9, 'Pan limit (rad), negative = right.', min=-math.pi, max=0.0)
    pan_max: float = param(2.9, 'Pan limit (rad), positive = left.', min=0.0, max=math.pi)
    camera_height: float = param(1.2, 'Height of the cameras above the floor (m).', min=0.0,
                                 max=5.0)
    target_height: float = param(1.0, 'Height to aim at on a target (m).', min=0.0, max=5.0)
    field_of_view: float = param(0.8, 'Horizontal field of view of the cameras (rad).',
                                 min=0.05, max=math.pi)
    max_range: float = param(8.0, 'Targets farther than this (m) are not aimed at.', min=0.5,
                             max=80.0)
    capture_samples: int = param(3, 'Consecutive scans in view for a target to count as '
                                    'captured.', min=1, max=100)
    selection: str = param('uncaptured_nearest', 'How the next target is chosen: '
                           'uncaptured_nearest (prefer targets not yet captured, then the '
                           'nearest), nearest, or heaviest (highest hypothesis weight).',
                           choices=('uncaptured_nearest', 'nearest', 'heaviest'))


@dataclass
class HeadCommand:
    """What the head is told at one instant: the aim point (odometry frame) and the angles."""

    stamp: float
    track_id: int
    aim_x: float
    aim_y: float
    lead: float
    pan: float
    tilt: float


class HeadPointer:
    """Chooses a target among confirmed tracks and computes the leading pan/tilt command.

    It keeps its target while that target is tracked and not yet captured; a target counts as
    captured once it has been inside the commanded view for ``capture_samples`` scans.
    """

    def __init__(self, config: HeadConfig | None = None):
        self.config = config or HeadConfig()
        self.target_id: int | None = None
        self.captured: set[int] = set()
        self._in_view: dict[int, int] = {}
        self._pan_estimate = 0.0

    def update(self, stamp: float, platform_pose, tracks) -> HeadCommand | None:
        """``tracks``: iterable of (id, x, y, vx, vy, weight) of confirmed tracks, odom frame.

        ``platform_pose`` is the head's base pose (x, y, theta) in the odometry frame.
        Returns None when there is nothing to aim at.
        """
        cfg = self.config
        rows = np.array([tuple(t)[:6] for t in tracks], dtype=float).reshape(-1, 6)
        if rows.size:
            rows = rows[np.all(np.isfinite(rows), axis=1)]
        if rows.shape[0] == 0:
            self.target_id = None
            return None
        local = transform_points(inverse(platform_pose), rows[:, 1:3])
        dist = np.hypot(local[:, 0], local[:, 1])
        in_range = dist <= cfg.max_range
        if not in_range.any():
            self.target_id = None
            return None
        ids = rows[:, 0].astype(int)
        self._count_views(ids, local)
        candidates = ids[in_range]
        uncaptured_left = any(i not in self.captured for i in candidates.tolist())
        # Keep the target while it is tracked, unless it is captured and another is not.
        keep = (self.target_id is not None and self.target_id in candidates
                and (self.target_id not in self.captured or not uncaptured_left))
        if not keep:
            self.target_id = self._choose(ids, dist, rows[:, 5], in_range)
        k = int(np.flatnonzero(ids == self.target_id)[0])
        return self._aim(stamp, platform_pose, rows[k])

    def _choose(self, ids, dist, weight, in_range) -> int:
        order_key = dist.copy()
        if self.config.selection == 'heaviest':
            order_key = -weight
        elif self.config.selection == 'uncaptured_nearest':
            captured = np.array([i in self.captured for i in ids])
            order_key = dist + np.where(captured, 1e6, 0.0)
        order_key = np.where(in_range, order_key, np.inf)
        return int(ids[int(np.argmin(order_key))])

    def _aim(self, stamp, platform_pose, row) -> HeadCommand:
        cfg = self.config
        track_id, x, y, vx, vy = int(row[0]), row[1], row[2], row[3], row[4]
        # Lead = time for the head to get there: delay + slew time, at most max_lead.
        now_local = transform_points(inverse(platform_pose), np.array([[x, y]]))[0]
        pan_now = math.atan2(now_local[1], now_local[0])
        slew = abs(float(wrap_angle(pan_now - self._pan_estimate))) / cfg.max_pan_speed
        lead = min(cfg.max_lead, cfg.command_delay + slew)
        aim = np.array([[x + vx * lead, y + vy * lead]])
        aim_local = transform_points(inverse(platform_pose), aim)[0]
        pan = float(np.clip(math.atan2(aim_local[1], aim_local[0]), cfg.pan_min, cfg.pan_max))
        distance = max(float(np.hypot(*aim_local)), 0.1)
        tilt = math.atan2(cfg.target_height - cfg.camera_height, distance)
        self._pan_estimate = pan
        return HeadCommand(stamp, track_id, float(aim[0, 0]), float(aim[0, 1]), lead, pan, tilt)

    def _count_views(self, ids, local) -> None:
        """Advance the capture counters with the bearings of the tracks this scan."""
        bearings = np.arctan2(local[:, 1], local[:, 0])
        half = self.config.field_of_view / 2
        seen = np.abs(wrap_angle(bearings - self._pan_estimate)) <= half
        for track_id, inside in zip(ids.tolist(), seen.tolist()):
            count = self._in_view.get(track_id, 0) + 1 if inside else 0
            self._in_view[track_id] = count
            if count >= self.config.capture_samples:
                self.captured.add(track_id)
        alive = set(ids.tolist())
        for stale in [k for k in self._in_view if k not in alive]:
            del self._in_view[stale]


class HeadModel:
    """A pan axis with a command delay and a speed limit, stepped at scan times."""

    def __init__(self, config: HeadConfig | None = None, pan: float = 0.0):
        self.config = config or HeadConfig()
        self.pan = pan
        self._stamp: float | None = None
        self._commands: deque[tuple[float, float]] = deque()
        self._goal = pan

    def command(self, stamp: float, pan: float) -> None:
        self._commands.append((stamp + self.config.command_delay, pan))

    def step(self, stamp: float) -> float:
        """Advance to ``stamp``; return the pan angle the head has reached."""
        if self._stamp is None or stamp < self._stamp:
            self._stamp = stamp
        while self._commands and self._commands[0][0] <= stamp:
            active_at, goal = self._commands.popleft()
            self._slew_until(max(active_at, self._stamp))
            self._goal = goal
        self._slew_until(stamp)
        return self.pan

    def _slew_until(self, stamp: float) -> None:
        dt = stamp - self._stamp
        self._stamp = stamp
        limit = self.config.max_pan_speed * dt
        self.pan += float(np.clip(float(wrap_angle(self._goal - self.pan)), -limit, limit))

    def sees(self, bearing: float) -> bool:
        return abs(float(wrap_angle(bearing - self.pan))) <= self.config.field_of_view / 2


def simulate_head(scan_stamps, platform_poses, confirmed_tracks,
                  config: HeadConfig | None = None) -> np.ndarray:
    """Pan angle the head reaches at each scan when driven by :class:`HeadPointer`.

    ``platform_poses`` (N, 3) are the estimated poses the tracker used (odometry frame);
    ``confirmed_tracks[k]`` the (id, x, y, vx, vy, weight) rows confirmed at scan k. The head
    starts looking straight ahead. Used offline to score "captured by the camera".
    """
    config = config or HeadConfig()
    pointer, head = HeadPointer(config), HeadModel(config)
    pans = np.empty(len(scan_stamps))
    for k, (stamp, pose) in enumerate(zip(scan_stamps, platform_poses)):
        cmd = pointer.update(float(stamp), pose, confirmed_tracks[k])
        if cmd is not None:
            head.command(float(stamp), cmd.pan)
        pans[k] = head.step(float(stamp))
    return pans


def captured_objects(pans, true_poses, object_rows, config: HeadConfig | None = None) -> set:
    """Ids of the objects the simulated camera captured.

    ``object_rows[k]`` holds (id, x, y) of the objects visible at scan k in the world frame;
    ``true_poses`` (N, 3) the platform's true poses there. An object is captured once it stays
    inside the camera's field of view (and range) for ``capture_samples`` consecutive scans.
    """
    config = config or HeadConfig()
    half = config.field_of_view / 2
    streak: dict[int, int] = {}
    captured: set = set()
    for pan, pose, rows in zip(pans, true_poses, object_rows):
        rows = np.asarray(rows, dtype=float).reshape(-1, 3)
        local = transform_points(inverse(pose), rows[:, 1:3])
        bearing = np.arctan2(local[:, 1], local[:, 0])
        inside = (np.abs(wrap_angle(bearing - pan)) <= half) & \
            (np.hypot(local[:, 0], local[:, 1]) <= config.max_range)
        seen = set()
        for obj_id, ok in zip(rows[:, 0].astype(int).tolist(), inside.tolist()):
            if ok:
                streak[obj_id] = streak.get(obj_id, 0) + 1
                seen.add(obj_id)
                if streak[obj_id] >= config.capture_samples:
                    captured.add(obj_id)
        for obj_id in [i for i in streak if i not in seen]:
            streak[obj_id] = 0
    return captured
