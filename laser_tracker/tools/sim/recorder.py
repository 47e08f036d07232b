"""Step a scenario through time: scans, odometry and ground truth, as plain data.

:func:`record` turns a :class:`Scenario` into a :class:`Recording` (no messages, no files);
``laser_tracker.tools.simulate.write_recording`` writes it as a rosbag2 recording.

Each beam is cast from where the scanner was, at the instant that beam was taken
(``stamp + i * time_increment``), against where every moving object was at that instant. The
ground truth is taken at each scan's stamp (its first beam): every object that exists then
(including occluded ones, ``visible`` = at least 2 beams returned from it) with its centre and
velocity in the world frame ``map``, and the platform's true pose and body-frame velocity.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from laser_tracker.conversions import MovingObject, PlanarOdometry
from laser_tracker.core.scan import Scan
from laser_tracker.tools.sim.agents import RobotBody, Trajectory
from laser_tracker.tools.sim.lidar import HokuyoConfig, LidarConfig, make_scanner
from laser_tracker.tools.sim.platform import OdometryConfig, OdometryStream, simulate_odometry
from laser_tracker.tools.sim.world import World, cast_scene

WORLD_FRAME = 'map'
SELF = -2    # owner of a beam that hit the platform's own body (0: static world, -1: none)


@dataclass
class Scenario:
    """Everything needed to simulate one recording, all of it derived from ``seed``."""

    name: str
    seed: int
    description: str
    world: World
    platform: Trajectory
    agents: list = field(default_factory=list)
    duration: float = 30.0
    scan_start: float = 0.5
    lidar: LidarConfig | HokuyoConfig = field(default_factory=LidarConfig)
    odometry: OdometryConfig = field(default_factory=OdometryConfig)
    publish_mount: bool = True        # record the scanner mount on /tf_static
    body: tuple = ((), ())            # the platform's own parts: (segments, circles), base frame

    @property
    def mount(self) -> tuple[float, float, float]:
        """The scanner's pose on the platform ``(x, y, yaw)``: base_link -> scan frame."""
        c = self.lidar
        return (c.mount_x, c.mount_y, c.mount_yaw)

    def agent(self, id: int):
        return next(a for a in self.agents if a.id == id)


@dataclass
class GroundTruthScan:
    """Moving objects at one scan stamp (world frame) and the platform's true state."""

    stamp: float
    objects: list[MovingObject]
    platform: PlanarOdometry


@dataclass
class Recording:
    scenario: Scenario
    scans: list[Scan]
    scan_receive_times: np.ndarray
    odometry: OdometryStream
    truth: list[GroundTruthScan]
    owners: list[np.ndarray]          # per scan: object id each beam hit (0 static, -1 none,
                                      # SELF the platform's body)

    def odometry_messages(self) -> list[PlanarOdometry]:
        o, c = self.odometry, self.scenario.odometry
        return [PlanarOdometry(float(s), float(p[0]), float(p[1]), float(p[2]), float(w[0]),
                               float(w[1]), float(w[2]), c.frame_id, c.child_frame_id)
                for s, p, w in zip(o.stamps, o.poses, o.twists)]


def _rngs(seed: int):
    """Independent random streams for the sensor, the odometry and the sensor's beams of
    each scan (the scene uses [seed, 0])."""
    return (np.random.default_rng([seed, 1]), np.random.default_rng([seed, 2]),
            np.random.default_rng([seed, 3]))


def record(scenario: Scenario) -> Recording:
    """Simulate ``scenario``: deterministic from its seed."""
    lidar = make_scanner(scenario.lidar)
    lc = scenario.lidar
    lidar_rng, odom_rng, beams_rng = _rngs(scenario.seed)
    seg_static = scenario.world.segments
    circ_static = scenario.world.circles
    static_sets_seg = [(seg_static, np.zeros(len(seg_static), dtype=np.int64))]
    static_sets_circ = [(circ_static, np.zeros(len(circ_static), dtype=np.int64))]
    glass = scenario.world.glass
    mount = np.array(scenario.mount)
    body = RobotBody(scenario.platform, *scenario.body)
    has_body = bool(len(body.local_segments) or len(body.local_circles))

    stamps = lidar.scan_stamps(scenario.scan_start, scenario.duration)
    scans, truth, owners_all = [], [], []
    for stamp in stamps:
        angle_min, increment, angles, offsets = lidar.beams(beams_rng)
        times = stamp + offsets
        base = scenario.platform.pose(times)                          # (N, 3)
        c, s = np.cos(base[:, 2]), np.sin(base[:, 2])
        origins = np.column_stack([base[:, 0] + c * mount[0] - s * mount[1],
                                   base[:, 1] + s * mount[0] + c * mount[1]])
        beam_dir = base[:, 2] + mount[2] + angles
        directions = np.column_stack([np.cos(beam_dir), np.sin(beam_dir)])

        present = [a for a in scenario.agents if a.trajectory.exists(stamp)]
        seg_sets, circ_sets = list(static_sets_seg), list(static_sets_circ)
        if has_body:
            seg_sets.append((body.segments(times), np.full(len(body.local_segments), SELF)))
            circ_sets.append((body.circles(times), np.full(len(body.local_circles), SELF)))
        for a in present:
            circ = a.circles(times)                                   # (N, k, 3)
            if circ.shape[1]:
                circ_sets.append((circ, np.full(circ.shape[1], a.id, dtype=np.int64)))
            seg = a.segments(times)                                   # (N, k, 4)
            if seg.shape[1]:
                seg_sets.append((seg, np.full(seg.shape[1], a.id, dtype=np.int64)))
        true_ranges, owner, incidence = cast_scene(origins, directions, seg_sets, circ_sets,
                                                   glass)
        ranges, returned = lidar.measure(true_ranges, lidar_rng, incidence, increment)
        owner = np.where(returned, owner, -1)
        owners_all.append(owner)
        scans.append(Scan(stamp=float(stamp), ranges=ranges, angle_min=angle_min,
                          angle_increment=increment, range_min=lc.range_min,
                          range_max=lc.range_max,
                          time_increment=float(offsets[1]) if offsets.size > 1 else 0.0,
                          scan_time=lidar.scan_time, frame_id=lc.frame_id))

        objects = []
        for a in present:
            centre, vel = a.centre(stamp), a.velocity(stamp)
            beams = int(np.count_nonzero(owner == a.id))
            objects.append(MovingObject(id=a.id, x=float(centre[0]), y=float(centre[1]),
                                        vx=float(vel[0]), vy=float(vel[1]),
                                        extra={'kind': a.kind, 'visible': beams >= 2,
                                               'beams': beams}))
        pose = scenario.platform.pose(stamp)
        twist = scenario.platform.body_velocity(stamp)
        truth.append(GroundTruthScan(float(stamp), objects, PlanarOdometry(
            float(stamp), float(pose[0]), float(pose[1]), float(pose[2]), float(twist[0]),
            float(twist[1]), float(twist[2]), WORLD_FRAME,
            scenario.odometry.child_frame_id)))

    receive = stamps + lc.receive_delay
    t_end = float(receive[-1]) + 0.2 if receive.size else scenario.scan_start
    odometry = simulate_odometry(scenario.platform, t_end, scenario.odometry, odom_rng)
    return Recording(scenario=scenario, scans=scans, scan_receive_times=receive,
                     odometry=odometry, truth=truth, owners=owners_all)
